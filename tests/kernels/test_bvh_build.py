"""bvh_build: copies of a triangle are traced once (issue 27, quadratic time on coincident vertices).

The ray-origin rule (``surface_origin``) visits every triangle whose box lies within 2 epsilon of a
vertex. N stacked copies of one triangle put N triangles around each of their 3N vertices: 3N^2 visits.
The build keeps the first copy only, so the work is counted here, not timed: the lanes within reach
of each vertex, summed over the vertices, for stacked copies and for as many distinct triangles.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from usdbake.kernels.bvh_build import build_triangle_bvh, first_copies
from usdbake.kernels.tracer import RAY_EPSILON_RELATIVE, Tracer

TRIANGLE = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1]], np.float32)


def copies_oracle(corners: np.ndarray) -> list[int]:
    """First index of each set of copies by brute force: a triangle is a copy of an earlier one when one of
    its three cyclic rotations equals it, value for value."""
    seen, keep = set(), []
    for index, triangle in enumerate(np.asarray(corners, np.float64)):
        rotations = {tuple(np.roll(triangle, k, axis=0).ravel()) for k in range(3)}
        if not rotations & seen:
            keep.append(index)
        seen |= rotations
    return keep


def traced_lanes(bvh) -> np.ndarray:
    """Scene triangle of every occupied lane of a TriangleBvh."""
    lanes = bvh.packet_triangle.ravel()
    return lanes[lanes >= 0]


def lanes_within_reach(bvh, points: np.ndarray, reach: float) -> int:
    """Sum over points of the lanes whose triangle box meets the cube point +- reach: the triangles the
    neighbourhood query of ``surface_origin`` tests at each point (a lower bound of its work)."""
    corners = bvh.packets.transpose(0, 2, 1).reshape(-1, 3, 3)[bvh.packet_triangle.ravel() >= 0]
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    total = 0
    for chunk in np.array_split(np.asarray(points, np.float32), max(1, len(points) // 256)):
        meets = (lo[None] <= chunk[:, None] + reach) & (hi[None] >= chunk[:, None] - reach)
        total += int(meets.all(axis=2).sum())
    return total


def test_rotated_copies_are_copies_and_a_reversed_twin_is_not():
    a, b, c = TRIANGLE
    zero_signed = TRIANGLE.copy()
    zero_signed[0, 0] = -0.0  # -0 and +0 are one coordinate
    corners = np.array([TRIANGLE, [b, c, a], [c, a, b], zero_signed, [a, c, b], TRIANGLE + 1, [c, b, a]])
    assert first_copies(corners).tolist() == [0, 4, 5]
    assert copies_oracle(corners) == [0, 4, 5]


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 12), st.lists(st.tuples(st.integers(0, 11), st.integers(0, 2)), max_size=40),
       st.integers(0, 2 ** 32 - 1))
def test_first_copies_agree_with_a_brute_force_oracle(distinct, picks, seed):
    """Triangles drawn from a few distinct ones (on a coarse grid, so some share corners), each rotated
    cyclically: the first copies are the oracle's."""
    rng = np.random.default_rng(seed)  # hypothesis draws the seed: reproducible on failure
    base = rng.integers(0, 3, (distinct, 3, 3)).astype(np.float32)
    corners = np.array([np.roll(base[k % distinct], r, axis=0) for k, r in picks], np.float32).reshape(-1, 3, 3)
    assert first_copies(corners).tolist() == copies_oracle(corners)


def test_a_stack_of_copies_is_one_traced_triangle_and_its_closest_hit_names_the_first():
    copies = 1000
    points = np.tile(TRIANGLE, (copies, 1))
    triangles = np.arange(3 * copies, dtype=np.int32).reshape(-1, 3)
    assert traced_lanes(build_triangle_bvh(points, triangles)).tolist() == [0]
    twin = np.r_[triangles, triangles[:1, ::-1]]  # and one back-to-back twin: a face of its own
    assert sorted(traced_lanes(build_triangle_bvh(points, twin)).tolist()) == [0, copies]
    hits = Tracer(points, triangles).closest_hit(np.array([[0.25, 0.25, 3.0]]), np.array([[0.0, 0.0, -1.0]]))
    assert hits.hit_triangle.tolist() == [0] and hits.hit_front.tolist() == [True]
    assert hits.hit_t.tolist() == [2.0]


def test_neighbourhood_work_on_stacked_copies_is_at_most_that_of_distinct_triangles():
    """The issue's target, counted: coincident vertices cost no more than twice distinct ones. N copies of
    one triangle against N distinct triangles of its size (scattered, fixed seed), same diagonal."""
    count = 2000
    stacked = np.tile(TRIANGLE, (count, 1))
    rng = np.random.default_rng(27)  # fixed seed: a reproducible scatter
    distinct = (np.repeat(rng.uniform(-20, 20, (count, 3)), 3, axis=0) + np.tile(TRIANGLE, (count, 1)))
    triangles = np.arange(3 * count, dtype=np.int32).reshape(-1, 3)
    work = {}
    for name, points in (("stacked", stacked), ("distinct", distinct.astype(np.float32))):
        reach = 2 * RAY_EPSILON_RELATIVE * 70.0  # 2 epsilon of the distinct scatter's diagonal (~70)
        work[name] = lanes_within_reach(build_triangle_bvh(points, triangles), points, reach)
    print(f"lanes within reach, summed over {3 * count} vertices: {work}")
    assert work["distinct"] >= 3 * count  # each vertex meets at least its own triangle: not vacuous
    assert work["stacked"] <= 2 * work["distinct"]


def test_stacked_copies_get_the_ao_of_one_triangle():
    """Every vertex of N stacked copies facing open sky has AO 1 (no copy occludes another), finite."""
    from usdbake.processors.occlusion.ambient_occlusion import compute_vertex_ao

    copies = 3000
    points = np.tile(TRIANGLE, (copies, 1))
    triangles = np.arange(3 * copies, dtype=np.int32).reshape(-1, 3)
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1)).astype(np.float32)
    ao = compute_vertex_ao(Tracer(points, triangles), points, normals, samples=16)
    np.testing.assert_array_equal(ao, 1.0)


def test_empty_packet_lanes_hold_nan():
    """A lane without a triangle is NaN, not a point triangle at the origin: every comparison with NaN is false,
    so the watertight test never hits it, even where a compiler fuses its products (CUDA's contraction made a
    zero lane's edge functions one rounding error each, all of one sign: a hit at the origin's depth)."""
    points = np.random.default_rng(2).normal(size=(30, 3)).astype(np.float32)  # fixed: 10 triangles, 3 packets
    bvh = build_triangle_bvh(points, np.arange(30).reshape(10, 3))
    empty = bvh.packet_triangle < 0
    assert empty.any() and (~empty).any()
    lanes = bvh.packets.transpose(0, 2, 1)  # (P, PACKET, 9)
    assert np.isnan(lanes[empty]).all() and np.isfinite(lanes[~empty]).all()
