"""The daylight scenes of issue 29 (benchmarks/daylight_scenes.py, furnished_daylight_room.py, stage_readback.py)
and the Radiance reference's glass, uniform sky and patch geometry (benchmarks/radiance_scene.py,
radiance_sky.py): the scenes hold what their docstring says, the geometry read back from the stage is the
authored one, ``sample_baked`` finds the face under a sensor, and Radiance's glass and sky agree with their
closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Sdf, UsdGeom, UsdShade, Vt

from usdbake.benchmarks import daylight_scenes as ds
from usdbake.benchmarks import furnished_daylight_room as fr
from usdbake.benchmarks import radiance_scene as rscene
from usdbake.benchmarks import radiance_sky as rsky
from usdbake.benchmarks import stage_readback as sr

AUTHORED = 1e-6
"""Values authored as float32 and read back: equal to float32 precision."""
GLASS_FIT = 1e-5
"""Radiance's VLT -> tn constants are rounded to 10 digits: the round trip holds to ~5e-6."""
RADIANCE_MC = 0.01
"""Radiance's Monte-Carlo noise on a smooth integrand at -ad 4096 (measured ~0.3%): the issue's 1%."""


@pytest.fixture(scope="module")
def office():
    return ds.lm83_office()


@pytest.fixture(scope="module")
def room():
    return fr.furnished_daylight_room()


def _preview_input(stage, prim_path: str, name: str):
    material, _ = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(prim_path)).ComputeBoundMaterial()
    shader = material.ComputeSurfaceSource()[0]
    return shader.GetInput(name).Get()


# --------------------------------------------------------------------------- the office


def test_office_window_to_wall_ratio_is_forty_percent(office):
    assert ds.window_to_wall_ratio(office) == pytest.approx(0.40, abs=AUTHORED)
    (x0, x1), (z0, z1) = ds.OFFICE_WINDOW
    assert (z0, z1) == (0.9, 2.4)
    assert (x1 - x0) * (z1 - z0) / (ds.OFFICE_SIZE[0] * ds.OFFICE_SIZE[2]) == pytest.approx(0.40)


def test_office_reflectances_and_glass_are_authored(office):
    stage = office.stage
    for prim, value in (("Floor", 0.2), ("Walls", 0.5), ("Ceiling", 0.7)):
        color = _preview_input(stage, f"/World/Office/{prim}", "diffuseColor")
        np.testing.assert_allclose(tuple(color), (value,) * 3, atol=AUTHORED)
    glass = stage.GetPrimAtPath("/World/Office/Glazing")
    assert glass.GetAttribute("bake:transmittance").Get() == pytest.approx(0.6, abs=AUTHORED)
    assert _preview_input(stage, "/World/Office/Glazing", "opacity") == pytest.approx(0.4, abs=AUTHORED)
    # The arrays handed to Radiance: the same values per triangle.
    glazed = office.transmittance > 0
    np.testing.assert_allclose(office.transmittance[glazed], 0.6, atol=AUTHORED)
    assert set(np.round(office.albedo[~glazed, 0], 6)) == {0.2, 0.5, 0.7}
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0


def test_office_is_a_closed_box_without_ground(office):
    tri = office.triangles
    lo, hi = tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)
    np.testing.assert_allclose(lo, 0.0, atol=AUTHORED)
    np.testing.assert_allclose(hi, ds.OFFICE_SIZE, atol=AUTHORED)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    w, d, h = ds.OFFICE_SIZE
    assert area.sum() == pytest.approx(2 * (w * d + w * h + d * h), rel=1e-6)  # the glass closes the opening
    # Every face looks into the room: the normal points towards the box's centre.
    centre = np.array(ds.OFFICE_SIZE) / 2
    assert np.all(np.einsum("ij,ij->i", cross, centre - tri.mean(axis=1)) > 0)


def test_office_sensors_are_lm83_grid_on_floor_faces(office):
    points, normals = office.sensor_points, office.sensor_normals
    assert len(points) == 10 * 17
    np.testing.assert_allclose(points[:, 2], ds.SENSOR_OFFSET)
    np.testing.assert_allclose(normals, np.tile([0.0, 0.0, 1.0], (len(points), 1)))
    np.testing.assert_allclose(np.unique(points[:, 0]), 0.3 + 0.6 * np.arange(10), atol=1e-9)
    np.testing.assert_allclose(np.unique(points[:, 1]), 0.3 + 0.6 * np.arange(17), atol=1e-9)
    # Each sensor lies in one floor face of 0.2 m (a cell of its own).
    floor = office.prim_paths.index("/World/Office/Floor")
    corners = office.triangles[office.tri_prim == floor]
    side = corners[:, :, :2].max(axis=1) - corners[:, :, :2].min(axis=1)
    np.testing.assert_allclose(side, 0.2, atol=1e-5)


# --------------------------------------------------------------------------- the furnished room


def test_room_has_100k_triangles_glass_rgb_and_ground(room):
    assert len(room.triangles) >= 100_000
    glazed = room.transmittance > 0
    assert glazed.sum() == 2 * len(fr.ROOM_WINDOWS)
    np.testing.assert_allclose(room.transmittance[glazed], 0.7, atol=AUTHORED)
    coloured = np.ptp(room.albedo, axis=1) > 0.1
    assert coloured.sum() > 10_000  # fabrics, books, leaves
    ground = room.tri_prim == room.prim_paths.index("/World/Ground")
    np.testing.assert_allclose(room.albedo[ground], 0.2, atol=AUTHORED)
    g = room.triangles[ground].reshape(-1, 3)
    assert g[:, 0].min() == pytest.approx(-100) and g[:, 0].max() == pytest.approx(100)
    # The footprint is left out: no ground triangle's centre lies under the building.
    centres = room.triangles[ground].mean(axis=1)
    lo, hi = fr.ROOM_LO - fr.WALL, fr.ROOM_HI + fr.WALL
    under = np.all((centres[:, :2] > lo[:2]) & (centres[:, :2] < hi[:2]), axis=1)
    assert not under.any()


def test_room_solids_are_closed_and_outward(room):
    """Furniture prims are closed (open only where they stand on something) and wound outward: positive
    enclosed volume, so one- and two-sided readers see the same surfaces."""
    tri = room.triangles
    volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    for index, path in enumerate(room.prim_paths):
        if "/Furniture/" in path:
            assert volume[room.tri_prim == index].sum() > 0, path


def test_room_random_points_are_inside_on_surfaces_and_repeatable(room):
    points, normals = room.sensor_points, room.sensor_normals
    assert len(points) == 150
    assert fr.inside_room(points).all()
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    again, _, prims = fr.random_surface_points(room, 150, seed=29)
    np.testing.assert_array_equal(again, points)
    assert prims == room.sensor_prims
    assert any("/Furniture/" in p for p in prims) and "/World/Room/Floor" in prims
    assert not any(p in ("/World/Room/Glazing", "/World/Ground", "/World/Room/Exterior") for p in prims)


# --------------------------------------------------------------------------- reading results back


def test_sample_baked_reads_the_face_under_each_sensor(office, tmp_path):
    """A uniform primvar holding each floor face's centre x, and a vertex primvar holding each point's x:
    sampled at the sensors they give the sensor's x (within half a cell; exactly for the vertex one)."""
    stage = ds.office_stage()
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Office/Floor"))
    points = np.asarray(mesh.GetPointsAttr().Get(), np.float64)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 4)
    assert (counts == 4).all()
    api = UsdGeom.PrimvarsAPI(mesh)
    centre_x = points[indices][:, :, 0].mean(axis=1)
    api.CreatePrimvar("bake:test", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.uniform).Set(
        Vt.FloatArray.FromNumpy(centre_x.astype(np.float32)))
    api.CreatePrimvar("bake:x", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex).Set(
        Vt.FloatArray.FromNumpy(points[:, 0].astype(np.float32)))
    path = tmp_path / "baked.usda"
    stage.GetRootLayer().Export(str(path))
    sensors = office.sensor_points
    got = sr.sample_baked(str(path), "bake:test", sensors, office.sensor_normals)[:, 0]
    np.testing.assert_allclose(got, sensors[:, 0], atol=1e-5)  # the sensor is the centre of its cell
    got = sr.sample_baked(path, "primvars:bake:x", sensors, office.sensor_normals,
                          prims=office.sensor_prims)[:, 0]
    np.testing.assert_allclose(got, sensors[:, 0], atol=1e-5)
    # A point facing down (the ceiling's way) finds no floor face.
    assert np.isnan(sr.sample_baked(path, "bake:test", sensors[:1], -office.sensor_normals[:1])).all()


# --------------------------------------------------------------------------- Radiance's glass and sky


def test_radiance_glass_conversion_matches_the_manual():
    # Radiance reference manual, glass: "a typical clear glass with 88% transmittance has tn = 0.96".
    assert rscene.glass_transmissivity(0.88) == pytest.approx(0.96, abs=0.005)
    vlt = np.linspace(0.05, 0.9, 18)
    # The manual's formula inverts glass's own normal-incidence model (n = 1.52) to its 10-digit constants.
    np.testing.assert_allclose(rscene.glass_normal_transmittance(rscene.glass_transmissivity(vlt)), vlt, rtol=GLASS_FIT)
    np.testing.assert_allclose(rscene.glass_transmittance(rscene.glass_transmissivity(vlt), np.ones_like(vlt)), vlt,
                               rtol=GLASS_FIT)
    for bad in (0.0, -0.1, 1.2, np.nan):
        with pytest.raises(ValueError):
            rscene.glass_transmissivity(bad)


def test_write_scene_writes_glass_and_rgb_plastic(tmp_path):
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]] * 3, float) + np.arange(3)[:, None, None]
    albedo = np.array([[0.6, 0.1, 0.1], [0.2, 0.2, 0.2], [0.0, 0.0, 0.0]])
    path = tmp_path / "scene.rad"
    assert rscene.write_scene(path, tri, albedo, transmittance=np.array([0.0, 0.0, 0.6])) == 3
    text = path.read_text()
    tn = rscene.glass_transmissivity(0.6)
    assert f"void glass mat2\n0\n0\n3 {tn:.6g} {tn:.6g} {tn:.6g}\n" in text and "mat2 polygon t2" in text
    assert "5 0.6 0.1 0.1 0 0" in text and "5 0.2 0.2 0.2 0 0" in text
    rscene.write_scene(path, tri, 0.5)  # a scalar grey, as before
    assert path.read_text().count("plastic") == 1


def test_reinhart_patches_cover_the_sky():
    for mf in (1, 2, 4):
        dirs, omegas = rsky.reinhart_patches(mf)
        assert len(dirs) == 144 * mf * mf + 2
        assert omegas[1:].sum() == pytest.approx(2 * np.pi)
        np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0)
        _, e_h = rsky.cie_overcast_sky(mf)
        assert e_h == pytest.approx(7.0 / 9.0 * np.pi, rel=0.005)  # CIE overcast: E_h = 7 pi L_z / 9


def test_radiance_uniform_sky_open_points():
    pytest.importorskip("pyradiance")
    up = np.tile([0.0, 0.0, 1.0], (4, 1))
    for ground in (False, True):
        e = rscene.uniform_sky_irradiance(None, None, np.zeros((4, 3)), up, radiance=2.0, ground=ground,
                                          ambient_divisions=1024)
        np.testing.assert_allclose(e, 2.0 * np.pi, rtol=RADIANCE_MC)
    timings = {}
    side = rscene.uniform_sky_irradiance(None, None, np.zeros((4, 3)), np.tile([0.0, 1.0, 0.0], (4, 1)),
                                         ground_reflectance=0.2, ambient_divisions=4096, timings=timings)
    np.testing.assert_allclose(side, np.pi * (1 + 0.2) / 2, rtol=RADIANCE_MC)  # half sky, half ground
    assert timings["radiance_seconds"] > 0 and "-ab 6" in timings["command"]


def test_radiance_glass_roof_transmits_its_diffuse_transmittance():
    """A point under a 200 m horizontal pane of VLT 0.6 (uniform sky, no ground): rtrace and rcontrib both
    give pi L times the pane's cosine-weighted transmittance, Radiance's glass formula integrated in float64
    (0.52: below the normal-incidence 0.6, glass reflects more at grazing angles)."""
    pytest.importorskip("pyradiance")
    s = 100.0
    roof = np.array([[[-s, -s, 1], [s, -s, 1], [s, s, 1]], [[-s, -s, 1], [s, s, 1], [-s, s, 1]]])
    points, up = np.zeros((4, 3)), np.tile([0.0, 0.0, 1.0], (4, 1))
    tau = np.full(2, 0.6)
    expected = rscene.glass_diffuse_transmittance(rscene.glass_transmissivity(0.6))
    assert 0.4 < expected < 0.6
    e = rscene.uniform_sky_irradiance(roof, np.zeros(2), points, up, transmittance=tau, ground=False,
                                      ambient_divisions=4096)
    np.testing.assert_allclose(e / np.pi, expected, rtol=RADIANCE_MC)
    dc = rscene.daylight_coefficients(roof, np.zeros(2), points, up, transmittance=tau, ambient_divisions=4096)
    np.testing.assert_allclose(dc[:, 1:, :].sum(axis=1) / np.pi, expected, rtol=RADIANCE_MC)


def test_radiance_seeds_give_independent_draws():
    pytest.importorskip("pyradiance")
    s = 100.0
    roof = np.array([[[-s, -s, 1], [s, -s, 1], [s, s, 1]], [[-s, -s, 1], [s, s, 1], [-s, s, 1]]])
    points, up = np.zeros((2, 3)), np.tile([0.0, 0.0, 1.0], (2, 1))
    runs = [rscene.uniform_sky_irradiance(roof, np.zeros(2), points, up, transmittance=np.full(2, 0.6), ground=False,
                                          ambient_divisions=256, seed=seed, processes=1) for seed in (None, None, 1, 2)]
    np.testing.assert_array_equal(runs[0], runs[1])  # no seed: Radiance's own, repeatable stream
    assert not np.array_equal(runs[2], runs[3]) and not np.array_equal(runs[0], runs[2])
