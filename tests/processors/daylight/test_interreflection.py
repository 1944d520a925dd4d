"""Interreflected daylight: the integrating-sphere limit of a box with a skylight, the bounce operator against
a hand-summed series, an open plane unchanged, the ground outside the model, and the relighter with bounces
equal to compute_daylight."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from glass_reference import slab_transmittance
from daylight_boxes import box_with_skylight, grid_quads, quad_scene
from tolerances import FLOAT32_ACCUMULATED, INTEGRATING_SPHERE, MC_SIGMAS, SKY_PATCH_INTEGRATION
from usdbake.kernels.sky import tregenza_patches
from usdbake.kernels.tracer import Tracer
from usdbake.kernels.daylight_relight import sun_patch_weights
from usdbake.processors.daylight.interreflection import BounceOperator, compute_interreflection
from usdbake.processors.daylight.sky_visibility import compute_sky_visibility

RADIANCE = 1.0
"""Uniform sky radiance, W/(m^2 sr)."""


def visibility(scene):
    tracer = Tracer.from_scene(scene)
    product, _ = compute_sky_visibility(tracer, scene, patches=tregenza_patches(), samples=16, adaptive=False)
    return tracer, product


def uniform_weights(product) -> np.ndarray:
    return (RADIANCE * product.patches.patch_solid_angles).astype(np.float32)


@pytest.mark.parametrize("albedo", [0.3, 0.7])
def test_box_with_a_skylight_approaches_the_integrating_sphere_from_below(albedo):
    """Area-averaged interior irradiance E_dir / (1 - rho (1 - f)), f the opening's share of the inner area:
    rising with every bounce, within 5% at 10 bounces, never above."""
    scene = box_with_skylight(albedo)
    tracer, product = visibility(scene)
    areas = product.face_areas.astype(np.float64)
    direct = product.visibility_float() @ uniform_weights(product)
    opening = 6.0 - areas.sum()
    limit = (direct @ areas / areas.sum()) / (1.0 - albedo * (1.0 - opening / 6.0))
    means = []
    for bounces in (0, 1, 2, 4, 10):
        inter, _ = compute_interreflection(tracer, scene, product, bounces=bounces, gather_rays=64, patches=96)
        total = direct + inter.sky_indirect[0] @ uniform_weights(product)
        means.append(float(total @ areas / areas.sum()))
    assert np.all(np.diff(means) > 0)
    assert means[-1] == pytest.approx(limit, rel=INTEGRATING_SPHERE)
    assert means[-1] <= limit * (1.0 + INTEGRATING_SPHERE / 5)


def test_bounce_operator_sums_the_series_of_two_facing_faces():
    """Two faces each sending a share a of their gather to the other, every face its own patch: the k-bounce
    indirect light is the partial sum of (G rho)^b E0, written out."""
    a, rho = 0.4, np.array([0.5, 0.8], np.float32)
    gather = sp.csr_matrix(np.array([[0.0, a], [a, 0.0]], np.float32))
    operator = BounceOperator.build(gather, np.arange(2), np.ones(2), outputs=2)
    direct = np.array([[1.0], [0.0]], np.float32)
    transfer = np.array([[0.0, a], [a, 0.0]]) * rho[None, :]
    for bounces in range(5):
        expected = sum(np.linalg.matrix_power(transfer, b) @ direct for b in range(1, bounces + 1)) \
            if bounces else np.zeros_like(direct)
        np.testing.assert_allclose(operator.indirect(direct, rho, bounces), expected, rtol=FLOAT32_ACCUMULATED,
                                   atol=1e-7)


def test_open_plane_is_unchanged_and_a_wall_sees_the_ground():
    """An open upward plane: no bounced light, no ground (it sees only the back of the wall, which reflects
    nothing). A vertical wall facing away from it: half its view is the ground outside the model (g = 1/2)."""
    plane = grid_quads((0, 0, 0), (1, 0, 0), (0, 1, 0), 4, 4)
    wall = grid_quads((0, 3, 0), (0, 0, 1), (1, 0, 0), 4, 4)  # facing +y, away from the plane
    scene = quad_scene([(plane, 0.5, 0.0), (wall, 0.5, 0.0)])
    tracer, product = visibility(scene)
    inter, _ = compute_interreflection(tracer, scene, product, bounces=3, gather_rays=256)
    on_plane = product.face_prim == 0
    assert not inter.sky_indirect[0][on_plane].any() and not inter.ground_direct[on_plane].any()
    on_wall = ~on_plane
    rays = 256 * on_wall.sum()
    share = inter.ground_direct[on_wall].mean() / np.pi
    assert share == pytest.approx(0.5, abs=MC_SIGMAS * 0.5 / np.sqrt(rays))
    assert not inter.sky_indirect[0][on_wall].any()


def test_sun_patch_weights_keep_the_direct_normal_irradiance():
    patches = tregenza_patches()
    sun = np.array([0.3, -0.5, 0.81])
    weights = sun_patch_weights(patches, sun, np.array([700.0, 700.0, 700.0]))
    assert weights[:, 0].sum() == pytest.approx(700.0, rel=1e-6)
    assert (weights[:, 0] > 0).sum() == 4
    nearest = np.argmax(patches.patch_directions @ (sun / np.linalg.norm(sun)))
    assert weights[nearest, 0] == weights[:, 0].max()
    assert not sun_patch_weights(patches, -sun, np.full(3, 700.0)).any()


def test_relighter_with_bounces_equals_compute_daylight():
    from usdbake.processors.daylight.daylight import DaylightRelighter, compute_daylight, sun_table

    scene = box_with_skylight(0.5, n=6)
    tracer, product = visibility(scene)
    inter, _ = compute_interreflection(tracer, scene, product, bounces=4, gather_rays=32, patches=48)
    site = dict(latitude=41.98, longitude=2.82, timezone=1.0)
    table = sun_table(tracer, product, latitude=site["latitude"], declination_step=12.0, hour_step=15.0)
    albedo = scene.tri_albedo[product.face_source]
    relighter = DaylightRelighter(product, table, **site, albedo=albedo, interreflection=inter)
    when = np.datetime64("2026-06-21T10:00")
    for sky in ("uniform", "perez", "overcast"):
        daylight, _ = compute_daylight(tracer, scene, product, np.array([when]), **site, sky=sky, sun=False,
                                       interreflection=inter)
        np.testing.assert_allclose(relighter.at(when, sky=sky, sun=False), daylight.face_radiance[0],
                                   rtol=FLOAT32_ACCUMULATED, atol=1e-6)
    assert (daylight.face_irradiance[0] > 0).all()


def test_a_face_under_glass_reads_the_panes_transmittance():
    """Under a wide horizontal pane of VLT t: the overhead sun (normal incidence) reads t x the open value within
    1%; the uniform sky reads the pane's hemispherical transmittance, 2 int t(theta) cos sin dtheta, of it."""
    from usdbake.processors.daylight.glazing import Glazing
    from usdbake.kernels.daylight_relight import sun_levels
    from usdbake.processors.daylight.sun_visibility import compute_sun_visibility, sun_bin_hits

    vlt = 0.6
    plane = grid_quads((0, 0, 0), (1, 0, 0), (0, 1, 0), 2, 2)
    pane = grid_quads((-200, -200, 0.5), (400, 0, 0), (0, 400, 0), 1, 1)
    scene = quad_scene([(plane, 0.5, 0.0), (pane, 0.0, vlt)])
    tracer, product = visibility(scene)
    under = product.face_prim == 0
    glazing = Glazing.of_scene(scene)
    corners = product.face_points[product.face_vertices][under]
    seen = compute_sun_visibility(tracer, corners, product.face_normals[under], np.array([0.0, 0.0, 1.0]),
                                  samples=64, glazing=glazing)
    np.testing.assert_allclose(seen, vlt, rtol=0.01)
    stored = sun_bin_hits(tracer, corners, product.face_normals[under], np.array([[0.0, 0.0, 1.0]]), samples=2,
                          glazing=glazing)  # the annual sun's bytes keep the share, not a count of 2 rays
    np.testing.assert_allclose(stored / sun_levels(2), vlt, atol=1.0 / sun_levels(2))
    theta = np.linspace(0.0, np.pi / 2, 20001)
    hemispherical = 2 * np.trapezoid(slab_transmittance(np.cos(theta), vlt) * np.cos(theta)
                                     * np.sin(theta), theta)
    np.testing.assert_allclose(product.exposure[under], hemispherical, rtol=SKY_PATCH_INTEGRATION)


def test_a_stage_with_its_own_ground_hides_the_ground_outside_the_model():
    """A wall standing on a wide ground of the stage: its rays below the horizon meet that ground (all but the
    few grazing ones that pass its edge, 500 m away), so the gendaymtx ground gives it next to nothing (a lone
    wall: half its view); the stage's ground reflects the sky to it instead (rho_g pi L / 2 seen from a vertical
    face over an infinite lit ground, less what the wall shades)."""
    wall = grid_quads((0, 0, 0), (0, 0, 1), (1, 0, 0), 4, 4)  # facing +y
    ground = grid_quads((-500, -500, 0), (1000, 0, 0), (0, 1000, 0), 1, 1)
    scene = quad_scene([(wall, 0.5, 0.0), (ground, 0.2, 0.0)])
    tracer, product = visibility(scene)
    inter, _ = compute_interreflection(tracer, scene, product, bounces=1, gather_rays=256)
    on_wall = product.face_prim == 0
    assert inter.ground_direct[on_wall].mean() / np.pi < 0.01
    bounced = (inter.sky_indirect[0][on_wall] @ uniform_weights(product)).mean()
    rays = 256 * on_wall.sum()  # the ground fills half the wall's view: its share's noise is 0.5 / sqrt(rays)
    assert bounced == pytest.approx(0.5 * 0.2 * np.pi * RADIANCE, rel=MC_SIGMAS / np.sqrt(rays) + 0.01)
