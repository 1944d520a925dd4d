"""processors/light_probes/placement.py: its pure numpy helpers, directly.

The placement box (probe volumes, backdrops, flat scenes), the volume test, the candidate grid and its
spacing, the 26-direction irradiance samples of an SH (closed forms of the L0 and L1 bands), edge
contrast and variation (hand-computed cases), the Delaunay edges, the separated picks of the
error-driven placement and greedy thinning. ``similar_probes`` and ``cluster_dark_probes`` have their
tests in test_light_probe_clouds.py; the traced parts (``place_probes``, ``refine_placement``,
``wall_probes``, ``conforming_placement``) run end to end in test_light_probes.py.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from patch_scenes import box_parts, make_scene, quad
from usdbake.processors.light_probes.placement import (
    BOUNDS_MIN_RELATIVE, RECEIVER_MARGIN, candidate_grid, cloud_edges, edge_contrast, grid_spacing,
    in_placement_volume, placement_box, sample_irradiance, separated_worst, thin, variation)

from tolerances import FLOAT32_STORAGE, FLOAT64_ROUNDING, ON_BOUNDARY

# ---------------------------------------------------------------------------
# placement_box and in_placement_volume


def test_probe_volumes_set_the_box_as_their_union():
    scene = make_scene(box_parts(1.0))
    volumes = np.array([[[0.0, 0.0, 0.0], [1.0, 2.0, 1.0]], [[0.5, -1.0, 0.2], [3.0, 0.5, 0.8]]])
    scene = dataclasses.replace(scene, probe_volumes=volumes)
    lo, hi = placement_box(scene)
    np.testing.assert_allclose(lo, [0.0, -1.0, 0.0], atol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(hi, [3.0, 2.0, 1.0], atol=FLOAT64_ROUNDING)
    # inside one volume or the other, not merely inside their union's box
    points = np.array([[0.5, 1.5, 0.5], [2.0, 0.0, 0.5], [2.0, 1.5, 0.5], [1.0, 2.0, 1.0], [3.0, 0.6, 0.5]])
    np.testing.assert_array_equal(in_placement_volume(scene, points, lo, hi), [True, True, False, True, False])


def test_without_backdrops_the_box_is_the_scene_bounds():
    scene = make_scene(box_parts(2.0))  # six faces of one cube: none is a backdrop
    lo, hi = placement_box(scene)
    np.testing.assert_allclose(lo, [0, 0, 0], atol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(hi, [2, 2, 2], atol=FLOAT64_ROUNDING)
    assert lo.dtype == hi.dtype == np.float64


def test_a_backdrop_leaves_the_box_around_the_other_receivers_grown_by_the_margin():
    ground = quad([-50, 0, 50], [100, 0, 0], [0, 0, -100])  # a 100 x 100 ground at y = 0 under a unit cube
    scene = make_scene([ground, *box_parts(1.0)])
    lo, hi = placement_box(scene)
    margin = RECEIVER_MARGIN * math.sqrt(3.0)
    # grown on every side, but never past the scene's own bounds: y in [0, 1] (the ground, the cube's top)
    np.testing.assert_allclose(lo, [-margin, 0.0, -margin], atol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(hi, [1 + margin, 1.0, 1 + margin], atol=FLOAT64_ROUNDING)


def test_a_flat_scene_gets_a_box_of_some_thickness():
    scene = make_scene([quad([0, 0, 0], [0, 0, 10], [10, 0, 0])])  # the plane y = 0
    lo, hi = placement_box(scene)
    half = 0.5 * BOUNDS_MIN_RELATIVE * math.sqrt(200.0)
    np.testing.assert_allclose(lo, [0.0, -half, 0.0], atol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(hi, [10.0, half, 10.0], atol=FLOAT64_ROUNDING)


def test_in_placement_volume_without_volumes_is_the_closed_box():
    scene = make_scene(box_parts(1.0))
    lo, hi = np.zeros(3), np.ones(3)
    points = [[0, 0, 0], [1, 1, 1], [0.5, 0.5, 0.5], [1 + 1e-9, 0.5, 0.5], [0.5, -1e-9, 0.5]]
    np.testing.assert_array_equal(in_placement_volume(scene, points, lo, hi), [True, True, True, False, False])
    assert in_placement_volume(scene, np.zeros((0, 3)), lo, hi).shape == (0,)
    assert in_placement_volume(scene, [0.5, 0.5, 0.5], lo, hi).tolist() == [True]  # one point, flat


# ---------------------------------------------------------------------------
# grid_spacing and candidate_grid


def corner_count(lo, hi, spacing) -> int:
    extent = np.asarray(hi, np.float64) - lo
    return int(np.prod([max(1, round(e / spacing)) + 1 for e in extent]))


@pytest.mark.parametrize("n", [2, 3, 5, 8, 10])
def test_a_cube_of_n_cubed_points_is_filled_exactly(n):
    lo, hi = np.zeros(3), np.ones(3)
    spacing = grid_spacing(lo, hi, n ** 3)
    assert corner_count(lo, hi, spacing) == n ** 3


@pytest.mark.parametrize("count", [1, 7, 50, 300, 4000])
def test_grid_spacing_never_exceeds_the_count_and_keeps_two_points_per_axis(count):
    lo, hi = np.array([0.0, -1.0, 2.0]), np.array([4.0, 1.0, 3.0])
    spacing = grid_spacing(lo, hi, count)
    assert spacing > 0
    points = corner_count(lo, hi, spacing)
    assert 8 <= points <= max(count, 8)
    if count >= 300:  # and not much coarser than asked: a 5 % step per axis at most
        assert points >= count / 1.05 ** 3 / 2


def test_grid_spacing_of_a_flat_box_is_finite():
    spacing = grid_spacing(np.zeros(3), np.array([1.0, 0.0, 1.0]), 100)
    assert np.isfinite(spacing) and spacing > 0


def test_candidates_are_jittered_corners_inside_the_shrunk_box():
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([2.0, 1.0, 4.0])
    spacing, margin = 0.5, 0.1
    rng = np.random.default_rng(3)  # fixed seed: the jitter
    grid = candidate_grid(lo, hi, spacing, margin, rng)
    inner_lo, inner_hi = lo + margin, hi - margin
    cells = np.maximum(1, np.round((inner_hi - inner_lo) / spacing)).astype(int)
    assert len(grid) == np.prod(cells + 1)
    assert (grid >= inner_lo).all() and (grid <= inner_hi).all()
    step = (inner_hi - inner_lo) / cells
    nearest = np.round((grid - inner_lo) / step)  # the lattice node each came from
    assert ((nearest >= 0) & (nearest <= cells)).all()
    assert (np.abs(grid - (inner_lo + nearest * step)) <= 0.25 * step + ON_BOUNDARY).all()
    # every node is taken once
    assert len({tuple(k) for k in nearest.astype(int)}) == len(grid)
    again = candidate_grid(lo, hi, spacing, margin, np.random.default_rng(3))
    np.testing.assert_array_equal(grid, again)


def test_a_margin_wider_than_the_box_is_capped_at_a_quarter_of_it():
    lo, hi = np.zeros(3), np.ones(3)
    grid = candidate_grid(lo, hi, 0.1, 5.0, np.random.default_rng(0))  # fixed seed: the jitter
    assert (grid >= 0.25).all() and (grid <= 0.75).all()
    assert len(grid) == 6 ** 3  # [0.25, 0.75] in cells of 0.1


# ---------------------------------------------------------------------------
# sample_irradiance, edge_contrast, variation


def directions_26() -> np.ndarray:
    d = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if (x, y, z) != (0, 0, 0)],
                 np.float64)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_a_constant_sh_is_the_same_in_every_direction():
    sh = np.zeros((2, 9, 3))
    sh[0, 0] = [1.0, 1.0, 1.0]
    sh[1, 0] = [2.0, 0.0, 0.0]  # red only
    samples = sample_irradiance(sh)
    y00 = 0.5 / math.sqrt(math.pi)
    assert samples.shape == (2, 26) and samples.dtype == np.float64
    np.testing.assert_allclose(samples[0], y00, rtol=FLOAT32_STORAGE)  # luminance weights sum to 1
    np.testing.assert_allclose(samples[1], 2.0 * y00 * 0.2126, rtol=FLOAT32_STORAGE)


def test_a_linear_sh_is_a_clamped_cosine_in_luminance():
    sh = np.zeros((1, 9, 3))
    sh[0, 1] = [1.0, 1.0, 1.0]  # the y band: Y_1,-1 = sqrt(3 / 4 pi) y
    expected = np.maximum(math.sqrt(3.0 / (4.0 * math.pi)) * directions_26()[:, 1], 0.0)
    samples = sample_irradiance(sh)[0]
    # compared as sets of values: the order of the 26 directions is the module's
    np.testing.assert_allclose(np.sort(samples), np.sort(expected), atol=FLOAT32_STORAGE)
    assert (samples >= 0).all() and (samples == 0).sum() == 17  # y <= 0: 9 + 8 directions


def test_edge_contrast_hand_cases():
    samples = np.array([[1.0, 1.0], [3.0, 1.0], [0.0, 0.0], [0.0, 5.0]])
    edges = np.array([[0, 1], [0, 0], [2, 3], [2, 2]])
    contrast = edge_contrast(samples, edges, floor=1e-300)
    # |1 - 3| / 4 = 0.5 and 0 -> 0.25; the same probe: 0; dark vs 5: 1 in one direction, 0 / floor in the other
    np.testing.assert_allclose(contrast, [0.25, 0.0, 0.5, 0.0], atol=FLOAT64_ROUNDING)
    with_floor = edge_contrast(samples, edges, floor=1.0)
    np.testing.assert_allclose(with_floor, [0.2, 0.0, 5.0 / 12.0, 0.0], atol=FLOAT64_ROUNDING)
    assert (with_floor < 1.0).all()


def test_variation_is_the_largest_contrast_per_unit_length_at_each_probe():
    positions = np.array([[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0], [3.0, 4.0, 0]])
    samples = np.array([[1.0], [3.0], [3.0], [1.0]])
    edges = np.array([[0, 1], [1, 2], [2, 3]])
    v, contrast = variation(positions, samples, edges, floor=1e-300)
    np.testing.assert_allclose(contrast, [0.5, 0.0, 0.5], atol=FLOAT64_ROUNDING)
    # edge (0, 1): 0.5 / 1; (1, 2): 0; (2, 3): 0.5 / 4
    np.testing.assert_allclose(v, [0.5, 0.5, 0.125, 0.125], atol=FLOAT64_ROUNDING)
    lonely = variation(np.zeros((2, 3)), np.ones((2, 1)), np.zeros((0, 2), np.int64), floor=1.0)[0]
    np.testing.assert_array_equal(lonely, [0.0, 0.0])


# ---------------------------------------------------------------------------
# cloud_edges


def test_the_edges_of_one_tetrahedron_are_its_six_pairs():
    positions = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    edges = cloud_edges(positions)
    assert edges is not None and edges.shape == (6, 2)
    assert {tuple(sorted(e)) for e in edges.tolist()} == {(i, j) for i in range(4) for j in range(i + 1, 4)}


def test_a_flat_or_tiny_cloud_has_no_edges():
    plane = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.5, 0.3, 0]])
    assert cloud_edges(plane) is None
    assert cloud_edges(plane[:3]) is None


def test_a_cube_keeps_its_twelve_edges():
    corners = np.array([(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float64)
    edges = {tuple(sorted(e)) for e in cloud_edges(corners).tolist()}
    twelve = {(i, j) for i in range(8) for j in range(i + 1, 8)
              if np.isclose(np.linalg.norm(corners[i] - corners[j]), 1.0)}
    assert len(twelve) == 12 and twelve <= edges


# ---------------------------------------------------------------------------
# separated_worst and thin


def test_separated_worst_takes_the_largest_errors_away_from_earlier_picks():
    points = np.array([[0.0, 0, 0], [0.5, 0, 0], [3.0, 0, 0], [6.0, 0, 0], [9.0, 0, 0]])
    error = np.array([0.9, 0.8, 0.5, 0.0, -1.0])
    picked = separated_worst(points, error, count=5, radius=1.0)
    # 0 first; 1 is within 1 of it; 2 next; 3 and 4 have no positive error
    np.testing.assert_array_equal(picked, [0, 2])
    assert picked.dtype == np.int64
    np.testing.assert_array_equal(separated_worst(points, error, count=1, radius=1.0), [0])
    assert len(separated_worst(points, -np.ones(5), count=3, radius=1.0)) == 0
    assert len(separated_worst(points, error, count=0, radius=1.0)) == 0


def test_thinning_keeps_the_first_in_order_and_drops_its_neighbours():
    positions = np.array([[0.0, 0, 0], [0.5, 0, 0], [1.2, 0, 0], [5.0, 0, 0]])
    np.testing.assert_array_equal(thin(positions, np.arange(4), 1.0), [0, 2, 3])
    # 1 first takes out 0 and 2 (both within 1.0 of it)
    np.testing.assert_array_equal(thin(positions, np.array([1, 0, 2, 3]), 1.0), [1, 3])
    # only the listed probes can be kept
    np.testing.assert_array_equal(thin(positions, np.array([3, 2]), 1.0), [2, 3])
    assert len(thin(np.zeros((0, 3)), np.zeros(0, np.int64), 1.0)) == 0


def test_thinned_probes_are_at_least_the_radius_apart():
    rng = np.random.default_rng(19)  # fixed seed: a random cloud
    positions = rng.uniform(0.0, 4.0, (400, 3))
    kept = thin(positions, rng.permutation(400), 0.5)
    gaps = np.linalg.norm(positions[kept][:, None] - positions[kept][None], axis=2)
    assert gaps[~np.eye(len(kept), dtype=bool)].min() > 0.5
    # and every dropped probe has a kept one within the radius (greedy thinning covers)
    dropped = np.setdiff1d(np.arange(400), kept)
    reach = np.linalg.norm(positions[dropped][:, None] - positions[kept][None], axis=2).min(axis=1)
    assert (reach <= 0.5).all()
    np.testing.assert_array_equal(kept, np.sort(kept))
