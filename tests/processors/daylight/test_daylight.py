"""Daylight: relight linearity and closed forms, sky models (Preetham, CIE overcast), sun irradiance and
visibility, and an end-to-end time-sampled bake through USD."""

from repo_paths import SAMPLES
import math

import numpy as np
import pytest
from tolerances import (FLOAT32_ACCUMULATED, FLOAT32_STORAGE, FLOAT64_AMPLIFIED, LUMINANCE_WEIGHTS, MC_SIGMAS,
                        PEREZ_PATCH_AVERAGING, SKY_PATCH_INTEGRATION, SUN_TABLE_BLEND, SUN_PENUMBRA_SHARE)
from usdbake.core import ParamError
from usdbake.processors.daylight.sun_visibility import compute_sun_visibility
from usdbake.processors.daylight.daylight import (
    Daylight,
    reinhard_tone_map,
    relight_daylight,
)
from usdbake.kernels.sky import (
    LUMINOUS_EFFICACY,
    overcast_radiance,
    patch_radiance,
    preetham_radiance,
    sun_normal_irradiance,
    uniform_patches,
)
from usdbake.core.scene import Scene
from usdbake.processors.daylight.sky_visibility import compute_sky_visibility
from usdbake.kernels.tracer import Tracer


def plane_scene(extra=()) -> Scene:
    """An upward 2 x 2 plane (prim 0, albedo 0.5) plus optional extra (points, triangles) occluders."""
    parts = [(np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32), np.array([[0, 1, 2], [0, 2, 3]]))]
    parts += list(extra)
    points, tris, tri_prim, point_prim, starts = [], [], [], [], [0]
    for m, (p, t) in enumerate(parts):
        tris.append(np.asarray(t, np.int32) + starts[-1])
        points.append(np.asarray(p, np.float32))
        tri_prim.append(np.full(len(t), m, np.int32))
        point_prim.append(np.full(len(p), m, np.int32))
        starts.append(starts[-1] + len(p))
    points, tris = np.concatenate(points), np.concatenate(tris)
    c = points[tris].astype(np.float64)
    cross = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    double = np.linalg.norm(cross, axis=1)
    n = len(parts)
    return Scene(
        points=points, tri_vertices=tris, tri_normals=(cross / double[:, None]).astype(np.float32),
        tri_areas=(double / 2).astype(np.float32), tri_albedo=np.full((len(tris), 3), 0.5, np.float32),
        tri_emission=np.zeros((len(tris), 3), np.float32), tri_prim=np.concatenate(tri_prim),
        tri_face=np.zeros(len(tris), np.int32), tri_instance=np.full(len(tris), -1, np.int32),
        tri_double_sided=np.zeros(len(tris), bool), point_prim=np.concatenate(point_prim),
        prim_paths=tuple(f"/P{m}" for m in range(n)), prim_point_start=np.array(starts, np.int64),
        prim_face_count=np.ones(n, np.int32), prim_writable=np.arange(n) == 0, prim_skip=np.zeros(n, bool),
        prim_surface=("",) * n, prim_to_world=np.repeat(np.eye(4)[None], n, axis=0), up_axis="Z",
    )


def test_relight_is_linear_and_uint8_matches_float():
    rng = np.random.default_rng(5)  # fixed: arbitrary factors and radiances
    v8 = rng.integers(0, 256, (500, 64), dtype=np.uint8)
    v = v8.astype(np.float32) / 255
    w1, w2 = rng.random((64, 3)).astype(np.float32), rng.random((64, 3)).astype(np.float32)
    albedo = rng.random((500, 3)).astype(np.float32)
    sun = rng.random((500, 3)).astype(np.float32)
    base = relight_daylight(v, w1, albedo=albedo)
    np.testing.assert_allclose(relight_daylight(v, 2 * w1, albedo=albedo), 2 * base, rtol=FLOAT32_STORAGE)
    np.testing.assert_allclose(relight_daylight(v, w1 + w2, albedo=albedo, sun=sun),
                               base + relight_daylight(v, w2, albedo=albedo) + albedo / np.pi * sun,
                               rtol=FLOAT32_ACCUMULATED, atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(relight_daylight(v8, w1, scale=1 / 255, albedo=albedo, chunk=77), base,
                               rtol=FLOAT32_ACCUMULATED)
    np.testing.assert_allclose(relight_daylight(np.ascontiguousarray(v.T), w1, albedo=albedo, patch_major=True), base,
                               rtol=FLOAT32_ACCUMULATED)
    with pytest.raises(ValueError):
        relight_daylight(v, w1[:10])


def test_open_plane_under_uniform_sky_reflects_albedo_times_radiance():
    scene = plane_scene()
    tracer = Tracer.from_scene(scene)
    product, _ = compute_sky_visibility(tracer, scene, patches=uniform_patches(256), samples=16)
    radiance = 700.0
    weights = np.full((256, 3), radiance, np.float32) * product.patches.patch_solid_angles[:, None].astype(np.float32)
    irradiance = relight_daylight(product.visibility, weights, scale=product.visibility_scale)
    np.testing.assert_allclose(irradiance, np.pi * radiance, rtol=SKY_PATCH_INTEGRATION)
    out = relight_daylight(product.visibility_float(), weights, albedo=scene.tri_albedo[product.face_source])
    np.testing.assert_allclose(out, 0.5 * radiance, rtol=SKY_PATCH_INTEGRATION)


def test_overcast_sky_horizontal_irradiance_closed_form():
    """CIE overcast: integral of Lz (1 + 2 cos t) / 3 cos t dw over the hemisphere = 7 pi / 9 Lz."""
    patches = uniform_patches(256)
    sun = np.array([0.0, -0.5, math.sqrt(0.75)])
    values = patch_radiance(patches, "overcast", sun)
    mean_cos = patches.patch_bounds[:, :2].mean(axis=1)  # exact patch-mean cosine of ring patches
    irradiance = (values[:, 0] * mean_cos * patches.patch_solid_angles).sum()
    zenith = overcast_radiance(np.array([0, 0, 1.0]), sun)[0]
    np.testing.assert_allclose(irradiance, 7 * np.pi / 9 * zenith, rtol=SKY_PATCH_INTEGRATION)
    np.testing.assert_allclose(overcast_radiance(np.array([1.0, 0, 0]), sun)[0] * 3, zenith)


def test_preetham_zenith_symmetry_and_circumsolar_brightening():
    t = 3.0
    theta_s = math.radians(40.0)
    sun = np.array([0.0, -math.sin(theta_s), math.cos(theta_s)])  # south, 50 deg altitude
    zenith = preetham_radiance(np.array([0, 0, 1.0]), sun, t)
    chi = (4 / 9 - t / 120) * (math.pi - 2 * theta_s)
    expected_y = ((4.0453 * t - 4.9710) * math.tan(chi) - 0.2155 * t + 2.4192) * 1000  # cd/m^2 (Preetham A.2)
    luminance = zenith @ np.array([0.2126, 0.7152, 0.0722]) * LUMINOUS_EFFICACY
    np.testing.assert_allclose(luminance, expected_y, rtol=LUMINANCE_WEIGHTS)
    east, west = preetham_radiance(np.array([[0.6, -0.3, 0.742], [-0.6, -0.3, 0.742]]), sun, t)
    np.testing.assert_allclose(east, west, rtol=FLOAT64_AMPLIFIED)  # symmetric about the sun's vertical plane
    near_sun = preetham_radiance(sun * 0.99 + np.array([0, 0, 0.01]), sun, t)
    away = preetham_radiance(np.array([0.0, 0.5, math.sqrt(0.75)]), sun, t)
    assert near_sun.sum() > 3 * away.sum()
    assert not preetham_radiance(np.array([0, 0, 1.0]), -sun, t).any()  # night: the model is not defined


def test_sun_normal_irradiance_physical_range():
    overhead = sun_normal_irradiance(np.array([0, 0, 1.0]), 2.0) * LUMINOUS_EFFICACY
    illuminance = overhead @ np.array([0.2126, 0.7152, 0.0722])
    # Clear-sky direct normal illuminance with the sun overhead: ~90-110 klx (e.g. CIE 110-1994 tables).
    assert 85_000 < illuminance < 115_000
    assert overhead[2] < overhead[0]  # Rayleigh scattering reddens the direct beam
    low = sun_normal_irradiance(np.array([0, 0.95, 0.312]), 2.0)
    hazy = sun_normal_irradiance(np.array([0, 0, 1.0]), 8.0)
    assert (low < overhead / LUMINOUS_EFFICACY).all() and (hazy < overhead / LUMINOUS_EFFICACY).all()
    assert not sun_normal_irradiance(np.array([0, 0, -1.0])).any()


def test_sun_visibility_open_and_shaded():
    roof = (np.array([[-0.5, -3, 1], [3, -3, 1], [3, 3, 1], [-0.5, 3, 1]], np.float32),
            np.array([[0, 2, 1], [0, 3, 2]]))  # covers x > -0.5 at height 1, facing down
    scene = plane_scene([roof])
    tracer = Tracer.from_scene(scene)
    corners = scene.points[scene.tri_vertices[:2]]
    overhead = compute_sun_visibility(tracer, corners, scene.tri_normals[:2], np.array([0, 0, 1.0]), samples=256)
    # Overhead sun: the roof shades x > -0.5. Triangle (0, 1, 2) is y <= x, (0, 2, 3) is y >= x, each of area 2;
    # their areas left of x = -0.5 are 0.125 and 0.875.
    visible = np.array([0.125, 0.875]) / 2
    tol = MC_SIGMAS * np.sqrt(visible * (1 - visible) / 256) + SUN_PENUMBRA_SHARE
    assert (np.abs(overhead - visible) <= tol).all(), (overhead, visible)
    low = compute_sun_visibility(tracer, corners, scene.tri_normals[:2], np.array([0, -1.0, -0.01]))
    assert not low.any()  # below the horizon of the faces


def test_bad_times_are_param_errors():
    with pytest.raises(ParamError, match="times"):
        Daylight.Params(times="2026-06-21T18:00/06:00/PT1H")
    with pytest.raises(ParamError, match="times"):
        Daylight.Params.from_dict({"times": "noon"})
    with pytest.raises(ParamError):
        Daylight.Params(sky="cloudy")
    with pytest.raises(ParamError):
        Daylight.Params(turbidity=50.0)


def test_tone_map_is_bounded_and_monotone():
    values = np.array([[0, 0, 0], [1, 1, 1], [10, 5, 1], [1e6, 1e6, 1e6]], np.float32)
    mapped, k = reinhard_tone_map(values)
    assert k > 0 and (mapped >= 0).all() and (mapped < 1).all()
    assert (np.diff(mapped[:, 0]) >= 0).all()


def test_time_sampled_bake_through_usd():
    import usdbake
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(SAMPLES / "window_room.usda"))
    usdbake.bake(stage, ["daylight"], {
        "sky_visibility": {"patch_count": 64, "max_level": 2},
        "daylight": {"times": "2026-06-21T06:00/18:00/PT3H", "display_color": True},
    })
    floor = stage.GetPrimAtPath("/World/Room/Floor")
    primvars = UsdGeom.PrimvarsAPI(floor)
    daylight = primvars.GetPrimvar("bake:daylight")
    assert daylight.GetInterpolation() == "uniform"
    assert daylight.GetAttr().GetTimeSamples() == [0.0, 1.0, 2.0, 3.0, 4.0]
    faces = len(UsdGeom.Mesh(floor).GetFaceVertexCountsAttr().Get())
    noon = np.array(daylight.Get(2.0))
    assert noon.shape == (faces, 3) and np.isfinite(noon).all() and noon.max() > 0
    display = np.array(primvars.GetPrimvar("displayColor").Get(2.0))
    assert display.shape == (faces, 3) and (display >= 0).all() and (display < 1).all()
    # Outdoors at noon is brighter than at 6:00 (low sun, dimmer sky).
    ground = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Ground")).GetPrimvar("bake:daylight")
    assert np.mean(ground.Get(2.0)) > 2 * np.mean(ground.Get(0.0))


# ---------------------------------------------------------------------------
# Perez all-weather sky

def test_perez_sky_integrates_to_the_diffuse_horizontal_irradiance():
    """The sky is scaled so that integral L cos(zeta) dw = DHI, on any patch layout (not only its own grid)."""
    from usdbake.kernels.sky import perez_radiance, tregenza_patches

    sun = np.array([0.3, -0.4, 0.8]) / np.linalg.norm([0.3, -0.4, 0.8])
    for dni, dhi in ((850.0, 90.0), (300.0, 220.0), (0.0, 160.0)):
        for patches in (uniform_patches(1024), tregenza_patches()):
            values = patch_radiance(patches, "perez", sun, direct_normal=dni, diffuse_horizontal=dhi, per_side=5)
            mean_cos = patches.patch_bounds[:, :2].mean(axis=1)
            irradiance = (values[:, 0] * mean_cos * patches.patch_solid_angles).sum()
            # patch averaging of a smooth but peaked (circumsolar) distribution: a few percent
            np.testing.assert_allclose(irradiance, dhi, rtol=PEREZ_PATCH_AVERAGING)
        assert np.all(perez_radiance(np.array([[0.6, 0.0, -0.8]]), sun, dni, dhi) == 0.0)  # below the horizon


def test_perez_sky_states_and_shapes():
    """Clearness from DNI/DHI (Perez 1990), the overcast bin's own c and d, and the model's shapes:
    a clear sky is brightest around the sun, an overcast one at the zenith rather than the horizon."""
    from usdbake.kernels.sky import (perez_coefficients, perez_radiance, perez_relative_luminance,
                                                perez_sky_state)

    zenith = math.radians(30.0)
    epsilon, delta = perez_sky_state(zenith, 0.0, 150.0)
    assert epsilon == 1.0  # no direct light: the overcast limit
    epsilon_clear, _ = perez_sky_state(zenith, 850.0, 90.0)
    kz3 = 1.041 * zenith ** 3
    np.testing.assert_allclose(epsilon_clear, ((90 + 850) / 90 + kz3) / (1 + kz3))
    a, b, c, d, e = perez_coefficients(zenith, 1.0, delta)
    np.testing.assert_allclose(c, math.exp((delta * (2.8 + 0.6004 * zenith)) ** 1.2375) - 1.0)
    np.testing.assert_allclose(d, -math.exp(delta * (1.8734 + 0.6297 * zenith)) + 0.9738 + delta * 0.2809)
    # Eq. 1 by hand for one element
    coefficients = np.array([a, b, c, d, e])
    sun = np.array([0.0, math.sin(zenith), math.cos(zenith)])
    element = np.array([0.0, 0.0, 1.0])  # the zenith: zeta = 0, gamma = sun zenith
    expected = (1 + a * math.exp(b)) * (1 + c * math.exp(d * zenith) + e * math.cos(zenith) ** 2)
    np.testing.assert_allclose(perez_relative_luminance(element, sun, coefficients), expected)

    clear = lambda v: perez_radiance(np.asarray(v, float), sun, 850.0, 90.0)[..., 0]  # noqa: E731
    away = np.array([0.0, -math.sin(zenith), math.cos(zenith)])  # mirror of the sun about the zenith
    assert clear(sun * 0.999 + np.array([0, 0, 0.001])) > 3 * clear(away)
    overcast = lambda v: perez_radiance(np.asarray(v, float), sun, 0.0, 150.0)[..., 0]  # noqa: E731
    assert overcast([0, 0, 1.0]) > 1.3 * overcast([1.0, 0.0, 0.05])


@pytest.fixture(scope="module")
def walled_plane():
    """The plane split into ~0.01 m^2 faces, a 0.5 m wall along x = 0.5 casting a shadow on it."""
    wall = (np.array([[0.5, -3, 0], [0.5, 3, 0], [0.5, 3, 0.5], [0.5, -3, 0.5]], np.float32),
            np.array([[0, 1, 2], [0, 2, 3]]))
    scene = plane_scene([wall])
    tracer = Tracer.from_scene(scene)
    product, _ = compute_sky_visibility(tracer, scene, patches=uniform_patches(128), samples=4, adaptive=False,
                                        max_face_area=0.01, prims=np.array([0]))
    return scene, tracer, product


def test_relighter_sky_is_compute_daylight_and_its_sun_table_the_rays(walled_plane):
    from usdbake.processors.daylight.daylight import DaylightRelighter, compute_daylight, sun_table

    scene, tracer, product = walled_plane
    site = {"latitude": 41.98, "longitude": 2.82, "timezone": 1.0}
    table = sun_table(tracer, product, latitude=site["latitude"], samples=64)
    albedo = scene.tri_albedo[product.face_source]
    relighter = DaylightRelighter(product, table, **site, albedo=albedo)
    areas = product.face_areas.astype(np.float64)
    for when in ("2026-03-02T09:20", "2026-06-21T08:35", "2031-11-05T10:10"):  # morning: the shadow is east
        time = np.datetime64(when)
        for sky in ("preetham", "perez", "overcast"):
            rays, _ = compute_daylight(tracer, scene, product, np.array([time]), **site, sky=sky, sun=False)
            np.testing.assert_allclose(relighter.at(time, sky=sky, sun=False), rays.face_radiance[0],
                                       rtol=FLOAT32_ACCUMULATED, atol=FLOAT32_STORAGE)
        with_sun, _ = compute_daylight(tracer, scene, product, np.array([time]), **site, sun_samples=64)
        sky_only, _ = compute_daylight(tracer, scene, product, np.array([time]), **site, sun=False)
        sun_rays = (with_sun.face_radiance[0] - sky_only.face_radiance[0])[:, 1]
        sun_table_term = (relighter.at(time) - relighter.at(time, sun=False))[:, 1]
        shaded = (sun_rays < 0.5 * sun_rays.max()).mean()
        assert 0.02 < shaded < 0.9, (when, shaded)  # the wall's shadow falls on the plane
        total = float(areas @ sun_rays)
        assert abs(float(areas @ sun_table_term) - total) <= SUN_TABLE_BLEND * total, when
