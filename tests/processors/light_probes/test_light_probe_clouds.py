"""light_probes, issue 15: interreflection in the capture (a furnace box), light decoupling (direct light at
the lookup), merge by SH contrast, k-means clusters of dark probes, and the conforming tetrahedra (fTetWild)
that never cross a wall."""

import math

import numpy as np
import pytest
from lit_scenes import cube, make_lights, make_scene, merge, quad
from tolerances import (FLOAT32_ACCUMULATED, FLOAT32_LONG_CHAIN, FLOAT32_STORAGE, FLOAT64_ROUNDING,
                        LEAST_SQUARES_RIDGE, MC_SIGMAS)

from usdbake.core import Context
from usdbake.processors.light_probes.products import ProbeCloud
from usdbake.core.scene import LIGHT_DISTANT, LIGHT_SPHERE
from usdbake.processors.light_probes import conforming
from usdbake.kernels.light_bundles import scene_lighting
from usdbake.kernels.sh import sh_basis_np
from usdbake.kernels.tracer import Tracer
from usdbake.processors.light_probes import light_probes as lp
from usdbake.processors.light_probes.capture import classify_points, compute_probe_sh, direct_light_irradiance
from usdbake.processors.light_probes.interpolation import interpolation_weights, irradiance_at, segment_blocked
from usdbake.processors.light_probes.placement import (DARK_CLUSTER_SIZE, cloud_edges, cluster_dark_probes,
                                                      similar_probes)


def bake(scene, **params):
    tracer = Tracer.from_scene(scene)
    processor = lp.LightProbes()
    return processor.run(Context(scene, processor.Params(**params), tracer)), tracer


@pytest.mark.parametrize("bounces", [1, 2, 4])
def test_capture_sees_the_geometric_series_of_bounces_in_an_emissive_box(bounces):
    """A closed box whose inside emits Le with albedo rho (no UsdLux light): after b bounces every wall leaves
    L = Le (1 + rho + ... + rho^b), so a probe anywhere inside gets E(n) = pi L for every normal."""
    le, rho = 1.0, 0.5
    points, tris = cube([-1, -1, -1], [1, 1, 1], inward=True)
    scene = make_scene(points, tris, albedo=rho, emission=np.full((len(tris), 3), le, np.float32))
    tracer = Tracer.from_scene(scene)
    rays = 4096
    got = compute_probe_sh(tracer, scene, np.array([[0.1, -0.2, 0.3]]), rays=rays, seed=5, bounces=bounces)
    normals = np.array([[0, 0, 1.0], [1, 0, 0], [0, -1, 0]])
    e = np.einsum("nk,kc->nc", sh_basis_np(normals), got[0].astype(np.float64))
    expected = math.pi * le * sum(rho ** k for k in range(bounces + 1))
    # Every ray's radiance is bounded by the series' sum (the paths' estimates stay below Le / (1 - rho))
    # and the emitter sampling of a uniform box is exact in the mean: MC_SIGMAS standard deviations.
    tolerance = MC_SIGMAS * math.pi * le / (1 - rho) * 2.0 / math.sqrt(rays)
    np.testing.assert_allclose(e, expected, atol=tolerance)


def sunlit_ground(rho=0.5, size=200.0):
    """A ground quad (normal +z, ``size`` m wide) and a distant light of irradiance 2 W/m^2 (angle 0) 45
    degrees up."""
    points, tris = quad([-size / 2, -size / 2, 0], [size, 0, 0], [0, size, 0])
    sun = np.array([1.0, 0.0, -1.0]) / math.sqrt(2.0)  # light travels along this direction
    lights = make_lights((LIGHT_DISTANT, [2, 2, 2], (0, 0, 0), sun, (0, 0)))
    return make_scene(points, tris, albedo=rho, lights=lights)


def test_decoupled_probes_leave_the_sun_to_the_lookup():
    """direct_lights=lookup: the probes hold only the ground's bounce; irradiance_at with a tracer adds the
    sun at the exact clamped cosine (E cos 45 on an upward normal), without one it is the bounce alone."""
    scene = sunlit_ground()
    tracer = Tracer.from_scene(scene)
    points = np.array([[0.0, 0.0, 1.0], [3.0, -2.0, 2.0]], np.float32)
    up = np.array([[0, 0, 1.0]] * 2, np.float32)
    bounce_only = compute_probe_sh(tracer, scene, points, rays=1024, seed=1, direct_lights=False)
    e_up = np.einsum("nk,nkc->nc", sh_basis_np(up.astype(np.float64)), bounce_only.astype(np.float64))
    # Looking up, the probe sees the black sky over the upper hemisphere: only L2 ringing of the ground's
    # radiance remains (|E_L2(up)| <= pi/4 - ... of the ground radiance rho E cos45 / pi).
    ground_radiance = 0.5 * 2.0 * math.cos(math.pi / 4) / math.pi
    assert np.abs(e_up).max() <= 0.25 * math.pi * ground_radiance
    direct = direct_light_irradiance(tracer, scene, points, up)
    np.testing.assert_allclose(direct, 2.0 * math.cos(math.pi / 4), rtol=FLOAT32_ACCUMULATED)
    shadowed = direct_light_irradiance(tracer, scene, np.array([[0, 0, -1.0]], np.float32), up[:1])
    np.testing.assert_array_equal(shadowed, 0.0)  # below the ground: the ground shadows the sun


def sunlit_block():
    """``sunlit_ground`` with a 2 m block standing on it (the probes go around the block)."""
    ground = sunlit_ground(size=12.0)
    points, tris = merge([(ground.points, ground.tri_vertices), cube([-1, -1, 0], [1, 1, 2])])
    return make_scene(points, tris, albedo=0.5, lights=ground.lights)


def test_a_baked_cloud_says_whether_its_probes_hold_direct_light():
    scene = sunlit_block()
    decoupled, tracer = bake(scene, probes=32, rays=64, placement_rays=16, iterations=1)
    coupled, _ = bake(scene, probes=32, rays=64, placement_rays=16, iterations=1, direct_lights="probes")
    a, b = decoupled.products[ProbeCloud], coupled.products[ProbeCloud]
    assert not a.direct_lights and b.direct_lights
    records = {r.name: r.value for r in decoupled.outputs if hasattr(r, "name") and hasattr(r, "value")}
    assert records["bake:directLights"] == "excluded"
    points = np.array([[-2.2, 0, 2.2], [0, 2.2, 2.1], [2.2, 0.5, 1.0]], np.float32)  # in the sun
    up = np.tile(np.float32([0, 0, 1]), (3, 1))
    with_sun = irradiance_at(a, points, up, tracer=tracer, scene=scene)
    without_sun = irradiance_at(a, points, up, tracer=tracer)  # the same visibility-tested probes
    np.testing.assert_allclose(with_sun - without_sun, 2.0 * math.cos(math.pi / 4),
                               rtol=FLOAT32_LONG_CHAIN)
    # With the sun in the probes, the lookup adds nothing.
    np.testing.assert_array_equal(irradiance_at(b, points, up, tracer=tracer, scene=scene),
                                  irradiance_at(b, points, up, tracer=tracer))


def test_probes_that_see_the_same_light_merge_into_the_more_varied_one():
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [5, 5, 5]], np.float64)
    samples = np.ones((5, 26))
    samples[4] = 10.0  # one probe sees other light
    v = np.array([0.5, 0.1, 0.2, 0.3, 1.0])
    edges = np.array([[0, 1], [0, 2], [2, 3], [3, 4]])
    gone = similar_probes(positions, samples, v, edges, floor=1e-6, threshold=0.05, max_length=2.0)
    # (0, 1) goes first (contrast 0, the first least-contrasted edge): 1 has the lower V. (0, 2) is then
    # skipped (0 was touched); (2, 3) merges 2; (3, 4) is contrasted and too long.
    np.testing.assert_array_equal(gone, [False, True, True, False, False])


def test_dark_probes_inside_an_unlit_region_become_one_per_cluster():
    rng = np.random.default_rng(0)
    lattice = np.stack(np.meshgrid(*[np.arange(8.0)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    positions = lattice + rng.uniform(-0.1, 0.1, lattice.shape)
    sh = np.zeros((len(positions), 9, 3), np.float32)
    lit = positions[:, 0] < 3.5
    sh[lit, 0] = 1.0  # a constant irradiance on the lit half
    kept_positions, kept_sh, gone = cluster_dark_probes(positions, sh, rng)
    assert gone > 0 and len(kept_positions) == len(positions) - gone
    # Every lit probe survives, and every survivor is one of the original probes (a valid spot).
    assert (np.abs(kept_sh[:, 0, 0] - 1.0) < FLOAT32_STORAGE).sum() == lit.sum()
    original = {tuple(p) for p in np.round(positions, 9)}
    assert all(tuple(p) in original for p in np.round(kept_positions, 9))
    # Dark probes beside lit ones keep the shadow's edge: the layer x ~ 4 is whole.
    assert (np.abs(kept_positions[:, 0] - 4.0) < 0.2).sum() == (np.abs(positions[:, 0] - 4.0) < 0.2).sum()
    # The other dark probes with a lit Delaunay neighbour (long hull edges reach a few) stay too; the
    # rest become one probe per k-means cluster.
    edges = cloud_edges(positions)
    beside_lit = np.zeros(len(positions), bool)
    for i, j in ((0, 1), (1, 0)):
        beside_lit[edges[lit[edges[:, j]], i]] = True
    interior = (~lit & ~beside_lit).sum()
    assert interior > 100
    assert len(kept_positions) - lit.sum() - (~lit & beside_lit).sum() == math.ceil(interior / DARK_CLUSTER_SIZE)


def two_rooms():
    """Two closed 4 x 4 x 3 rooms (inward faces) 5 cm apart, a bright lamp in A and a dim one in B."""
    a_p, a_t = cube([0, 0, 0], [4, 4, 3], inward=True)
    b_p, b_t = cube([4.05, 0, 0], [8.05, 4, 3], inward=True)
    points, tris = merge([(a_p, a_t), (b_p, b_t)])
    lights = make_lights((LIGHT_SPHERE, [2000, 2000, 2000], (2, 2, 2.5), (0, 0, -1), (0.1, 0.1)),
                         (LIGHT_SPHERE, [100, 100, 100], (6.05, 2, 2.5), (0, 0, -1), (0.1, 0.1)))
    return make_scene(points, tris, albedo=0.6, lights=lights)


def partitioned_room():
    """One closed 8 x 4 x 3 room (inward faces) cut in two at x = 4 by a zero-thickness double-sided wall,
    a bright lamp in one half and a dim one in the other."""
    room_p, room_t = cube([0, 0, 0], [8, 4, 3], inward=True)
    wall_p, wall_t = quad([4, 0, 0], [0, 4, 0], [0, 0, 3])
    points, tris = merge([(room_p, room_t), (wall_p, wall_t)])
    lights = make_lights((LIGHT_SPHERE, [2000, 2000, 2000], (2, 2, 2.5), (0, 0, -1), (0.1, 0.1)),
                         (LIGHT_SPHERE, [100, 100, 100], (6, 2, 2.5), (0, 0, -1), (0.1, 0.1)))
    return make_scene(points, tris, albedo=0.6, double_sided=np.r_[np.zeros(len(room_t)), np.ones(2)].astype(bool),
                      lights=lights)


CONFORMING_SCENES = {"two rooms": two_rooms, "partitioned room": partitioned_room}


def test_error_driven_placement_puts_probes_where_the_light_is():
    """Room A's lamp is 20 times room B's: the same relative variation is 20 times the absolute error there,
    so the refinement spends most of the budget beyond its uniform start in room A."""
    scene = two_rooms()
    result, _ = bake(scene, probes=200, rays=16, placement_rays=64)
    positions = result.products[ProbeCloud].probe_positions
    in_a, in_b = (positions[:, 0] < 4.0).sum(), (positions[:, 0] > 4.05).sum()
    assert in_a + in_b == len(positions) == 200
    assert in_a > 2 * in_b


@pytest.fixture(scope="module", params=sorted(CONFORMING_SCENES))
def conforming_rooms(request):
    scene = CONFORMING_SCENES[request.param]()
    result, tracer = bake(scene, probes=300, rays=64, tetrahedra="conforming")
    return request.param, scene, tracer, result


def test_conforming_tetrahedra_never_cross_a_wall(conforming_rooms):
    """Rays along every edge of every tetrahedron outside geometry (between the probes' capture positions,
    which sit on their own side of a wall) meet no geometry."""
    name, scene, tracer, result = conforming_rooms
    cloud = result.products[ProbeCloud]
    at = cloud.capture_positions
    tets = cloud.tet_vertices
    centroid = cloud.probe_positions[tets].mean(axis=1)
    inside, _ = classify_points(tracer, scene_lighting(scene, tracer.device), centroid)
    open_tets = tets[~inside]
    assert len(open_tets) > 100
    edges = np.unique(np.sort(np.concatenate([open_tets[:, [i, j]] for i, j in
                                              ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))]), axis=1), axis=0)
    edges = edges[np.linalg.norm(at[edges[:, 0]] - at[edges[:, 1]], axis=1) > 0]
    assert not segment_blocked(tracer, at[edges[:, 0]], at[edges[:, 1]]).any()
    if name == "partitioned room":
        # The partition's vertices are split: two probes at one vertex, captured on either side of it.
        on_wall = np.isclose(cloud.probe_positions[:, 0], 4.0, atol=FLOAT32_LONG_CHAIN)
        assert (at[on_wall, 0] < 4.0).sum() > 4 and (at[on_wall, 0] > 4.0).sum() > 4
        assert len(np.unique(cloud.probe_positions[on_wall], axis=0)) < on_wall.sum()


def test_conforming_interpolation_beside_the_wall_uses_its_own_room(conforming_rooms):
    name, scene, tracer, result = conforming_rooms
    cloud = result.products[ProbeCloud]
    wall = 4.05 if name == "two rooms" else 4.0
    rng = np.random.default_rng(3)
    points = np.c_[rng.uniform(wall + 0.01, wall + 0.1, 200), rng.uniform(0.2, 3.8, 200), rng.uniform(0.2, 2.8, 200)]
    probes, weights = interpolation_weights(cloud, points)
    used = probes[weights > 1e-6]
    assert (cloud.capture_positions[used, 0] > wall).all()  # only the dim room's probes


def test_clip_to_box_keeps_the_inside_part_of_a_crossing_triangle():
    triangle = np.array([[[-1.0, 0.5, 0.5], [2.0, 0.5, 0.5], [0.5, 3.0, 0.5]]])
    pieces = conforming.clip_to_box(triangle, np.zeros(3), np.ones(3))
    assert ((pieces >= -FLOAT64_ROUNDING) & (pieces <= 1 + FLOAT64_ROUNDING)).all()
    area = 0.5 * np.linalg.norm(np.cross(pieces[:, 1] - pieces[:, 0], pieces[:, 2] - pieces[:, 0]), axis=1).sum()
    # The triangle covers the unit square's strip y in [0.5, 1] of the plane z = 0.5 (its slanted edges stay
    # outside x in [0, 1] there): area 0.5.
    assert area == pytest.approx(0.5, rel=FLOAT64_ROUNDING)


def test_variation_gradient_kernel_recovers_a_linear_field():
    """Least squares over the neighbours is exact for V linear in position (up to the tiny ridge)."""
    from usdbake.processors.light_probes.ascent import variation_gradient

    rng = np.random.default_rng(1)
    positions = rng.uniform(-2, 2, (300, 3))
    slope = np.array([0.3, -1.2, 0.7])
    edges = cloud_edges(positions)
    tracer = Tracer.from_scene(two_rooms())
    gradient, mean_edge = variation_gradient(tracer, positions, positions @ slope + 5.0, edges)
    np.testing.assert_allclose(gradient, np.broadcast_to(slope, gradient.shape), rtol=LEAST_SQUARES_RIDGE,
                               atol=LEAST_SQUARES_RIDGE)
    length = np.linalg.norm(positions[edges[:, 0]] - positions[edges[:, 1]], axis=1)
    expected = np.bincount(edges.ravel(), np.repeat(length, 2), 300) / np.bincount(edges.ravel(), minlength=300)
    np.testing.assert_allclose(mean_edge, expected, rtol=FLOAT64_ROUNDING)
