"""Tracer: closest-hit and any-hit queries on analytic geometry, chunked CPU
launches, scale invariance, and degenerate input."""

import numpy as np
import pytest
import warp as wp

from tolerances import FLOAT32_ACCUMULATED, FLOAT32_STORAGE, GRAZING_RAY_FLIPS
from usdbake.processors.occlusion.ambient_occlusion import compute_vertex_ao
from usdbake.kernels.tracer import MIN_CHUNK, RAY_EPSILON_RELATIVE, Tracer, trace_scale

wp.set_module_options({"enable_backward": False})

CUBE_FACES = {
    # face name: (outward normal, 4 corners counter-clockwise seen from outside)
    "-x": ((-1, 0, 0), [0, 4, 6, 2]),
    "+x": ((1, 0, 0), [1, 3, 7, 5]),
    "-y": ((0, -1, 0), [0, 1, 5, 4]),
    "+y": ((0, 1, 0), [2, 6, 7, 3]),
    "-z": ((0, 0, -1), [0, 2, 3, 1]),
    "+z": ((0, 0, 1), [4, 5, 7, 6]),
}
"""The unit cube [0,1]^3; corner k has coordinates (k & 1, k >> 1 & 1, k >> 2 & 1)."""


def unit_cube() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(8, 3) points, (12, 3) outward-wound triangles, (12,) face index, (6, 3) face normals."""
    points = np.array([[k & 1, k >> 1 & 1, k >> 2 & 1] for k in range(8)], np.float32)
    triangles, tri_face, normals = [], [], []
    for face, (normal, (a, b, c, d)) in enumerate(CUBE_FACES.values()):
        triangles += [[a, b, c], [a, c, d]]
        tri_face += [face, face]
        normals.append(normal)
    return points, np.array(triangles, np.int32), np.array(tri_face), np.array(normals, np.float32)


def floor_and_box(scale: float) -> tuple[np.ndarray, np.ndarray]:
    """A 4 x 4 floor (z = 0, normal +z) with a unit box standing on its centre, times ``scale``."""
    floor = [[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]]
    box = [[x, y, z] for z in (0, 1) for y in (-0.5, 0.5) for x in (-0.5, 0.5)]
    points = np.array(floor + box, np.float64) * scale
    triangles = [[0, 1, 2], [0, 2, 3]]
    _, cube_tris, _, _ = unit_cube()
    triangles += (cube_tris + 4).tolist()  # same corner numbering as unit_cube
    return points.astype(np.float32), np.array(triangles, np.int32)


def test_closest_hit_from_outside_hits_each_cube_face_at_analytic_distance():
    points, triangles, tri_face, normals = unit_cube()
    tracer = Tracer(points, triangles)
    rng = np.random.default_rng(1)  # fixed seed: reproducible targets and ray directions
    per_face = 64
    origins, directions, targets, faces, distances = [], [], [], [], []
    for face, normal in enumerate(normals):
        axis = int(np.flatnonzero(normal)[0])
        # Targets strictly inside the face (off its edges and diagonal), origins outside on its side: the cube
        # is convex, so the first thing such a segment meets is the target.
        target = rng.uniform(0.05, 0.95, (per_face, 3))
        target[:, axis] = 1.0 if normal[axis] > 0 else 0.0
        away = normal + rng.uniform(-0.7, 0.7, (per_face, 3)) * (normal == 0)
        away /= np.linalg.norm(away, axis=1, keepdims=True)
        distance = rng.uniform(0.5, 3.0, per_face)
        origins.append(target + away * distance[:, None])
        # Directions of arbitrary length: t is a distance along the unit direction.
        directions.append(-away * rng.uniform(0.1, 10.0, (per_face, 1)))
        targets.append(target)
        faces.append(np.full(per_face, face))
        distances.append(distance)
    hits = tracer.closest_hit(np.concatenate(origins), np.concatenate(directions))
    targets, faces = np.concatenate(targets), np.concatenate(faces)

    np.testing.assert_allclose(hits.hit_t, np.concatenate(distances), rtol=FLOAT32_ACCUMULATED)
    np.testing.assert_array_equal(tri_face[hits.hit_triangle], faces)
    assert hits.hit_front.all()
    corners = points[triangles[hits.hit_triangle]]  # (N, 3 corners, 3)
    u, v = hits.hit_uv[:, 0:1], hits.hit_uv[:, 1:2]
    rebuilt = u * corners[:, 0] + v * corners[:, 1] + (1 - u - v) * corners[:, 2]
    np.testing.assert_allclose(rebuilt, targets, rtol=0, atol=FLOAT32_ACCUMULATED)
    assert (hits.hit_uv >= -FLOAT32_ACCUMULATED).all()
    assert (hits.hit_uv.sum(axis=1) <= 1 + FLOAT32_ACCUMULATED).all()


def test_closest_hit_from_inside_meets_back_faces():
    points, triangles, tri_face, normals = unit_cube()
    tracer = Tracer(points, triangles)
    rng = np.random.default_rng(2)  # fixed seed: reproducible origins
    origins = np.repeat(rng.uniform(0.2, 0.8, (16, 3)), len(normals), axis=0)
    directions = np.tile(normals, (16, 1))
    hits = tracer.closest_hit(origins, directions)
    axis = np.abs(directions).argmax(axis=1)
    coordinate = origins[np.arange(len(origins)), axis]
    expected = np.where(directions[np.arange(len(origins)), axis] > 0, 1.0 - coordinate, coordinate)
    np.testing.assert_allclose(hits.hit_t, expected, rtol=FLOAT32_ACCUMULATED)
    np.testing.assert_array_equal(tri_face[hits.hit_triangle], np.tile(np.arange(len(normals)), 16))
    assert not hits.hit_front.any()


def test_misses_and_zero_directions_return_inf_and_minus_one():
    points, triangles, _, normals = unit_cube()
    tracer = Tracer(points, triangles)
    origins = np.concatenate([0.5 + 2 * normals, 0.5 + 2 * normals, [[0.5, 0.5, 0.5], [0.5, 0.5, 5.0]]])
    directions = np.concatenate([normals, [[1, 1, 0]] * 6, [[0, 0, 0], [0, 0, 0]]])  # away, sideways, zero
    hits = tracer.closest_hit(origins, directions)
    np.testing.assert_array_equal(hits.hit_t, np.inf)
    np.testing.assert_array_equal(hits.hit_triangle, -1)
    assert np.isfinite(hits.hit_uv).all() and not hits.hit_front.any()
    assert not tracer.occluded(origins, directions).any()


def test_closest_hit_respects_max_t():
    points, triangles, _, _ = unit_cube()
    tracer = Tracer(points, triangles)
    origin, direction = [[0.5, 0.5, 3.0]], [[0.0, 0.0, -1.0]]  # the +z face is 2 away
    assert tracer.closest_hit(origin, direction, max_t=1.0).hit_triangle[0] == -1
    np.testing.assert_allclose(tracer.closest_hit(origin, direction, max_t=3.0).hit_t, [2.0], rtol=FLOAT32_ACCUMULATED)


def test_occluded_respects_max_t():
    # A blocker quad at z = 2 above the origin.
    points = np.array([[-1, -1, 2], [1, -1, 2], [1, 1, 2], [-1, 1, 2]], np.float32)
    tracer = Tracer(points, [[0, 1, 2], [0, 2, 3]])
    origins = np.zeros((3, 3))
    directions = np.array([[0, 0, 1], [0, 0, 1], [0, 0, -1]])
    assert tracer.occluded(origins[:1], directions[:1], max_t=3.0).tolist() == [True]
    assert tracer.occluded(origins[:1], directions[:1], max_t=1.0).tolist() == [False]
    # Default max_t is unbounded; pointing away never occludes.
    np.testing.assert_array_equal(tracer.occluded(origins, directions), [True, True, False])


def big_ray_batch(count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays over a z = 0 floor, each with its own height (so its own hit_t); every 7th points up and misses.

    Returns origins, directions and the expected hit_t, each row unique to its index.
    """
    index = np.arange(count)
    heights = 1.0 + index / count  # distinct in float32 (step 1/count >> ulp(2) = 2.4e-7 for count < 4e6)
    x = (index % 1000) / 1000.0 * 3.8 - 1.9
    y = (index // 1000 % 1000) / 1000.0 * 3.8 - 1.9
    origins = np.stack([x, y, heights], axis=1)
    up = index % 7 == 0
    directions = np.where(up[:, None], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0])
    return origins, directions, np.where(up, np.inf, heights)


def test_chunked_closest_hit_is_bit_exact_across_thread_counts_and_covers_every_ray():
    count = 150_001  # > 100k and not a multiple of the chunk count
    assert count >= 2 * MIN_CHUNK  # the 2-thread run really is chunked
    points, triangles = floor_and_box(1.0)
    origins, directions, expected_t = big_ray_batch(count)
    single = Tracer(points, triangles, threads=1).closest_hit(origins, directions)
    double = Tracer(points, triangles, threads=2).closest_hit(origins, directions)
    for name in ("hit_t", "hit_triangle", "hit_uv", "hit_front"):
        np.testing.assert_array_equal(getattr(double, name), getattr(single, name), err_msg=name)
    # hit_t starts as uninitialised memory (wp.empty): an index no chunk wrote would not equal its own height.
    # Floor hits only where the box is not in the way; the box top is at z = 1 < every origin height.
    over_box = (np.abs(origins[:, :2]) <= 0.5).all(axis=1)
    expected_t = np.where(over_box & np.isfinite(expected_t), expected_t - 1.0, expected_t)
    keep = ~(np.isclose(np.abs(origins[:, :2]), 0.5).any(axis=1))  # skip rays grazing the box's edges
    np.testing.assert_allclose(double.hit_t[keep], expected_t[keep], rtol=FLOAT32_ACCUMULATED)
    np.testing.assert_array_equal(double.hit_triangle[np.isinf(expected_t)], -1)


@wp.kernel
def count_items_kernel(start: int, counts: wp.array(dtype=int)):
    """Test-only: count how often Tracer.launch visits each item."""
    wp.atomic_add(counts, start + wp.tid(), 1)


@pytest.mark.parametrize("dim", [1, 2 * MIN_CHUNK - 1, 2 * MIN_CHUNK, 100_003])
def test_launch_visits_every_index_exactly_once(dim):
    points, triangles = floor_and_box(1.0)
    tracer = Tracer(points, triangles, threads=2)
    counts = wp.zeros(dim, dtype=int, device="cpu")
    tracer.launch(count_items_kernel, dim, [counts])
    np.testing.assert_array_equal(counts.numpy(), 1)


def test_vertex_ao_is_bit_exact_across_thread_counts():
    # The RNG is seeded by the global receiver index, so chunking must not change a single ray.
    points, triangles = floor_and_box(1.0)
    rng = np.random.default_rng(3)  # fixed seed: reproducible receivers
    count = 3 * MIN_CHUNK + 17
    positions = np.column_stack([rng.uniform(-1.9, 1.9, (count, 2)), np.zeros(count)]).astype(np.float32)
    normals = np.tile(np.float32([0, 0, 1]), (count, 1))
    single = compute_vertex_ao(Tracer(points, triangles, threads=1), positions, normals, samples=16, seed=5)
    double = compute_vertex_ao(Tracer(points, triangles, threads=2), positions, normals, samples=16, seed=5)
    np.testing.assert_array_equal(double, single)


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_epsilon_scales_with_scene_diagonal(scale):
    points, triangles = floor_and_box(scale)
    diagonal = np.linalg.norm([4.0, 4.0, 1.0]) * scale
    np.testing.assert_allclose(Tracer(points, triangles).epsilon, RAY_EPSILON_RELATIVE * diagonal, rtol=FLOAT32_STORAGE)


def test_ao_next_to_box_is_scale_invariant():
    samples = 256
    # Same seed, same receivers in relative terms: the rays are the same up to float32 rounding, which may flip a
    # ray that grazes an edge.
    flip_tol = GRAZING_RAY_FLIPS / samples
    x = np.linspace(0.52, 1.9, 48)  # floor points from just beside the box (x = 0.5) out to the floor's edge
    receivers = np.column_stack([x, 0.25 * np.ones_like(x), np.zeros_like(x)])
    normals = np.tile([0.0, 0.0, 1.0], (len(x), 1))
    results = {}
    for scale in (1.0, 1e-3, 1e3):
        tracer = Tracer(*floor_and_box(scale))
        results[scale] = compute_vertex_ao(tracer, receivers * scale, normals, samples=samples, seed=9)
    # The box really occludes: AO rises from ~1/2 at the wall towards the open floor.
    assert results[1.0][0] < 0.6 and results[1.0][-1] > results[1.0][0] + 0.2
    np.testing.assert_allclose(results[1e-3], results[1.0], rtol=0, atol=flip_tol)
    np.testing.assert_allclose(results[1e3], results[1.0], rtol=0, atol=flip_tol)


@pytest.mark.parametrize("scale", [2.0 ** -60, 2.0 ** -40, 2.0 ** 40, 2.0 ** 60])
def test_a_scene_scaled_by_a_power_of_two_is_traced_bit_for_bit_alike(scale):
    """Issue 27: at 1e12 the watertight test's t (a product of three coordinates) overflowed float32 and AO
    was 1 everywhere; below ~1e-13 it fell into denormals. The ray core stores a scene far from unit size
    scaled by a power of two (``trace_scale``), so a scene scaled by one traces exactly as the unscaled one:
    the same triangles, t scaled, barycentrics and AO equal bit for bit."""
    points, triangles = floor_and_box(1.0)
    reference = Tracer(points, triangles)
    scaled = Tracer(points * np.float32(scale), triangles)
    assert reference.scale == 1.0 and 0.5 <= scaled.scale * scale * np.linalg.norm([4.0, 4.0, 1.0]) <= 2.0
    rng = np.random.default_rng(11)  # fixed seed: the same rays every run
    origins = rng.uniform(-2.5, 2.5, (20000, 3)).astype(np.float32)
    directions = rng.normal(size=(20000, 3)).astype(np.float32)
    hits, scaled_hits = reference.closest_hit(origins, directions), scaled.closest_hit(origins * np.float32(scale),
                                                                                       directions)
    assert (hits.hit_triangle >= 0).mean() > 0.15  # rays meet the floor or the box, not only misses
    np.testing.assert_array_equal(scaled_hits.hit_triangle, hits.hit_triangle)
    np.testing.assert_array_equal(scaled_hits.hit_t, hits.hit_t * np.float32(scale))
    np.testing.assert_array_equal(scaled_hits.hit_uv, hits.hit_uv)
    x = np.linspace(0.5, 1.9, 32)  # from the box's wall (an edge: surface_origin's neighbourhood query) outwards
    receivers = np.column_stack([x, 0.25 * np.ones_like(x), np.zeros_like(x)]).astype(np.float32)
    normals = np.tile([0.0, 0.0, 1.0], (len(x), 1))
    ao = compute_vertex_ao(reference, receivers, normals, samples=64, seed=3)
    assert ao.min() < 0.7
    np.testing.assert_array_equal(compute_vertex_ao(scaled, receivers * np.float32(scale), normals, samples=64,
                                                    seed=3), ao)


@pytest.mark.parametrize("diagonal, scale", [(0.0, 1.0), (1e-6, 1.0), (960.0, 1.0), (1e6, 1.0), (1e-9, 2.0 ** 30),
                                             (1e15, 2.0 ** -50), (float("inf"), 1.0)])
def test_trace_scale_leaves_ordinary_scenes_alone(diagonal, scale):
    """1 within TRACE_SCALE_RANGE (2^-20 to 2^20: every sample stage traces exactly as before), else the
    power of two nearest to 1 / diagonal."""
    assert trace_scale(diagonal) == scale


@pytest.mark.parametrize("points", [np.zeros((0, 3)), np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])],
                         ids=["no-points", "points-only"])
def test_empty_scene_never_hits(points):
    tracer = Tracer(points, np.zeros((0, 3), np.int32))
    # Rays straight through the origin and the first point, where the placeholder triangle sits.
    origins = np.array([[0, 0, 1], [0, 0, -1], [1, 2, 4], [5, 5, 5]], np.float32)
    directions = np.array([[0, 0, -1], [0, 0, 1], [0, 0, -1], [-1, -1, -1]], np.float32)
    hits = tracer.closest_hit(origins, directions)
    np.testing.assert_array_equal(hits.hit_triangle, -1)
    np.testing.assert_array_equal(hits.hit_t, np.inf)
    assert not tracer.occluded(origins, directions).any()
    assert np.isfinite(tracer.epsilon) and tracer.epsilon > 0
    ao = compute_vertex_ao(tracer, origins, np.tile([0.0, 0.0, 1.0], (4, 1)), samples=16)
    np.testing.assert_array_equal(ao, 1.0)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_points_raise(bad):
    points, triangles, _, _ = unit_cube()
    points[3, 1] = bad
    with pytest.raises(ValueError, match="NaN or inf"):
        Tracer(points, triangles)


def test_degenerate_triangles_are_never_hit():
    points = np.array([
        [0, 0, 0], [1, 0, 0], [0.5, 0, 0],   # a segment on the x axis (and its midpoint)
        [2, 0, 0], [3, 0, 0], [2, 1, 0],     # one good triangle
    ], np.float32)
    triangles = np.array([
        [0, 1, 1],  # duplicated vertex
        [0, 1, 2],  # collinear, zero area
        [2, 2, 2],  # a point
        [3, 4, 5],  # the only real triangle
    ], np.int32)
    tracer = Tracer(points, triangles)
    # Rays straight down through the degenerate triangles' points and segment, grazing along it, and one at the
    # good triangle.
    origins = np.array([[0.5, 0, 1], [0.25, 0, 1], [0, 0, 1], [1, 0, 1], [-1, 0, 0], [2.25, 0.25, 1]], np.float32)
    directions = np.array([[0, 0, -1]] * 4 + [[1, 0, 0], [0, 0, -1]], np.float32)
    hits = tracer.closest_hit(origins, directions)
    np.testing.assert_array_equal(hits.hit_triangle, [-1, -1, -1, -1, -1, 3])
    np.testing.assert_allclose(hits.hit_t[-1], 1.0, rtol=FLOAT32_ACCUMULATED)
    np.testing.assert_array_equal(tracer.occluded(origins, directions), [False] * 5 + [True])
