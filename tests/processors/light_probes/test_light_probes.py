"""light_probes: capture against closed forms and a quadrature oracle, placement (never inside closed
geometry), leak fixing with a wall, determinism across thread counts, applies(), params, and
end-to-end bakes through USD (a small stage and samples/atrium.usda)."""

from repo_paths import REPO
import math

import numpy as np
from lit_scenes import cube, make_lights, make_scene, merge, quad
from stage_builders import base_context
import pytest
from tolerances import (FLOAT32_ACCUMULATED, FLOAT32_LONG_CHAIN, FLOAT32_ROUNDING, FLOAT32_STORAGE,
                        FLOAT32_UNIT_ROUNDOFF, GROUND_QUADRATURE, MC_SIGMAS)

from usdbake.processors.light_probes.products import ProbeCloud
from usdbake.geometry.mesh import backdrop_prims
from usdbake.kernels.light_bundles import scene_lighting
from usdbake.processors.light_probes import light_probes as lp
from usdbake.processors.light_probes import tetrahedra
from usdbake.processors.light_probes.capture import classify_points, compute_probe_sh
from usdbake.processors.light_probes.interpolation import build_cloud, cloud_from_arrays, interpolate_sh, irradiance_at
from usdbake.processors.light_probes.placement import CLEARANCE_FRACTION, RECEIVER_MARGIN
from usdbake.core import Context, ParamError
from usdbake.kernels import sh
from usdbake.core.scene import LIGHT_DISTANT, LIGHT_DOME, LIGHT_SPHERE, Scene
from usdbake.kernels.tracer import Tracer


# -- scenes built without pxr -------------------------------------------------------------------












def run(scene: Scene, threads: int | None = None, **params):
    tracer = Tracer.from_scene(scene, threads=threads)
    processor = lp.LightProbes()
    return processor.run(Context(scene, processor.Params(**params), tracer)), tracer


def random_dirs(n, seed):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


# -- capture -------------------------------------------------------------------------------------


def capture_tolerance(rays: int, radiance_bound: float) -> float:
    """MC_SIGMAS x the i.i.d. standard deviation of the L2 irradiance estimate E(n) from ``rays``
    uniform samples of radiance <= radiance_bound: E = 4 pi / N sum L K(n.w), with
    E[K^2] = sum_l A_l^2 (2l+1) / (4 pi)^2 over the uniform sphere."""
    k2 = sum(a * a * (2 * l + 1) for l, a in enumerate((math.pi, 2 * math.pi / 3, math.pi / 4))) / (4 * math.pi) ** 2
    return MC_SIGMAS * 4 * math.pi * radiance_bound * math.sqrt(k2 / rays)


def test_uniform_dome_gives_pi_l_for_every_normal():
    """Only a dome (radiance L) and a tiny far-away triangle: E(n) = pi L for all n."""
    points, tris = quad([1e3, 1e3, 1e3], [1e-3, 0, 0], [0, 1e-3, 0])
    dome = np.array([0.2, 0.5, 1.0])
    scene = make_scene(points, tris, lights=make_lights((LIGHT_DOME, dome, (0, 0, 0), (0, 0, -1), (0, 0))))
    tracer = Tracer.from_scene(scene)
    rays = 4096
    probe_sh = compute_probe_sh(tracer, scene, np.zeros((1, 3)), rays=rays, seed=3)
    # Band 0 is exact: every sample returns L and Y_0 is constant.
    np.testing.assert_allclose(probe_sh[0, 0], math.pi * dome * math.sqrt(4 * math.pi),
                               rtol=FLOAT32_UNIT_ROUNDOFF * rays)
    e = sh.evaluate_np(probe_sh[0], random_dirs(200, seed=4))
    np.testing.assert_allclose(e, np.tile(math.pi * dome, (200, 1)), atol=capture_tolerance(rays, 1.0))


def test_capture_matches_a_quadrature_oracle_for_a_sunlit_ground():
    """A probe 1 m above a 40 x 40 m ground (albedo rho) under a zero-angle distant light (E_s):
    the ground's radiance is rho E_s cos(theta_s) / pi wherever a downward ray meets it, the sun adds
    E_s Y(w_s) to the radiance SH. The oracle projects that by Gauss-Legendre quadrature."""
    rho, e_sun = 0.6, 2.0
    w_sun = np.array([0.3, 0.0, 1.0]) / np.linalg.norm([0.3, 0.0, 1.0])
    points, tris = quad([-20, -20, 0], [40, 0, 0], [0, 40, 0])
    scene = make_scene(points, tris, albedo=rho,
                       lights=make_lights((LIGHT_DISTANT, [e_sun] * 3, (0, 0, 0), -w_sun, (0, 0))))
    tracer = Tracer.from_scene(scene)
    rays = 16384
    probe = np.array([[0.0, 0.0, 1.0]])
    got = compute_probe_sh(tracer, scene, probe, rays=rays, seed=5)[0, :, 0]

    nodes, weights = np.polynomial.legendre.leggauss(400)  # z in [-1, 0): the lower hemisphere
    z, wz = 0.5 * nodes - 0.5, 0.5 * weights
    phi = (np.arange(800) + 0.5) * 2 * np.pi / 800
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - zz ** 2)
    dirs = np.stack([r * np.cos(pp), r * np.sin(pp), zz], axis=-1).reshape(-1, 3)
    w = (wz[:, None] * np.full(800, 2 * np.pi / 800)[None]).reshape(-1)
    t = 1.0 / -dirs[:, 2]
    hit = (np.abs(dirs[:, 0] * t) < 20) & (np.abs(dirs[:, 1] * t) < 20)
    ground = rho * e_sun * w_sun[2] / math.pi
    radiance_sh = sh.project_np(dirs, ground * hit, w) + e_sun * sh.sh_basis_np(w_sun[None])[0]
    expected = sh.irradiance_sh_np(radiance_sh)
    normals = random_dirs(100, seed=6)
    e_got = normals_eval(got, normals)
    e_expected = normals_eval(expected, normals)
    # Plus the quadrature error of the hit boundary (the square's edges cut the grid).
    np.testing.assert_allclose(e_got, e_expected, atol=capture_tolerance(rays, ground) + GROUND_QUADRATURE * e_sun)


def normals_eval(coefficients, normals):
    return sh.sh_basis_np(normals) @ np.asarray(coefficients, np.float64)


def cone_directions(axis_z_half_angle: float, n: int = 400) -> np.ndarray:
    """(n*n, 3) equal-solid-angle midpoints of a cone of the given half-angle around +z."""
    u = (np.arange(n) + 0.5) / n
    z = 1.0 - u[:, None] * (1.0 - math.cos(axis_z_half_angle))
    phi = 2.0 * math.pi * u[None, :]
    r = np.sqrt(1.0 - z * z)
    return np.stack(np.broadcast_arrays(r * np.cos(phi), r * np.sin(phi), z), axis=-1).reshape(-1, 3)


def test_sphere_light_is_its_cone_of_radiance_and_a_wall_shadows_it():
    """A sphere light seen from a probe: its radiance SH is L times the SH integral over the cone it
    subtends (computed here by dense quadrature); behind a wall, zero."""
    radius, distance, radiance = 0.1, 3.0, 50.0
    wall_points, wall_tris = quad([1.5, -5, -5], [0, 10, 0], [0, 0, 10])
    scene = make_scene(wall_points, wall_tris, albedo=0.0, lights=make_lights(
        (LIGHT_SPHERE, [radiance] * 3, (0, 0, distance), (0, 0, -1), (radius, radius))))
    tracer = Tracer.from_scene(scene)
    probes = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]])  # the second one has the wall (x = 1.5) between
    got = compute_probe_sh(tracer, scene, probes, rays=16, seed=1)
    half = math.asin(radius / distance)
    omega = 2 * math.pi * (1 - math.cos(half))
    basis = sh.sh_basis_np(cone_directions(half))
    expected = sh.irradiance_sh_np(radiance * omega * basis.mean(axis=0))
    # 16 stratified samples of the cone: each coefficient is off by at most L Omega A_l times the spread
    # of its basis function over the cone, plus float32 rounding of the sums (relative to band 0).
    spread = radiance * omega * sh.COSINE_LOBE * (basis.max(axis=0) - basis.min(axis=0))
    np.testing.assert_array_less(np.abs(got[0, :, 0] - expected), spread + FLOAT32_LONG_CHAIN * expected[0])
    np.testing.assert_allclose(got[0, 0, 0], expected[0], rtol=FLOAT32_LONG_CHAIN)  # band 0 is exact: L Omega Y_00
    # probe 2 at (3, 0, 0): the line to the lamp (0, 0, 3) crosses x = 1.5 at z = 1.5, inside the wall
    np.testing.assert_allclose(got[1], 0.0, atol=FLOAT32_STORAGE)


def test_back_faces_are_dark_and_front_faces_lit():
    """Inside a closed outward-facing box under a dome, a probe sees only back faces: no light."""
    points, tris = cube([-1, -1, -1], [1, 1, 1])
    scene = make_scene(points, tris, lights=make_lights((LIGHT_DOME, [1, 1, 1], (0, 0, 0), (0, 0, -1), (0, 0))))
    tracer = Tracer.from_scene(scene)
    got = compute_probe_sh(tracer, scene, np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 3.0]]), rays=256, seed=2)
    np.testing.assert_allclose(got[0], 0.0, atol=FLOAT32_ROUNDING)
    assert got[1, 0, 0] > 0


def test_emissive_surface_lights_probes():
    """A large emissive ceiling (radiance Le) 1 m above a probe, no UsdLux lights: E(up) -> pi Le."""
    le = 3.0
    points, tris = quad([-50, -50, 1], [0, 100, 0], [100, 0, 0])  # normal -z
    scene = make_scene(points, tris, albedo=0.0, emission=np.full((2, 3), le, np.float32))
    ok, _ = lp.LightProbes().applies(base_context(scene))
    assert ok
    tracer = Tracer.from_scene(scene)
    rays = 4096
    got = compute_probe_sh(tracer, scene, np.zeros((1, 3)), rays=rays, seed=3)[0]
    e_up = normals_eval(got, np.array([[0.0, 0.0, 1.0]]))[0, 0]
    # L2 truncation of a half-sphere of radiance: E_L2(up) = pi/4 + pi/2 + 0 (band 2 vanishes) in units
    # of Le, vs the exact pi Le; the capture must match the L2 value (not the exact one).
    l2 = le * (math.pi / 2 + math.pi / 2)  # band 0: pi * (2 pi C0) * C0 = pi / 2; band 1: 2pi/3 * pi C1 * C1 = pi/2
    assert e_up == pytest.approx(l2, abs=capture_tolerance(rays, le))


# -- placement -----------------------------------------------------------------------------------


def room_with_boxes():
    """A 10 x 10 x 4 room (inward faces), two closed outward boxes and a sun through an open roof."""
    room_p, room_t = cube([-5, -5, 0], [5, 5, 4], inward=True)
    keep = np.ones(len(room_t), bool)
    keep[2:4] = False  # no ceiling (+z face): open to the sky
    a_p, a_t = cube([-3, -3, 0], [-1, -1, 2])
    b_p, b_t = cube([1, 0, 0], [3.5, 3, 3])
    points, tris = merge([(room_p, room_t[keep]), (a_p, a_t), (b_p, b_t)])
    sun = np.array([-0.3, -0.2, -1]) / np.linalg.norm([0.3, 0.2, 1])
    lights = make_lights((LIGHT_DISTANT, [3, 3, 3], (0, 0, 0), sun, (0, 0)),
                         (LIGHT_DOME, [0.2, 0.3, 0.5], (0, 0, 0), (0, 0, -1), (0, 0)))
    return make_scene(points, tris, lights=lights), [((-3, -3, 0), (-1, -1, 2)), ((1, 0, 0), (3.5, 3, 3))]


@pytest.mark.parametrize("placement", lp.PLACEMENTS)
def test_probes_never_inside_closed_geometry(placement):
    scene, boxes = room_with_boxes()
    result, _ = run(scene, probes=128, rays=64, placement_rays=16, iterations=3, placement=placement)
    cloud = result.products[ProbeCloud]
    positions = cloud.probe_positions
    assert len(positions) >= 20
    for lo, hi in boxes:
        inside = ((positions > np.asarray(lo)) & (positions < np.asarray(hi))).all(axis=1)
        assert not inside.any()
    # inside the room's bounds, and clear of every surface by the clearance
    assert (positions >= [-5, -5, 0]).all() and (positions <= [5, 5, 4]).all()
    tracer = Tracer.from_scene(scene)
    _, nearest = classify_points(tracer, scene_lighting(scene, tracer.device), positions)
    assert nearest.min() >= CLEARANCE_FRACTION * result.stats["min_spacing"] * (1 - FLOAT32_STORAGE)
    spacing = np.linalg.norm(positions[:, None] - positions[None], axis=2) + np.eye(len(positions)) * 1e9
    # merged to min_spacing; the probes beside blockers (leak fixing) to half of it
    assert spacing.min() >= 0.5 * result.stats["min_spacing"] * (1 - FLOAT32_STORAGE)


def test_classify_points_inside_outside():
    points, tris = cube([-1, -1, -1], [1, 1, 1])
    scene = make_scene(points, tris, lights=make_lights((LIGHT_DOME, [1, 1, 1], (0, 0, 0), (0, 0, -1), (0, 0))))
    tracer = Tracer.from_scene(scene)
    inside, nearest = classify_points(tracer, scene_lighting(scene, tracer.device),
                                         np.array([[0, 0, 0], [0.9, 0.2, -0.5], [3, 0, 0], [0, 0, -2.5]]))
    np.testing.assert_array_equal(inside, [True, True, False, False])
    assert nearest[0] == pytest.approx(1.0, rel=FLOAT32_ACCUMULATED)  # the axis rays meet the faces at distance 1


def test_spawn_and_ascent_add_probes_where_light_changes():
    """With a hard shadow in the room, adaptation moves and spawns probes (and respects the budget)."""
    scene, _ = room_with_boxes()
    grid_only, _ = run(scene, probes=96, rays=16, placement_rays=16, iterations=0, placement="thesis")
    adapted, _ = run(scene, probes=96, rays=16, placement_rays=16, iterations=3, placement="thesis")
    assert adapted.stats["moved"] > 0 and adapted.stats["spawned"] > 0
    assert adapted.stats["probes"] <= 96
    assert grid_only.stats["moved"] == grid_only.stats["spawned"] == 0


def test_determinism_across_thread_counts():
    scene, _ = room_with_boxes()
    one, _ = run(scene, threads=1, probes=64, rays=400, placement_rays=256)
    two, _ = run(scene, threads=2, probes=64, rays=400, placement_rays=256)
    a, b = one.products[ProbeCloud], two.products[ProbeCloud]
    np.testing.assert_array_equal(a.probe_positions, b.probe_positions)
    np.testing.assert_array_equal(a.probe_sh, b.probe_sh)
    np.testing.assert_array_equal(a.tet_vertices, b.tet_vertices)
    np.testing.assert_array_equal(a.tet_blocked, b.tet_blocked)


# -- leak fixing ---------------------------------------------------------------------------------


def wall_scene(light_left=True):
    """A 20 x 20 wall in the plane x = 0 (double-sided, black) and, optionally, a lamp on the left."""
    points, tris = quad([0, -10, -10], [0, 20, 0], [0, 0, 20])
    lights = make_lights((LIGHT_SPHERE, [200, 200, 200], (-2, 0, 0), (0, 0, -1), (0.1, 0.1))) if light_left else None
    return make_scene(points, tris, albedo=0.0, double_sided=np.ones(2, bool), lights=lights)


WALL_PROBES = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
"""Cube corners astride the wall. A query at |x| >= 0.6 has >= 80 % of its barycentric weight on its
own side (x is linear in the weights), so one of its own side's (at most 3) probes dominates
(>= 0.8 / 3 > 0.2): the leak rule must then return that side's values only."""


def test_leak_fix_with_a_wall_synthetic_values():
    """Left probes red, right probes blue: with leak fixing a query left of the wall is pure red."""
    scene = wall_scene(light_left=False)
    tracer = Tracer.from_scene(scene)
    values = np.zeros((len(WALL_PROBES), 9, 3), np.float32)
    left = WALL_PROBES[:, 0] < 0
    values[left, 0, 0] = 1.0
    values[~left, 0, 2] = 1.0
    fixed = build_cloud(WALL_PROBES, values, tracer, leak_fix=True)
    leaky = build_cloud(WALL_PROBES, values, tracer, leak_fix=False)
    edges, index = tetrahedra.edge_list(fixed.tet_vertices)
    crossing = (WALL_PROBES[edges[:, 0], 0] < 0) != (WALL_PROBES[edges[:, 1], 0] < 0)
    blocked = np.zeros(len(edges), bool)
    blocked[index[np.unpackbits(fixed.tet_blocked[:, None], axis=1, bitorder="little")[:, :6].astype(bool)]] = True
    np.testing.assert_array_equal(blocked, crossing)  # exactly the edges through the wall
    queries = np.array([[-0.6, 0.2, 0.1], [-0.8, -0.5, 0.4], [0.6, -0.2, 0.3], [0.7, 0.6, -0.6]])
    got = interpolate_sh(fixed, queries)[:, 0]
    np.testing.assert_allclose(got[:2], [[1, 0, 0], [1, 0, 0]], atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(got[2:], [[0, 0, 1], [0, 0, 1]], atol=FLOAT32_STORAGE)
    mixed = interpolate_sh(leaky, queries)[:, 0]
    assert (mixed[0, 2] > 0.05) and (mixed[2, 0] > 0.05)  # without the fix, light leaks through


def test_visibility_keeps_a_query_on_its_side_where_the_weight_rule_cannot():
    """Left probes red at x = -1, right probes blue at x = +0.2: a query at x = -0.1 has most of its
    barycentric weight on the right, so the blocked-edge rule takes the wrong side; with a tracer the
    lookup drops the probes the wall hides and is pure red."""
    scene = wall_scene(light_left=False)
    tracer = Tracer.from_scene(scene)
    positions = WALL_PROBES * np.where(WALL_PROBES[:, :1] < 0, 1.0, [0.2, 1.0, 1.0])
    values = np.zeros((len(positions), 9, 3), np.float32)
    left = positions[:, 0] < 0
    values[left, 0, 0] = 1.0
    values[~left, 0, 2] = 1.0
    cloud = build_cloud(positions, values, tracer, leak_fix=True)
    queries = np.array([[-0.1, 0.2, 0.1], [-0.05, -0.5, 0.4], [0.1, -0.2, 0.3]])
    by_rule = interpolate_sh(cloud, queries)[:, 0]
    assert by_rule[0, 2] > 0.5  # the rule puts the first query on the right
    seen = interpolate_sh(cloud, queries, tracer)[:, 0]
    np.testing.assert_allclose(seen, [[1, 0, 0], [1, 0, 0], [0, 0, 1]], atol=FLOAT32_STORAGE)


def test_leak_fix_with_a_wall_captured_light():
    """A lamp left of the wall: right of the wall, interpolated irradiance stays dark with the fix."""
    scene = wall_scene(light_left=True)
    tracer = Tracer.from_scene(scene)
    probe_sh = compute_probe_sh(tracer, scene, WALL_PROBES, rays=64, seed=1)
    right = WALL_PROBES[:, 0] > 0
    assert np.abs(probe_sh[right]).max() < FLOAT32_STORAGE and probe_sh[~right, 0, 0].min() > 0
    fixed = build_cloud(WALL_PROBES, probe_sh, tracer, leak_fix=True)
    leaky = build_cloud(WALL_PROBES, probe_sh, tracer, leak_fix=False)
    query = np.array([[0.7, 0.1, 0.2]])
    normal = np.array([[-1.0, 0.0, 0.0]])
    # x = 0.7 keeps 15 % of its weight on the lit side: without the fix, that much light leaks through
    assert irradiance_at(leaky, query, normal)[0, 0] > 0.05 * irradiance_at(leaky, -query, normal)[0, 0]
    assert abs(irradiance_at(fixed, query, normal)[0, 0]) < FLOAT32_STORAGE


# -- interpolation API ---------------------------------------------------------------------------


def test_interpolate_at_probes_returns_their_sh_and_irradiance_matches_evaluation():
    rng = np.random.default_rng(8)  # fixed seed
    positions = rng.random((30, 3)).astype(np.float32) * 4
    values = rng.normal(size=(30, 9, 3)).astype(np.float32)
    cloud = build_cloud(positions, values)  # no tracer: no leak fixing
    np.testing.assert_allclose(interpolate_sh(cloud, positions), values, atol=FLOAT32_ACCUMULATED)
    points = rng.random((50, 3)) * 4
    normals = random_dirs(50, seed=9)
    expected = np.einsum("nk,nkc->nc", sh.sh_basis_np(normals), interpolate_sh(cloud, points))
    np.testing.assert_allclose(irradiance_at(cloud, points, normals), expected, rtol=FLOAT32_ACCUMULATED,
                               atol=FLOAT32_ACCUMULATED)
    # a linear field in the SH coefficients is reproduced inside the hull
    a = rng.normal(size=(3, 27))
    linear = (positions.astype(np.float64) @ a).reshape(-1, 9, 3).astype(np.float32)
    cloud = build_cloud(positions, linear)
    _, _, inside = tetrahedra.locate(cloud.tetra, points)
    got = interpolate_sh(cloud, points[inside])
    np.testing.assert_allclose(got, (points[inside] @ a).reshape(-1, 9, 3), atol=FLOAT32_LONG_CHAIN)  # float32 storage


# -- processor contract ----------------------------------------------------------------------------


def test_applies_reasons():
    points, tris = quad([0, 0, 0], [1, 0, 0], [0, 1, 0])
    ok, reason = lp.LightProbes().applies(base_context(make_scene(points, tris)))
    assert not ok and "no lights" in reason
    empty = make_scene(np.zeros((0, 3)), np.zeros((0, 3)),
                       lights=make_lights((LIGHT_DOME, [1, 1, 1], (0, 0, 0), (0, 0, -1), (0, 0))))
    ok, reason = lp.LightProbes().applies(base_context(empty))
    assert not ok and "no empty space" in reason
    dark = make_scene(points, tris, lights=make_lights((LIGHT_DOME, [0, 0, 0], (0, 0, 0), (0, 0, -1), (0, 0))))
    assert not lp.LightProbes().applies(base_context(dark))[0]


@pytest.mark.parametrize("bad", [{"probes": 2}, {"rays": 0}, {"contrast": 1.5}, {"min_spacing": -1.0},
                                 {"iterations": -1}])
def test_bad_params(bad):
    with pytest.raises(ParamError):
        lp.LightProbes.Params(**bad)


def test_everything_inside_geometry_is_a_clear_error():
    points, tris = cube([-1, -1, -1], [1, 1, 1])
    scene = make_scene(points, tris, lights=make_lights((LIGHT_DOME, [1, 1, 1], (0, 0, 0), (0, 0, -1), (0, 0))))
    with pytest.raises(ValueError, match="empty space"):
        run(scene, probes=16)


def test_outputs_cover_the_schema():
    scene, _ = room_with_boxes()
    result, _ = run(scene, probes=48, rays=16, placement_rays=16, iterations=1)
    names = {getattr(r, "name", None) for r in result.outputs}
    assert {"probePositions", "shCoefficients", "tetrahedra", "tetNeighbors", "shOrder", "shBasis",
            "bake:tetBlockedEdges"} <= names
    cloud = result.products[ProbeCloud]
    assert np.isfinite(cloud.probe_sh).all()
    assert cloud.tet_vertices.shape[1] == 4 and cloud.tet_neighbors.shape == cloud.tet_vertices.shape


# -- end to end through USD ------------------------------------------------------------------------


def read_cloud(path):
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    prim = stage.GetPrimAtPath(lp.CLOUD_PRIM)
    assert prim and prim.GetTypeName() == "LightProbeCloud"
    get = lambda name: prim.GetAttribute(name).Get()  # noqa: E731
    assert get("shOrder") == 2 and get("shBasis") == "realOrthonormal"
    positions = np.asarray(get("probePositions"), np.float32)
    coefficients = np.asarray(get("shCoefficients"), np.float32)
    assert coefficients.shape == (9 * len(positions), 3)
    return stage, cloud_from_arrays(positions, coefficients, np.asarray(get("tetrahedra")),
                                       np.asarray(get("tetNeighbors")), np.asarray(get("bake:tetBlockedEdges")))


def test_end_to_end_small_stage(tmp_path):
    from lit_scenes import lamp_room_file
    from usdbake.cli.main import main

    source = lamp_room_file(tmp_path)
    out = tmp_path / "room_probes.usdc"
    code = main(["bake", str(source), "-o", str(out), "-p", "light_probes", "--cache", str(tmp_path / "cache"),
                 "--set", "light_probes.probes=64", "--set", "light_probes.rays=64"])
    assert code == 0
    _, cloud = read_cloud(out)
    assert 4 <= len(cloud.probe_positions) <= 64
    inside_box = ((cloud.probe_positions > [-1, -1, 0]) & (cloud.probe_positions < [1, 1, 1])).all(axis=1)
    assert not inside_box.any()
    np.testing.assert_allclose(interpolate_sh(cloud, cloud.probe_positions), cloud.probe_sh,
                               atol=FLOAT32_ACCUMULATED)
    # The lamp is at (1.5, 1.5, 2.5): probes near it see more light than probes at the far corner.
    dc = cloud.probe_sh[:, 0] @ [0.2126, 0.7152, 0.0722]
    d = np.linalg.norm(cloud.probe_positions - [1.5, 1.5, 2.5], axis=1)
    assert dc[d < np.percentile(d, 25)].mean() > dc[d > np.percentile(d, 75)].mean()


def test_end_to_end_atrium(tmp_path):
    """samples/atrium.usda at defaults through the CLI (a few seconds on 2 cores)."""
    from usdbake.cli.main import main

    out = tmp_path / "atrium_probes.usdc"
    code = main(["bake", str(REPO / "samples" / "atrium.usda"), "-o", str(out), "-p", "light_probes",
                 "--cache", str(tmp_path / "cache")])
    assert code == 0
    _, cloud = read_cloud(out)
    assert 200 <= len(cloud.probe_positions) <= 1024
    assert np.isfinite(cloud.probe_sh).all()
    # Interpolation everywhere in the courtyard volume is finite and blends at most 4 probes.
    lo, hi = cloud.probe_positions.min(axis=0), cloud.probe_positions.max(axis=0)
    points = lo + np.random.default_rng(1).random((500, 3)) * (hi - lo)  # fixed seed
    e = irradiance_at(cloud, points, random_dirs(500, seed=2))
    assert np.isfinite(e).all()


# -- hostile input ---------------------------------------------------------------------------------


def scaled(scene: Scene, factor: float) -> Scene:
    import dataclasses

    return dataclasses.replace(scene, points=(scene.points * factor).astype(np.float32),
                               tri_areas=(scene.tri_areas * factor * factor).astype(np.float32))


@pytest.mark.parametrize("factor", [2.0 ** -10, 2.0 ** 10])
def test_scale_invariance(factor):
    """Only distant and dome lights: irradiance does not depend on the scene's size, and every length
    the placement uses is relative to it. Scaling by a power of two is exact in floating point, so
    the scaled room must give exactly the scaled cloud: any absolute length would show here."""
    scene, _ = room_with_boxes()
    base, _ = run(scene, probes=64, rays=64, placement_rays=16)
    big, _ = run(scaled(scene, factor), probes=64, rays=64, placement_rays=16)
    a, b = base.products[ProbeCloud], big.products[ProbeCloud]
    assert len(a.probe_positions) == len(b.probe_positions)
    np.testing.assert_allclose(b.probe_positions / factor, a.probe_positions, rtol=FLOAT32_STORAGE,
                               atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(b.probe_sh, a.probe_sh, rtol=FLOAT32_ACCUMULATED,
                               atol=FLOAT32_ACCUMULATED * np.abs(a.probe_sh).max())


@pytest.mark.parametrize("factor", [1e-3, 1e3])
def test_grid_placement_at_other_scales(factor):
    """At non-power-of-two scales float32 rounding differs, and the adaptive rounds (thresholds on
    Monte Carlo estimates) may then diverge; the grid placement and the capture must not."""
    scene, _ = room_with_boxes()
    base, _ = run(scene, probes=64, rays=64, placement_rays=16, iterations=0)
    big, _ = run(scaled(scene, factor), probes=64, rays=64, placement_rays=16, iterations=0)
    a, b = base.products[ProbeCloud], big.products[ProbeCloud]
    assert len(a.probe_positions) == len(b.probe_positions)
    np.testing.assert_allclose(b.probe_positions / factor, a.probe_positions, atol=FLOAT32_ACCUMULATED)  # float32 of ~5
    # Same directions (seeded per ray); a hit point moved by float32 rounding could flip one shadow ray
    # (measured: none do here).
    np.testing.assert_allclose(b.probe_sh, a.probe_sh, atol=FLOAT32_LONG_CHAIN * np.abs(a.probe_sh).max())


def test_degenerate_triangles_do_not_produce_nan():
    scene, _ = room_with_boxes()
    points = np.concatenate([scene.points, [[0, 0, 1], [0, 0, 1], [0, 0, 1], [1, 1, 1], [2, 2, 2], [3, 3, 3]]])
    n = len(scene.points)
    tris = np.concatenate([scene.tri_vertices, [[n, n + 1, n + 2], [n + 3, n + 4, n + 5]]])  # a point, a line
    hostile = make_scene(points, tris, lights=scene.lights)
    result, _ = run(hostile, probes=48, rays=16, placement_rays=16)
    cloud = result.products[ProbeCloud]
    assert np.isfinite(cloud.probe_sh).all() and np.isfinite(cloud.probe_positions).all()


def _room_on_a_lawn():
    """A 4 x 4 x 3 m open-top room (walls facing in) on a 200 m ground plane, lit by a dome (Z up, metres)."""
    from pxr import UsdLux

    from stage_builders import add_mesh, new_stage

    stage = new_stage(up_axis="Z")
    add_mesh(stage, "/World/Ground", [(-100, -100, 0), (100, -100, 0), (100, 100, 0), (-100, 100, 0)], [4],
             [0, 1, 2, 3])
    box = [(x, y, z) for z in (0, 3) for y in (-2, 2) for x in (-2, 2)]
    outward = [[0, 2, 3, 1], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    add_mesh(stage, "/World/Room", box, [4] * 5, [i for face in outward for i in face[::-1]])
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(1.0)
    return stage


def test_without_a_probe_volume_probes_surround_the_receivers_not_the_backdrop():
    """The same room on a lawn without a probe volume: the ground plane is a backdrop (16x wider than the
    room on two axes), so the probes go around the room (its bounds grown by RECEIVER_MARGIN of their
    diagonal), some of them inside it, and the result names the backdrop it left out."""
    from usdbake.stages.extract import extract_scene

    scene = extract_scene(_room_on_a_lawn())
    backdrops, others = backdrop_prims(scene)
    assert [scene.prim_paths[b] for b in backdrops] == ["/World/Ground"]
    result, _ = run(scene, probes=64, iterations=1, rays=16, placement_rays=16)
    world = result.products[ProbeCloud].probe_positions + scene.origin
    margin = RECEIVER_MARGIN * np.linalg.norm([4, 4, 3])
    assert ((world >= np.array([-2, -2, 0]) - margin) & (world <= np.array([2, 2, 3]) + margin)).all()
    assert ((world > [-2, -2, 0]) & (world < [2, 2, 3])).all(axis=1).sum() >= 4
    assert any("/World/Ground" in m for m in result.messages)


def test_probes_go_where_the_probe_volume_is():
    """The room on a lawn with a ProbeVolumeAPI cube around the room: every probe lies in the room's volume;
    the result says which volumes it used."""
    from pxr import Gf, UsdGeom

    from usdbake.stages.extract import extract_scene

    stage = _room_on_a_lawn()
    params = {"probes": 64, "iterations": 1, "rays": 16, "placement_rays": 16}
    cube = UsdGeom.Cube.Define(stage, "/World/RoomVolume")
    UsdGeom.Xformable(cube).AddTranslateOp().Set(Gf.Vec3d(0, 0, 1.5))
    UsdGeom.Xformable(cube).AddScaleOp().Set(Gf.Vec3f(2, 2, 1.5))
    cube.GetPrim().ApplyAPI("ProbeVolumeAPI")
    scene = extract_scene(stage)
    result, _ = run(scene, **params)
    world = result.products[ProbeCloud].probe_positions + scene.origin
    assert len(world) >= 8
    assert ((world >= [-2, -2, 0]) & (world <= [2, 2, 3])).all()
    assert result.stats["probe_volumes"] == 1.0
    assert any("probe volume(s)" in m for m in result.messages)
