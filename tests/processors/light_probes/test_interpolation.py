"""processors/light_probes/interpolation.py on its own, on clouds placed by hand.

- ``segment_blocked``: a wall between the ends blocks a segment from either end; a segment that stops short
  of the wall, passes beside it or has zero length does not; empty input;
- ``build_cloud``: each tetrahedron's 6-bit mask marks exactly the edges (TET_EDGES order) that cross the
  wall, written here from the plane crossing; without a tracer or with ``leak_fix`` off, no bits;
- ``interpolation_weights`` / ``interpolate_sh`` without blockers: barycentric weights (non-negative, summing
  to 1, reproducing the point and any affine field of SH), clamped outside the hull; at a probe, its SH;
- ``irradiance_at``: E(n) = sum_k c_k Y_k(n), with the real SH basis written here (constant and linear bands);
- blockers: the leak rule's weights; with a tracer the visibility rule (``visible_weights``): probes the wall
  hides from a point get no weight, the others renormalized, the leak rule's where every probe is hidden.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tolerances import FLOAT32_BARYCENTRIC, FLOAT32_STORAGE, FLOAT64_ROUNDING
from usdbake.kernels.tracer import Tracer
from usdbake.processors.light_probes import tetrahedra
from usdbake.processors.light_probes.interpolation import (build_cloud, interpolate_sh, interpolation_weights,
                                                           irradiance_at, segment_blocked, visible_weights)

WALL_X = 0.05
"""The wall's plane x = WALL_X (off the lattice's x = 0 column, so no probe lies on it)."""


def wall_tracer(half: float = 1.5) -> Tracer:
    """A square wall in the plane x = WALL_X, |y|, |z| <= half (two triangles)."""
    points = np.array([[WALL_X, -half, -half], [WALL_X, half, -half], [WALL_X, half, half], [WALL_X, -half, half]])
    return Tracer(points, np.array([[0, 1, 2], [0, 2, 3]]))


def lattice() -> np.ndarray:
    """27 probes on the grid {-1, 0, 1}^3, slightly jittered so the Delaunay tetrahedra are unique."""
    g = np.array(np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0], indexing="ij")).reshape(3, -1).T
    rng = np.random.default_rng(3)  # a fixed small jitter
    return g + rng.uniform(-0.03, 0.03, g.shape)


def affine_sh(positions: np.ndarray) -> np.ndarray:
    """(P, 9, 3) SH coefficients affine in position (each coefficient and channel its own affine function)."""
    k = np.arange(9)[None, :, None]
    c = np.arange(3)[None, None, :]
    p = positions[:, None, None, :]
    return 1.0 + 0.1 * k + 0.2 * c + p[..., 0] * (0.3 - 0.01 * k) + p[..., 1] * 0.2 * c - p[..., 2] * 0.05 * k


def test_segment_blocked_by_a_wall_from_either_end():
    tracer = wall_tracer()
    a = np.array([[-1, 0, 0], [1, 0, 0], [-1, 0, 0], [-1, 2, 0], [-1, 0.3, 0.2], [0.5, 0.5, 0.5]], np.float64)
    b = np.array([[1, 0, 0], [-1, 0, 0], [-0.5, 0, 0], [1, 2, 0], [1, -0.3, 1.0], [0.5, 0.5, 0.5]], np.float64)
    blocked = segment_blocked(tracer, a, b)
    # through, through backwards, stops short, beside the wall (|y| = 2 > 1.5), through obliquely, zero length
    assert blocked.tolist() == [True, True, False, False, True, False]
    assert segment_blocked(tracer, np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)


def crossing_edges(positions: np.ndarray, tets: np.ndarray, half: float) -> np.ndarray:
    """(T,) 6-bit masks: edge e of tet t crosses the wall square (plane x = WALL_X, |y|, |z| <= half)."""
    masks = np.zeros(len(tets), np.int64)
    for e, (i, j) in enumerate(tetrahedra.TET_EDGES):
        p, q = positions[tets[:, i]], positions[tets[:, j]]
        s, t = p[:, 0] - WALL_X, q[:, 0] - WALL_X
        crosses = s * t < 0
        f = np.where(crosses, s / np.where(crosses, s - t, 1.0), 0.0)
        hit = p + f[:, None] * (q - p)
        inside = crosses & (np.abs(hit[:, 1]) <= half) & (np.abs(hit[:, 2]) <= half)
        masks |= inside.astype(np.int64) << e
    return masks


def test_build_cloud_masks_the_edges_that_cross_the_wall():
    positions = lattice()
    sh = affine_sh(positions)
    tracer = wall_tracer(half=0.7)  # the outer ring of edges passes beside it
    cloud = build_cloud(positions, sh, tracer)
    assert cloud.tet_blocked.dtype == np.uint8 and cloud.tet_blocked.shape == (len(cloud.tet_vertices),)
    expected = crossing_edges(positions.astype(np.float32).astype(np.float64), cloud.tet_vertices, 0.7)
    np.testing.assert_array_equal(cloud.tet_blocked, expected)
    assert cloud.tet_blocked.any() and not cloud.tet_blocked.all()
    np.testing.assert_array_equal(cloud.probe_sh, sh.astype(np.float32))
    assert not build_cloud(positions, sh, tracer, leak_fix=False).tet_blocked.any()
    assert not build_cloud(positions, sh).tet_blocked.any()


def test_without_blockers_the_weights_are_barycentric_and_clamped_outside():
    positions = lattice()
    cloud = build_cloud(positions, affine_sh(positions))
    rng = np.random.default_rng(8)  # points inside the lattice's hull (a cube, shrunk by the jitter)
    inside = rng.uniform(-0.9, 0.9, (400, 3))
    probes, weights = interpolation_weights(cloud, inside)
    assert probes.shape == weights.shape == (400, 4)
    assert (weights >= 0).all()
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(np.einsum("nv,nvc->nc", weights, positions.astype(np.float32)[probes]), inside,
                               atol=FLOAT32_BARYCENTRIC)
    # an affine field of SH comes back at the point
    np.testing.assert_allclose(interpolate_sh(cloud, inside), affine_sh(inside), atol=FLOAT32_BARYCENTRIC * 2)
    # outside the hull: still a convex combination of one tetrahedron's probes (the boundary one, clamped)
    outside = rng.uniform(-1, 1, (100, 3)) * 4 + np.sign(rng.uniform(-1, 1, (100, 3))) * 2
    probes_out, weights_out = interpolation_weights(cloud, outside)
    assert (weights_out >= 0).all()
    np.testing.assert_allclose(weights_out.sum(axis=1), 1.0, atol=FLOAT64_ROUNDING)
    assert ((probes_out >= 0) & (probes_out < len(positions))).all()


def test_at_a_probe_the_cloud_reads_its_own_sh():
    positions = lattice()
    cloud = build_cloud(positions, affine_sh(positions))
    np.testing.assert_allclose(interpolate_sh(cloud, positions), cloud.probe_sh,
                               atol=FLOAT32_BARYCENTRIC * np.abs(cloud.probe_sh).max())


def test_irradiance_is_the_sh_basis_against_the_coefficients():
    """A constant irradiance E: c_0 = E / Y_0 with Y_0 = 1 / (2 sqrt(pi)); a linear band along z: c_2 Y_2(n) with
    Y_2 = sqrt(3 / (4 pi)) n_z (the real orthonormal basis, index 2 = (l 1, m 0))."""
    positions = lattice()
    e0, slope = np.array([2.0, 1.0, 0.5]), 0.4
    sh = np.zeros((len(positions), 9, 3))
    sh[:, 0] = e0 * 2.0 * math.sqrt(math.pi)
    sh[:, 2] = slope
    cloud = build_cloud(positions, sh)
    rng = np.random.default_rng(2)  # any normals and points inside
    normals = rng.normal(size=(50, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    e = irradiance_at(cloud, rng.uniform(-0.8, 0.8, (50, 3)), normals)
    assert e.shape == (50, 3) and e.dtype == np.float32
    expected = e0[None, :] + slope * math.sqrt(3.0 / (4.0 * math.pi)) * normals[:, 2:3]
    np.testing.assert_allclose(e, expected, atol=FLOAT32_STORAGE * 4)


def test_blocked_tetrahedra_follow_the_leak_rule_without_a_tracer():
    positions = lattice()
    cloud = build_cloud(positions, affine_sh(positions), wall_tracer())
    points = np.random.default_rng(9).uniform(-0.9, 0.9, (300, 3))
    probes, weights = interpolation_weights(cloud, points)
    plain = build_cloud(positions, affine_sh(positions))
    _, bary = interpolation_weights(plain, points)  # same tetrahedra (same positions), no blockers
    tet, _, _ = tetrahedra.locate(cloud.tetra, points)
    np.testing.assert_allclose(weights, tetrahedra.leak_weights(bary, cloud.tet_blocked[tet]), atol=FLOAT64_ROUNDING)
    # the rule changes only the tetrahedra with a blocked edge, and there it drops at least one probe
    masked = cloud.tet_blocked[tet] > 0
    assert masked.any() and (~masked).any()
    np.testing.assert_allclose(weights[~masked], bary[~masked], atol=FLOAT64_ROUNDING)
    assert ((weights[masked] == 0) & (bary[masked] > 0)).any(axis=1).mean() > 0.5


def test_with_a_tracer_hidden_probes_get_no_weight():
    positions = lattice()
    tracer = wall_tracer()
    cloud = build_cloud(positions, affine_sh(positions), tracer)
    rng = np.random.default_rng(10)  # points off the wall's plane
    points = rng.uniform(-0.9, 0.9, (300, 3))
    points = points[np.abs(points[:, 0] - WALL_X) > 0.02]
    probes, weights = interpolation_weights(cloud, points, tracer)
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=FLOAT64_ROUNDING)
    other_side = np.sign(positions[probes][..., 0] - WALL_X) != np.sign(points[:, 0] - WALL_X)[:, None]
    own_weighted = ((~other_side) & (weights > 0)).any(axis=1)
    # wherever a probe on the point's side has weight, none beyond the wall (|y|, |z| < 1.5 covers the lattice)
    assert own_weighted.mean() > 0.9
    assert not (weights[own_weighted] * other_side[own_weighted]).any()


def test_visible_weights_renormalize_and_fall_back():
    positions = lattice()
    tracer = wall_tracer()
    cloud = build_cloud(positions, affine_sh(positions))
    left = np.flatnonzero(positions[:, 0] < -0.5)[:2]  # x near -1: behind the wall from the point
    right = np.flatnonzero(positions[:, 0] > 0.5)[:2]  # x near 1: on the point's side
    point = np.array([[0.5, 0.0, 0.0]])
    probes = np.array([[left[0], right[0], left[1], right[1]]])
    weights = np.array([[0.1, 0.3, 0.2, 0.4]])
    fallback = np.array([[0.25, 0.25, 0.25, 0.25]])
    got = visible_weights(tracer, cloud, point, probes, weights, fallback)
    np.testing.assert_allclose(got, [[0.0, 0.3 / 0.7, 0.0, 0.4 / 0.7]], atol=FLOAT64_ROUNDING)
    hidden = np.array([[left[0], left[1], left[0], left[1]]])
    np.testing.assert_array_equal(visible_weights(tracer, cloud, point, hidden, weights, fallback), fallback)
    # capture positions, when given, are where visibility is tested from
    capture = np.where(np.arange(len(positions))[:, None] == left[0], [0.9, 0.0, 0.0], positions)
    moved = dataclasses.replace(cloud, capture_positions=capture.astype(np.float32))
    got = visible_weights(tracer, moved, point, probes, weights, fallback)
    np.testing.assert_allclose(got, [[0.1 / 0.8, 0.3 / 0.8, 0.0, 0.4 / 0.8]], atol=FLOAT64_ROUNDING)


@pytest.mark.parametrize("count", [0, 1])
def test_empty_queries(count):
    positions = lattice()
    cloud = build_cloud(positions, affine_sh(positions))
    probes, weights = interpolation_weights(cloud, np.zeros((count, 3)))
    assert probes.shape == weights.shape == (count, 4)
