"""The ray core (kernels.traversal, kernels.bvh_build, kernels.trace_instances through kernels.tracer.Tracer)
against independent references, never against stored outputs:

- closest hit and any hit on random triangle soups (hypothesis) against a float64 brute force over every
  triangle (Moller-Trumbore), at 1e-3 to 1e4 scales and 1e5 units from the origin, with max_t limits;
- watertightness: rays from inside closed meshes aimed exactly at their vertices and shared edges all hit;
- two-level instancing against the same scene traced flat (a PointInstancer with rotated, non-uniformly
  scaled and mirrored instances), and ray origins from ``surface_origin`` that do not hit their own face;
- bit-identical results for any CPU thread count; ``trace_any_in_instance`` on ``Tracer.of_meshes``;
- degenerate input (no triangles, only zero-area ones, NaN points);
- the native source (kernels/native) ships with the package.

Rays the float64 reference cannot decide for float32 input are left out of the exact comparisons: those
passing within FLOAT32_ACCUMULATED (in barycentrics, widened as 1 / cosine at grazing incidence) of an
edge of a triangle ahead, and grazing hits (cosine below GRAZING_COSINE), whose distance float32 resolves
only to eps / cosine.
"""

from __future__ import annotations

import tomllib
from fnmatch import fnmatch

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st
from instanced_scenes import icosphere
from repo_paths import REPO
from tolerances import INSTANCE_TRANSFORM_FLIPS, FLOAT32_ACCUMULATED, FLOAT32_LONG_CHAIN, FLOAT32_STORAGE
from usdbake.kernels import tracer as tracer_module
from usdbake.kernels.tracer import Tracer
from usdbake.kernels.traversal import NATIVE, TraceScene, surface_origin, trace_any_in_instance

wp.set_module_options({"enable_backward": False})

PROPERTY = settings(derandomize=True, max_examples=25, deadline=None, database=None)
"""Fixed examples (reproducible in CI, nothing written to a .hypothesis folder), each a whole scene and
hundreds of rays: ~25 scenes keep this file within seconds."""

RAYS = 400
"""Rays per random scene: half aimed at a random point of a random triangle, half in random directions."""

GRAZING_COSINE = 0.05
"""Hits with |cos(ray, normal)| below this are grazing: their float32 distance is good to ~eps / cosine
relative, beyond FLOAT32_ACCUMULATED (a classification, not a tolerance: such rays are left out)."""

INSTANCE_MISMATCH_SHARE = INSTANCE_TRANSFORM_FLIPS
"""Share of rays that may meet a different triangle in the two-level scene than in the flat one
(tolerances.INSTANCE_TRANSFORM_FLIPS)."""


# -- float64 reference ---------------------------------------------------------------------------


def brute_force(points, triangles, origins, directions):
    """Every ray against every triangle in float64 (Moller-Trumbore on the float32 input, exactly widened).

    Returns (R, T) arrays: t (distance along the unit direction to the triangle's plane), the barycentrics
    (R, T, 3) of that point in the core's convention (weights of v0, v1, v2), the |cosine| between ray and
    normal, and whether the triangle has area and is not parallel to the ray.
    """
    corners = np.asarray(points, np.float32).astype(np.float64)[np.asarray(triangles, np.int64)]
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    o = np.asarray(origins, np.float32).astype(np.float64)
    d = np.asarray(directions, np.float32).astype(np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    e1, e2 = b - a, c - a
    normal = np.cross(e1, e2)
    area2 = np.linalg.norm(normal, axis=1)
    p = np.cross(d[:, None, :], e2[None])
    det = np.einsum("tk,rtk->rt", e1, p)
    s = o[:, None, :] - a[None]
    q = np.cross(s, e1[None])
    usable = (area2 > 0)[None] & (det != 0)
    safe = np.where(usable, det, 1.0)
    w1 = np.einsum("rtk,rtk->rt", s, p) / safe
    w2 = np.einsum("rk,rtk->rt", d, q) / safe
    t = np.einsum("tk,rtk->rt", e2, q) / safe
    bary = np.stack([1.0 - w1 - w2, w1, w2], axis=-1)
    cosine = np.abs(d @ normal.T) / np.where(area2 > 0, area2, 1.0)[None]
    return t, bary, cosine, usable


def reference(points, triangles, origins, directions, max_t, size):
    """What the core must report, from ``brute_force``: a dict of per-ray arrays.

    near_t, near_triangle, second_t: the two nearest hits (t < max_t; inf and -1 without); bary: the
    barycentrics of the nearest; uv_condition: how much they amplify a relative error of the hit point;
    near_reach: the length along the ray that float32 rounding of the hit triangle's corners is relative
    to; any: some hit within max_t; decided: float32 cannot go either way (no triangle ahead passes within
    the edge band, none is met at t ~ 0 or t ~ max_t, the nearest hit is not grazing). ``size`` is the
    scene's length scale (for t ~ 0).
    """
    t, bary, cosine, usable = brute_force(points, triangles, origins, directions)
    min_bary = bary.min(axis=-1)
    ahead = usable & (t > -FLOAT32_ACCUMULATED * size)
    near_edge = ahead & (np.abs(min_bary) * cosine < FLOAT32_ACCUMULATED)
    inside = usable & (min_bary >= 0)
    at_start = inside & (np.abs(t) <= FLOAT32_ACCUMULATED * size)
    at_limit = inside & np.isfinite(max_t) & (np.abs(t - max_t) <= FLOAT32_ACCUMULATED * max_t)
    hit_t = np.where(inside & (t >= 0) & (t < max_t), t, np.inf)
    order = np.argsort(hit_t, axis=1, kind="stable")
    rows = np.arange(len(t))
    near = order[:, 0]
    near_t = hit_t[rows, near]
    second_t = hit_t[rows, order[:, 1]] if t.shape[1] > 1 else np.full(len(t), np.inf)
    grazing = np.isfinite(near_t) & (cosine[rows, near] < GRAZING_COSINE)
    # A float32 hit point is good to a few ulps of the ray's reach (its length, or the triangle's if that is
    # longer); across the triangle, as the ray sees it, that is this many times as much in barycentrics.
    corners = np.asarray(points, np.float64)[np.asarray(triangles)[near]]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    area2 = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):  # rays without a hit
        uv_condition = np.maximum(near_t, longest) * longest / (area2 * cosine[rows, near])
        # Float32 corners relative to the origin are good to a few ulps of the triangle's extent: along the
        # ray, that is this distance (it bounds t near the origin, where a relative bound cannot).
        near_reach = longest / cosine[rows, near]
    decided = ~(near_edge.any(axis=1) | at_start.any(axis=1) | at_limit.any(axis=1) | grazing)
    return {
        "near_t": near_t, "near_triangle": np.where(np.isfinite(near_t), near, -1), "second_t": second_t,
        "bary": bary[rows, near], "uv_condition": uv_condition, "near_reach": near_reach,
        "any": np.isfinite(near_t), "decided": decided,
    }


def winding_front(points, triangles, hit_triangle, directions) -> np.ndarray:
    """hit_front by its definition: dot(direction, cross(v1 - v0, v2 - v0)) < 0, in float64."""
    corners = np.asarray(points, np.float64)[np.asarray(triangles)[hit_triangle]]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return np.einsum("ij,ij->i", np.asarray(directions, np.float64), normal) < 0


# -- 1. random triangle soups against the brute force --------------------------------------------


def triangle_soup(rng, count: int, scale: float, offset: float, degenerate_share: float):
    """``count`` triangles (0.3-sized, scattered over ~1) times ``scale`` plus ``offset``, as float32.

    A share of them has exactly zero area in float32: a repeated vertex, or three points differing in x
    only (collinear whatever the rounding)."""
    centre = rng.normal(size=(count, 1, 3))
    corners = centre + 0.3 * rng.normal(size=(count, 3, 3))
    degenerate = (rng.random(count) < degenerate_share) & (np.arange(count) > 0)  # one real triangle at least
    repeated = degenerate & (rng.random(count) < 0.5)
    collinear = degenerate & ~repeated
    corners[repeated, 1] = corners[repeated, 0]
    corners[collinear, 1:, 1:] = corners[collinear, :1, 1:]
    points = (corners.reshape(-1, 3) * scale + offset).astype(np.float32)
    return points, np.arange(3 * count, dtype=np.int32).reshape(-1, 3), degenerate


def random_rays(rng, points, triangles, scale, offset, count, aim_at=None):
    """Origins around the soup; half the rays aimed at a random point of a random triangle of ``aim_at``
    (default: all), half in random directions. Direction lengths vary over 4 decades (t is a distance
    along the unit direction)."""
    aim_at = np.arange(len(triangles)) if aim_at is None else aim_at
    origins = (rng.normal(size=(count, 3)) * 2 * scale + offset).astype(np.float32)
    corners = points.astype(np.float64)[triangles[aim_at[rng.integers(0, len(aim_at), count)]]]
    weights = rng.dirichlet(np.ones(3), count)
    targets = np.einsum("rk,rkj->rj", weights, corners)
    directions = np.where((np.arange(count) % 2 == 0)[:, None], targets - origins, rng.normal(size=(count, 3)))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    directions *= 10.0 ** rng.uniform(-2, 2, (count, 1))
    return origins, directions.astype(np.float32)


soups = st.fixed_dictionaries({
    "count": st.integers(5, 200),
    "scale": st.sampled_from([1e-3, 1.0, 1e4]),
    # 1e5 units away, or 1e5 sizes for the 1e-3 scale (1e5 units would round it to one float32 ulp of 0.008)
    "far": st.booleans(),
    "degenerate_share": st.floats(0.0, 0.3),
    "seed": st.integers(0, 2**32 - 1),
    "max_t_quantile": st.floats(0.1, 0.9),
})


def soup_case(case):
    rng = np.random.default_rng(case["seed"])
    scale = case["scale"]
    offset = 1e5 * min(scale, 1.0) if case["far"] else 0.0
    points, triangles, degenerate = triangle_soup(rng, case["count"], scale, offset, case["degenerate_share"])
    # Rays aimed at zero-area triangles are test_rays_aimed_at_zero_area_triangles_never_hit's.
    aim_at = np.flatnonzero(~degenerate) if (~degenerate).any() else None
    origins, directions = random_rays(rng, points, triangles, scale, offset, RAYS, aim_at)
    return points, triangles, degenerate, origins, directions, scale


def assert_hits_match(hits, expected, points, triangles, directions, label):
    """The core's closest hits against ``reference``, on the decided rays."""
    decided = expected["decided"]
    np.testing.assert_array_equal(hits.hit_triangle[decided] >= 0, expected["any"][decided],
                                  err_msg=f"{label}: hit or miss")
    both = decided & expected["any"]
    t_error = np.abs(hits.hit_t[both] - expected["near_t"][both])
    t_tol = FLOAT32_ACCUMULATED * expected["near_t"][both] + FLOAT32_STORAGE * expected["near_reach"][both]
    assert (t_error <= t_tol).all(), f"{label}: t off by {(t_error / t_tol).max():.2f} x tol"
    assert np.isinf(hits.hit_t[decided & ~expected["any"]]).all(), f"{label}: a miss has a finite t"
    # The nearest triangle is defined where no other hit is within rounding of its distance.
    with np.errstate(invalid="ignore"):  # inf - inf for misses
        separated = both & (expected["second_t"] - expected["near_t"] > FLOAT32_ACCUMULATED * expected["near_t"])
    np.testing.assert_array_equal(hits.hit_triangle[separated], expected["near_triangle"][separated],
                                  err_msg=f"{label}: triangle")
    uv_error = np.abs(hits.hit_uv[separated] - expected["bary"][separated, :2]).max(axis=1)
    uv_tol = np.maximum(FLOAT32_LONG_CHAIN, expected["uv_condition"][separated] * FLOAT32_STORAGE)
    assert (uv_error <= uv_tol).all(), f"{label}: uv off by {(uv_error / uv_tol).max():.2f} x tol"
    hit = decided & (hits.hit_triangle >= 0)
    np.testing.assert_array_equal(hits.hit_front[hit],
                                  winding_front(points, triangles, hits.hit_triangle[hit], directions[hit]),
                                  err_msg=f"{label}: front")


@PROPERTY
@given(soups)
def test_closest_and_any_hit_match_a_float64_brute_force(case):
    """Random soups with zero-area triangles, at 1e-3 to 1e4 scales and 1e5 from the origin: hit or miss,
    distance, triangle, barycentrics and side of every decided ray, without and with max_t."""
    points, triangles, degenerate, origins, directions, scale = soup_case(case)
    tracer = Tracer(points, triangles, threads=1)
    unlimited = reference(points, triangles, origins, directions, np.inf, scale)
    assert unlimited["decided"].mean() > 0.9, "most rays must be compared (the exclusions are rare)"
    assert (unlimited["decided"] & unlimited["any"]).sum() >= RAYS // 10, "too few hits to compare"

    hits = tracer.closest_hit(origins, directions)
    assert not np.isin(hits.hit_triangle, np.flatnonzero(degenerate)).any(), "a zero-area triangle was hit"
    assert_hits_match(hits, unlimited, points, triangles, directions, "no limit")
    decided = unlimited["decided"]
    np.testing.assert_array_equal(tracer.occluded(origins, directions)[decided], unlimited["any"][decided],
                                  err_msg="any hit, no limit")

    # A max_t between the hit distances: the nearer hits stay, the farther ones become misses.
    max_t = float(np.quantile(unlimited["near_t"][unlimited["any"]], case["max_t_quantile"]))
    limited = reference(points, triangles, origins, directions, max_t, scale)
    assert limited["any"].sum() < unlimited["any"].sum(), "max_t must cut some hits"
    assert_hits_match(tracer.closest_hit(origins, directions, max_t=max_t), limited, points, triangles,
                      directions, f"max_t {max_t:g}")
    decided = limited["decided"]
    np.testing.assert_array_equal(tracer.occluded(origins, directions, max_t=max_t)[decided],
                                  limited["any"][decided], err_msg="any hit with max_t")


@pytest.mark.parametrize("size, offset", [(1.0, 0.0), (1e-3, 1e2), (1.0, 1e5)], ids=["unit", "small", "far"])
def test_max_t_keeps_every_hit_before_it(size, offset):
    """One triangle (``size``, ``offset`` from the origin: the soups' placements), rays aimed inside it from
    0.01 % to 3 % nearer or farther than max_t: exactly those meeting it before max_t hit (outside a
    FLOAT32_ACCUMULATED band around max_t), in closest_hit and occluded; no node box may be culled short
    of max_t."""
    points = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]]) * size + offset).astype(np.float32)
    tracer = Tracer(points, [[0, 1, 2]])
    rng = np.random.default_rng(13)  # fixed seed: reproducible rays
    count, max_t = 2000, 2.0 * size
    targets = (rng.dirichlet(np.ones(3), count) * 0.8 + 0.2 / 3) @ points.astype(np.float64)  # off the edges
    directions = rng.normal(size=(count, 3))
    directions[:, 2] = -np.abs(directions[:, 2]) - 0.3  # downwards, at most ~73 degrees from the normal
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    distance = max_t * (1 + np.where(np.arange(count) % 2 == 0, 1, -1) * 10 ** rng.uniform(-4, -1.5, count))
    origins = (targets - directions * distance[:, None]).astype(np.float32)
    expected = reference(points, [[0, 1, 2]], origins, directions, max_t, size)
    decided = expected["decided"]
    assert decided.mean() > 0.95 and 0.3 < expected["any"].mean() < 0.7
    hits = tracer.closest_hit(origins, directions, max_t=max_t)
    lost = decided & expected["any"] & (hits.hit_triangle < 0)
    assert not lost.any(), f"{lost.sum()} of {expected['any'].sum()} hits before max_t lost"
    np.testing.assert_array_equal(hits.hit_triangle[decided] >= 0, expected["any"][decided])
    np.testing.assert_array_equal(tracer.occluded(origins, directions, max_t=max_t)[decided], expected["any"][decided])


# -- 2. watertightness --------------------------------------------------------------------------


def unit_cube() -> tuple[np.ndarray, np.ndarray]:
    """[0, 1]^3 as 12 outward-wound triangles (corner k at (k & 1, k >> 1 & 1, k >> 2 & 1))."""
    points = np.array([[k & 1, k >> 1 & 1, k >> 2 & 1] for k in range(8)], np.float64)
    quads = [[0, 4, 6, 2], [1, 3, 7, 5], [0, 1, 5, 4], [2, 6, 7, 3], [0, 2, 3, 1], [4, 5, 7, 6]]
    return points, np.array([[a, b, c] for a, b, c, _ in quads] + [[a, c, d] for a, _, c, d in quads], np.int32)


def closed_mesh(shape: str):
    """(points, triangles, a radius inside its inscribed sphere) of a closed mesh of unit size around the
    origin."""
    if shape == "cube":
        points, triangles = unit_cube()
        return points - 0.5, triangles, 0.5
    points, triangles = icosphere(int(shape[-1]))
    return points, triangles, 0.9  # the faces of a level-2/3 icosphere are 0.98 or more from its centre


PLACEMENTS = {  # scale, offset of the centre from the origin (per axis)
    "unit": (1.0, 0.0),
    "tiny": (1e-3, 0.0),
    "huge": (1e4, 0.0),
    "far": (1.0, 1e3),
    "far and large": (1e3, 1e5),
}

EDGE_PARAMETERS = (0.5, 0.25, 1 / 3, 0.9, 1e-3)
"""Points a + s (b - a) along each edge, the midpoint first."""


@pytest.mark.parametrize("placement", list(PLACEMENTS))
@pytest.mark.parametrize("shape", ["icosphere2", "icosphere3", "cube"])
def test_closed_meshes_are_watertight(shape, placement):
    """Rays from inside aimed exactly at every vertex and at points of every shared edge (float32, as the
    tracer stores them) hit something, from the centre and from random inside points: the watertight
    triangle test must not let a ray through the crack between two triangles, and no node box may cull
    the triangles a ray meets on the box's own boundary."""
    points, triangles, inner = closed_mesh(shape)
    scale, offset = PLACEMENTS[placement]
    stored = (points * scale + offset).astype(np.float32)
    tracer = Tracer(stored, triangles)
    edges = np.unique(np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]),
                              axis=1), axis=0)
    a, b = stored[edges[:, 0]], stored[edges[:, 1]]
    targets = np.concatenate([stored] + [a + np.float32(s) * (b - a) for s in EDGE_PARAMETERS])
    centre = np.full(3, offset, np.float32)
    rng = np.random.default_rng(17)  # fixed seed: reproducible inside points
    inside = rng.normal(size=(len(targets), 3))
    inside *= (0.5 * inner * rng.random((len(targets), 1)) / np.linalg.norm(inside, axis=1, keepdims=True))
    for label, origins in (("centre", np.broadcast_to(centre, targets.shape)),
                           ("inside points", (inside * scale + offset).astype(np.float32))):
        directions = targets - origins
        hits = tracer.closest_hit(origins, directions)
        escaped = np.flatnonzero(hits.hit_triangle < 0)
        assert len(escaped) == 0, (f"{len(escaped)} of {len(targets)} rays from the {label} escaped, e.g. origin "
                                   f"{origins[escaped[0]].tolist()} direction {directions[escaped[0]].tolist()}")
        assert tracer.occluded(origins, directions).all(), f"any-hit rays from the {label} escaped"


# -- 3. instanced against flattened --------------------------------------------------------------

INSTANCES = 400


def scatter_stage(count: int = INSTANCES, seed: int = 7):
    """A 40 x 40 ground grid and a PointInstancer of ``count`` rocks (an 80-triangle icosphere, lumpy and
    squashed so it has no symmetry) with random orientations, non-uniform scales, ~15 % mirrored in x."""
    from pxr import Gf, UsdGeom, Vt
    from instanced_scenes import grid
    from stage_builders import add_mesh, new_stage

    rng = np.random.default_rng(seed)  # fixed seed: the same stage every run
    stage = new_stage()
    ground, ground_tris = grid(20, 8)
    add_mesh(stage, "/World/Ground", ground, [3] * len(ground_tris), ground_tris.ravel())
    rock, rock_tris = icosphere(1)
    rock = rock * rng.uniform(0.8, 1.2, (len(rock), 1)) * [1.0, 0.6, 0.4] + [0.3, 0.0, 0.0]
    scatter = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    add_mesh(stage, "/World/Scatter/Protos/Rock", rock, [3] * len(rock_tris), rock_tris.ravel())
    scatter.CreatePrototypesRel().SetTargets(["/World/Scatter/Protos/Rock"])
    scatter.CreateProtoIndicesAttr([0] * count)
    positions = np.c_[rng.uniform(-18, 18, count), rng.uniform(0.2, 3, count), rng.uniform(-18, 18, count)]
    scatter.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(positions.astype(np.float32)))
    quaternions = rng.normal(size=(count, 4))
    quaternions /= np.linalg.norm(quaternions, axis=1, keepdims=True)
    scatter.CreateOrientationsAttr(Vt.QuathArray([Gf.Quath(*map(float, q)) for q in quaternions]))
    scales = rng.uniform(0.5, 1.5, (count, 3))
    scales[rng.random(count) < 0.15, 0] *= -1
    scatter.CreateScalesAttr(Vt.Vec3fArray.FromNumpy(scales.astype(np.float32)))
    return stage


@pytest.fixture(scope="module")
def instanced():
    """The scatter scene, its two-level and flat tracers, and 20000 rays through it (hits and misses)."""
    from usdbake.stages.extract import extract_scene

    scene = extract_scene(scatter_stage())
    rng = np.random.default_rng(8)  # fixed seed: reproducible rays
    count = 20000
    origins = np.c_[rng.uniform(-25, 25, count), rng.uniform(0.1, 8, count), rng.uniform(-25, 25, count)]
    targets = np.c_[rng.uniform(-20, 20, count), rng.uniform(0, 3, count), rng.uniform(-20, 20, count)]
    origins -= scene.origin  # the Scene's points are relative to its origin
    targets -= scene.origin
    return {
        "scene": scene, "always": Tracer.from_scene(scene, instancing="always"),
        "never": Tracer.from_scene(scene, instancing="never"),
        "origins": origins.astype(np.float32), "directions": (targets - origins).astype(np.float32),
    }


def test_instanced_scene_is_two_level_and_smaller(instanced):
    """Every instance (mirrored ones too) is traced through its prototype's one tree, and the two-level
    scene is a small fraction of the flat one (400 x 80 triangles against 80 + 400 transforms)."""
    always, never, scene = instanced["always"], instanced["never"], instanced["scene"]
    assert len(scene.instances) == INSTANCES
    assert always.arrays.top_root >= 0 and never.arrays.top_root == -1
    assert len(always.arrays.instance_root) == INSTANCES + 1  # each instance, plus the static ground
    mirrored = np.linalg.det(np.asarray(scene.instances.instance_transforms)[:, :3, :3]) < 0
    assert mirrored.sum() > 20 and always.arrays.instance_mirrored.sum() == mirrored.sum()
    assert always.nbytes * 10 < never.nbytes, (always.nbytes, never.nbytes)


def test_instanced_hits_match_the_flattened_scene(instanced):
    """Same triangle (up to float32 rounding at borders), distance, barycentrics and any-hit as the flat
    trace of the scene's own triangles. Positions agree to FLOAT32_STORAGE of the scene diagonal (float32
    points and transforms), so t does too for hits near the origin, and a barycentric to that over the hit
    triangle's smallest height as the ray sees it (foreshortened by the cosine of incidence)."""
    scene, always, never = instanced["scene"], instanced["always"], instanced["never"]
    origins, directions = instanced["origins"], instanced["directions"]
    flat, inst = never.closest_hit(origins, directions), always.closest_hit(origins, directions)
    hit = flat.hit_triangle >= 0
    assert 0.3 < hit.mean() < 0.97 and (scene.tri_instance[flat.hit_triangle[hit]] >= 0).mean() > 0.5
    same = inst.hit_triangle == flat.hit_triangle
    assert (~same).mean() <= INSTANCE_MISMATCH_SHARE, f"{(~same).sum()} rays met another triangle"
    both = same & hit
    diagonal = float(np.linalg.norm(scene.points.max(axis=0) - scene.points.min(axis=0)))
    position_tol = FLOAT32_STORAGE * diagonal
    np.testing.assert_allclose(inst.hit_t[both], flat.hit_t[both], rtol=FLOAT32_LONG_CHAIN, atol=position_tol)
    corners = scene.points.astype(np.float64)[scene.tri_vertices[flat.hit_triangle[both]]]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area2 = np.linalg.norm(normal, axis=1)
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    d = directions[both].astype(np.float64)
    cosine = np.abs(np.einsum("ij,ij->i", d, normal)) / (np.linalg.norm(d, axis=1) * area2)
    uv_tol = position_tol / (area2 / longest * cosine)  # over the smallest height, foreshortened
    uv_error = np.abs(inst.hit_uv[both] - flat.hit_uv[both]).max(axis=1)
    assert (uv_error <= uv_tol).all(), f"uv off by {uv_error.max():.2e} ({(uv_error / uv_tol).max():.2f} x tol)"
    np.testing.assert_array_equal(always.occluded(origins, directions), never.occluded(origins, directions))


def test_instanced_hit_front_is_the_scenes_winding_side(instanced):
    """hit_front in the two-level scene is the side of the scene's triangle (mirrored instances list
    theirs with reversed winding), as in the flat scene and by the winding test."""
    scene, always, never = instanced["scene"], instanced["always"], instanced["never"]
    origins, directions = instanced["origins"], instanced["directions"]
    flat, inst = never.closest_hit(origins, directions), always.closest_hit(origins, directions)
    both = (flat.hit_triangle >= 0) & (inst.hit_triangle == flat.hit_triangle)
    expected = winding_front(scene.points, scene.tri_vertices, flat.hit_triangle[both], directions[both])
    np.testing.assert_array_equal(flat.hit_front[both], expected, err_msg="flat scene")
    instance = scene.tri_instance[flat.hit_triangle[both]]
    mirrored = np.linalg.det(np.asarray(scene.instances.instance_transforms)[:, :3, :3]) < 0
    on_mirrored = (instance >= 0) & mirrored[np.maximum(instance, 0)]
    wrong = inst.hit_front[both] != expected
    assert not wrong.any(), (f"two-level hit_front wrong on {wrong.sum()} of {both.sum()} hits, "
                             f"{wrong[on_mirrored].sum()} of {on_mirrored.sum()} on mirrored instances")


def test_mirrored_instance_reports_the_front_side():
    """The smallest case of the check above: one triangle facing +z, instanced plain and mirrored in x
    (its scene triangle is re-wound to face +z as well): a ray from above meets both fronts."""
    from pxr import Gf, UsdGeom
    from stage_builders import add_mesh, new_stage
    from usdbake.stages.extract import extract_scene

    stage = new_stage()
    scatter = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    add_mesh(stage, "/World/Scatter/Tri", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    scatter.CreatePrototypesRel().SetTargets(["/World/Scatter/Tri"])
    scatter.CreateProtoIndicesAttr([0, 0])
    scatter.CreatePositionsAttr([Gf.Vec3f(0, 0, 0), Gf.Vec3f(5, 0, 0)])
    scatter.CreateScalesAttr([Gf.Vec3f(1, 1, 1), Gf.Vec3f(-1, 1, 1)])
    scene = extract_scene(stage)
    origins = np.array([[0.25, 0.25, 1.0], [4.75, 0.25, 1.0]]) - scene.origin
    down = np.array([[0.0, 0.0, -1.0]] * 2)
    np.testing.assert_array_equal(winding_front(scene.points, scene.tri_vertices, [0, 1], down), [True, True])
    for mode in ("never", "always"):
        hits = Tracer.from_scene(scene, instancing=mode).closest_hit(origins, down)
        np.testing.assert_array_equal(hits.hit_triangle, [0, 1], err_msg=mode)
        np.testing.assert_array_equal(hits.hit_front, [True, True], err_msg=mode)


@wp.kernel
def surface_origin_kernel(scene: TraceScene, points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                          epsilon: float, origins: wp.array(dtype=wp.vec3)):
    """Test-only: ``surface_origin`` of each point (no inward tangent: points inside faces)."""
    i = wp.tid()
    origins[i] = surface_origin(scene, points[i], normals[i], wp.vec3(0.0, 0.0, 0.0), epsilon)


def test_surface_origins_on_instances_do_not_hit_their_own_face(instanced):
    """Points where rays met a front face (instances and ground), pushed off by ``surface_origin`` in each
    tracer: rays into the face's hemisphere start at most a few epsilon away and never meet that face."""
    scene, flat_tracer = instanced["scene"], instanced["never"]
    hits = flat_tracer.closest_hit(instanced["origins"], instanced["directions"])
    keep = (hits.hit_triangle >= 0) & hits.hit_front
    face = hits.hit_triangle[keep]
    corners = scene.points.astype(np.float64)[scene.tri_vertices[face]]
    u, v = hits.hit_uv[keep, :1].astype(np.float64), hits.hit_uv[keep, 1:].astype(np.float64)
    points = u * corners[:, 0] + v * corners[:, 1] + (1 - u - v) * corners[:, 2]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    rng = np.random.default_rng(9)  # fixed seed: reproducible directions
    directions = rng.normal(size=points.shape)
    directions += normals * (np.abs(np.einsum("ij,ij->i", directions, normals)) + 0.05)[:, None]  # into the front
    for mode in ("always", "never"):
        tracer = instanced[mode]
        origins = wp.zeros(len(points), dtype=wp.vec3, device=tracer.device)
        wp.launch(surface_origin_kernel, len(points), inputs=[tracer.scene, tracer.array(points, wp.vec3),
                                                              tracer.array(normals, wp.vec3), tracer.epsilon, origins],
                  device=tracer.device)
        origins = origins.numpy()
        lift = np.einsum("ij,ij->i", origins - points, normals)
        assert (lift > 0).all() and (np.linalg.norm(origins - points, axis=1) <= 4 * tracer.epsilon).all(), mode
        again = tracer.closest_hit(origins, directions)
        assert not (again.hit_triangle == face).any(), f"{mode}: {(again.hit_triangle == face).sum()} self hits"


# -- 4. thread counts -----------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["soup", "instanced"])
def test_results_are_bit_identical_for_any_thread_count(kind, instanced, monkeypatch):
    """The same rays split into chunks over 1, 2 or 3 threads (MIN_CHUNK lowered so 20000 rays make
    many chunks) give bit-identical Hits and any-hit results."""
    if kind == "soup":
        rng = np.random.default_rng(10)  # fixed seed: reproducible soup and rays
        points, triangles, _ = triangle_soup(rng, 500, 1.0, 0.0, 0.05)
        tracer = Tracer(points, triangles)
        origins, directions = random_rays(rng, points, triangles, 1.0, 0.0, 20000)
    else:
        tracer, origins, directions = instanced["always"], instanced["origins"], instanced["directions"]
    monkeypatch.setattr(tracer_module, "MIN_CHUNK", 64)
    launches = []
    launch = wp.launch
    monkeypatch.setattr(wp, "launch", lambda *args, **kwargs: (launches.append(1), launch(*args, **kwargs))[1])
    results = {}
    for threads in (1, 2, 3):
        monkeypatch.setattr(tracer, "threads", threads)
        launches.clear()
        results[threads] = tracer.closest_hit(origins, directions), tracer.occluded(origins, directions)
        assert (len(launches) == 2) == (threads == 1), f"{threads} threads: {len(launches)} launches"
    hits, occluded = results[1]
    assert (hits.hit_triangle >= 0).mean() > 0.2
    for threads in (2, 3):
        other, other_occluded = results[threads]
        for name in ("hit_t", "hit_triangle", "hit_uv", "hit_front"):
            np.testing.assert_array_equal(getattr(other, name), getattr(hits, name), err_msg=f"{threads}: {name}")
        np.testing.assert_array_equal(other_occluded, occluded, err_msg=f"{threads}: occluded")


# -- 5. one instance of Tracer.of_meshes ----------------------------------------------------------


@wp.kernel
def any_in_instance_kernel(scene: TraceScene, instance: int, origins: wp.array(dtype=wp.vec3),
                           directions: wp.array(dtype=wp.vec3), max_t: wp.array(dtype=float),
                           blocked: wp.array(dtype=wp.int32)):
    """Test-only: ``trace_any_in_instance`` per ray."""
    i = wp.tid()
    blocked[i] = wp.where(trace_any_in_instance(scene, instance, origins[i], directions[i], max_t[i]), 1, 0)


def test_trace_any_in_instance_sees_only_that_mesh():
    """Two overlapping quads, mesh 0 at z = 0 over x in [-1, 1], mesh 1 at z = 0.5 over x in [0, 2]: rays
    down from z = 2 are blocked in an instance only where its own quad lies below them (and within max_t)."""
    quad = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    mesh0 = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    mesh1 = np.array([[0, -1, 0.5], [2, -1, 0.5], [2, 1, 0.5], [0, 1, 0.5]], np.float32)
    tracer = Tracer.of_meshes([(mesh0, quad), (mesh1, quad)])
    xs = [-0.5, 1.5, 0.5, 3.0, 0.5]  # mesh 0 only, mesh 1 only, both, neither, both but max_t stops at mesh 1
    max_ts = [10.0, 10.0, 10.0, 10.0, 1.7]
    expected = {0: [1, 0, 1, 0, 0], 1: [0, 1, 1, 0, 1]}
    origins = np.array([[x, 0.1, 2.0] for x in xs], np.float32)
    down = np.tile(np.float32([0, 0, -1]), (len(xs), 1))
    for instance in (0, 1):
        blocked = wp.zeros(len(xs), dtype=wp.int32, device=tracer.device)
        wp.launch(any_in_instance_kernel, len(xs), inputs=[tracer.scene, instance, tracer.array(origins, wp.vec3),
                                                           tracer.array(down, wp.vec3),
                                                           tracer.array(np.float32(max_ts), float), blocked],
                  device=tracer.device)
        assert blocked.numpy().tolist() == expected[instance], f"instance {instance}: {blocked.numpy().tolist()}"
    # The whole scene sees both meshes.
    assert tracer.occluded(origins, down).tolist() == [True, True, True, False, True]


# -- 6. degenerate input --------------------------------------------------------------------------


def test_no_triangles_and_only_degenerate_triangles_never_hit():
    """No triangles (with and without points), or only zero-area ones: every query misses, even rays
    through the degenerate triangles' points and along their segments."""
    segment = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]], np.float32)
    degenerate = np.array([[0, 1, 2], [3, 3, 3], [0, 0, 1], [1, 3, 1]], np.int32)  # collinear, point, repeats
    origins = np.array([[0.5, 0, 1], [1, 0, 1], [0, 1, 1], [-1, 0, 0], [0.5, 0.5, 1], [0, 0, 1]], np.float32)
    directions = np.array([[0, 0, -1], [0, 0, -1], [0, 0, -1], [1, 0, 0], [0, 0, -1], [0, 0, -1]], np.float32)
    for label, tracer in (("no points", Tracer(np.zeros((0, 3)), np.zeros((0, 3), np.int32))),
                          ("no triangles", Tracer(segment, np.zeros((0, 3), np.int32))),
                          ("degenerate", Tracer(segment, degenerate)),
                          ("no meshes", Tracer.of_meshes([])),
                          ("degenerate meshes", Tracer.of_meshes([(segment, degenerate), (segment, degenerate[:1])]))):
        hits = tracer.closest_hit(origins, directions)
        np.testing.assert_array_equal(hits.hit_triangle, -1, err_msg=label)
        np.testing.assert_array_equal(hits.hit_t, np.inf, err_msg=label)
        assert not tracer.occluded(origins, directions).any(), label


def test_nan_points_raise_value_error():
    """A NaN among the points is refused, by the plain constructor and by of_meshes."""
    points, triangles = unit_cube()
    points = points.astype(np.float32)
    points[5, 2] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        Tracer(points, triangles)
    with pytest.raises(ValueError, match="NaN"), np.errstate(invalid="ignore"):
        Tracer.of_meshes([(unit_cube()[0], triangles), (points, triangles)])


def test_rays_aimed_at_zero_area_triangles_never_hit():
    """Triangles with three distinct, exactly collinear float32 corners (on an axis, and on a diagonal in
    dyadic steps) and rays from random origins aimed at points of their segment (up to float32 rounding):
    a zero-area triangle has no side and no normal, so it is never reported (test_tracer's degenerate test
    aims along the axes only)."""
    points = np.array([[0, 0, 0], [0.3, 0, 0], [1, 0, 0],
                       [0, 0, 2], [0.25, 0.5, 2.75], [0.5, 1, 3.5]], np.float32)
    tracer = Tracer(points, [[0, 1, 2], [3, 4, 5]])
    rng = np.random.default_rng(12)  # fixed seed: reproducible origins and targets
    count = 2000
    s = rng.random((count, 1))
    targets = np.where(np.arange(count)[:, None] % 2 == 0, s * points[2], points[3] + s * (points[5] - points[3]))
    origins = (rng.normal(size=(count, 3)) * 2).astype(np.float32)
    directions = (targets - origins).astype(np.float32)
    hits = tracer.closest_hit(origins, directions)
    assert (hits.hit_triangle < 0).all(), f"{(hits.hit_triangle >= 0).sum()} of {count} rays hit a zero-area triangle"
    assert not tracer.occluded(origins, directions).any()


def test_a_tree_deeper_than_the_traversal_stack_is_walked_without_overflowing_it():
    """A hand-made tree 60 levels deep, each node holding 7 leaves and the next node: walking down it needs
    420 stack entries against the 256 there are. Only the root's leaves hold the triangle (the others an
    empty packet), and the walks still find it: closest hit, any hit and surface_origin's box query leave
    out the nodes the stack has no room for rather than write past it over the entries of the root's leaves."""
    from usdbake.kernels.bvh_build import (CHILD_OFFSET, COUNT_OFFSET, NODE_FLOATS, PACKET, WIDTH, TriangleBvh,
                                           leaf_ref, single_level)

    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    packets = np.zeros((2, 9, PACKET), np.float32)  # packet 0: the triangle in lane 0; packet 1: empty
    packets[0, :, 0] = points.ravel()
    packet_triangle = np.full((2, PACKET), -1, np.int32)
    packet_triangle[0, 0] = 0
    depth = 60
    nodes = np.zeros((depth, NODE_FLOATS), np.float32)
    nodes[:, :3 * WIDTH], nodes[:, 3 * WIDTH:6 * WIDTH] = -1.0, 2.0  # every child box holds the triangle
    ints = nodes.view(np.int32)
    ints[:, CHILD_OFFSET:CHILD_OFFSET + WIDTH] = leaf_ref(1, 1)
    ints[0, CHILD_OFFSET:CHILD_OFFSET + WIDTH] = leaf_ref(0, 1)
    ints[:-1, CHILD_OFFSET + WIDTH - 1] = np.arange(1, depth)  # the last child: the next node
    ints[:, COUNT_OFFSET] = WIDTH
    tracer = Tracer(points, [[0, 1, 2]], arrays=single_level(TriangleBvh(nodes, packets, packet_triangle)))
    origin, down = np.array([[0.25, 0.25, 10.0]], np.float32), np.array([[0.0, 0.0, -1.0]], np.float32)
    hits = tracer.closest_hit(origin, down)
    assert hits.hit_triangle.tolist() == [0] and hits.hit_t.tolist() == [10.0]
    assert tracer.occluded(origin, down).tolist() == [True]
    normal = np.array([[0.6, 0.0, 0.8]], np.float32)  # tilted: the origin must be moved in front of the face
    moved = wp.zeros(1, dtype=wp.vec3, device=tracer.device)
    inputs = [tracer.scene, tracer.array(origin * [1, 1, 0], wp.vec3), tracer.array(normal, wp.vec3), tracer.epsilon]
    wp.launch(surface_origin_kernel, 1, inputs=[*inputs, moved], device=tracer.device)
    assert moved.numpy()[0, 2] >= tracer.epsilon * (1 - FLOAT32_ACCUMULATED), (moved.numpy(), tracer.epsilon)

# -- 7. the native source ------------------------------------------------------------------------


def test_native_source_ships_with_the_package():
    """Every file of kernels/native (the C++ traversal.py reads at import) is matched by pyproject's package
    data for usdbake.kernels, so an installed package can trace."""
    config = tomllib.loads((REPO / "pyproject.toml").read_text())
    patterns = config["tool"]["setuptools"]["package-data"]["usdbake.kernels"]
    files = [path.relative_to(NATIVE.parent).as_posix() for path in NATIVE.iterdir()]
    assert files and all(any(fnmatch(name, pattern) for pattern in patterns) for name in files), (files, patterns)
