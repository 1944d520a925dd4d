"""streaming: the progressive order (a permutation, coarse sub-grids first, stratified runs), 3D
push-pull (received data untouched, bounded by it, constant and linear fields reproduced), and
the stream file (round trip, prefixes, bad input)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tolerances import FLOAT64_ROUNDING
from usdbake.formats import streaming as s

RESOLUTIONS = [(9, 9, 9), (8, 5, 3), (16, 12, 7), (1, 4, 4), (2, 2, 2), (1, 1, 1), (33, 2, 17)]


def linear_field(resolution, channels=2):
    coords = s.grid_coords(resolution).astype(np.float64)
    gradient = np.array([[0.3, -1.2], [2.0, 0.5], [-0.7, 1.1]])[:, :channels]
    return coords @ gradient + 5.0


# -- order ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("resolution", RESOLUTIONS)
def test_order_is_a_permutation(resolution):
    order = s.progressive_order(resolution)
    np.testing.assert_array_equal(np.sort(order), np.arange(np.prod(resolution)))


@pytest.mark.parametrize("resolution", [(9, 9, 9), (8, 5, 3), (16, 12, 7), (33, 2, 17)])
def test_prefixes_at_level_boundaries_are_the_coarse_sub_grids(resolution):
    order = s.progressive_order(resolution)
    coords = s.grid_coords(resolution)
    levels = s.vertex_levels(resolution)
    # The corners come first (the paper's initial transfer).
    assert s.corner_mask(resolution)[order[:8]].all()
    for level in range(1, levels.max() + 1):
        n = s.level_prefix(resolution, level)
        prefix = set(order[:n].tolist())
        stride = 2**level
        sub_grid = {int(v) for v, c in enumerate(coords)
                    if all(c[a] % stride == 0 or c[a] == resolution[a] - 1 for a in range(3))}
        # Stride-2^level vertices (plus the last plane of each axis, the pyramid's clamped vertices).
        assert set(np.flatnonzero(levels >= level).tolist()) == prefix
        assert {v for v in sub_grid if all(c % stride == 0 for c in coords[v])} <= prefix
    # The first level-1 prefix is about an eighth of the grid.
    first = s.level_prefix(resolution, 1) / np.prod(resolution)
    assert first <= 0.26 + 1.0 / min(r for r in resolution if r > 2)


def test_runs_within_a_level_are_spread_over_the_grid():
    """Any eighth of the finest level, taken in stream order, touches all 8 octants of the grid."""
    resolution = (16, 16, 16)
    order = s.progressive_order(resolution)
    start = s.level_prefix(resolution, 1)
    finest = order[start:]
    coords = s.grid_coords(resolution)[finest]
    octant = ((coords >= 8) * [1, 2, 4]).sum(axis=1)
    run = len(finest) // 8
    for k in range(8):
        assert len(set(octant[k * run:(k + 1) * run].tolist())) == 8
    # A raster order would not: its first eighth is one slab.
    raster = s.grid_coords(resolution)[np.arange(start, start + run)]
    assert len(set(((raster >= 8) * [1, 2, 4]).sum(axis=1).tolist())) < 8


def test_bad_resolution():
    with pytest.raises(ValueError):
        s.progressive_order((0, 3, 3))


# -- push-pull -------------------------------------------------------------------------------------


@pytest.mark.parametrize("smooth", [False, True])
@pytest.mark.parametrize("resolution", RESOLUTIONS)
def test_constant_field_is_reproduced_for_any_holes(resolution, smooth):
    rng = np.random.default_rng(4)  # fixed seed
    v = int(np.prod(resolution))
    known = rng.random(v) < 0.2
    known[rng.integers(v)] = True
    values = np.where(known[:, None], np.array([[2.5, -1.0, 7.0]]), np.nan)
    filled = s.push_pull(values, resolution, known, smooth=smooth)
    np.testing.assert_allclose(filled, np.tile([2.5, -1.0, 7.0], (v, 1)), rtol=FLOAT64_ROUNDING)


@pytest.mark.parametrize("resolution", [r for r in RESOLUTIONS if max(r) > 2])
def test_linear_field_is_reproduced_from_a_level_prefix(resolution):
    truth = linear_field(resolution)
    order = s.progressive_order(resolution)
    for level in range(1, s.vertex_levels(resolution).max() + 1):
        known = np.zeros(len(truth), bool)
        known[order[:s.level_prefix(resolution, level)]] = True
        filled = s.push_pull(np.where(known[:, None], truth, 0.0), resolution, known, smooth=False)
        np.testing.assert_allclose(filled, truth, atol=FLOAT64_ROUNDING * np.abs(truth).max())


@given(st.integers(0, 2**31 - 1), st.floats(0.01, 0.95), st.booleans(),
       st.sampled_from([(9, 9, 9), (8, 5, 3), (6, 1, 11), (3, 3, 3)]))
@settings(max_examples=40, deadline=None)
def test_filled_values_are_bounded_and_received_ones_untouched(seed, fraction, smooth, resolution):
    rng = np.random.default_rng(seed)
    v = int(np.prod(resolution))
    known = rng.random(v) < fraction
    known[rng.integers(v)] = True
    values = rng.normal(size=(v, 2)) * 10
    filled = s.push_pull(values, resolution, known, smooth=smooth)
    np.testing.assert_array_equal(filled[known], values[known])
    lo, hi = values[known].min(axis=0), values[known].max(axis=0)
    tol = FLOAT64_ROUNDING * np.abs(values).max()
    assert (filled >= lo - tol).all() and (filled <= hi + tol).all()


def test_holes_between_neighbours_are_filled_between_them():
    """A 1D-like ramp with one hole: the fill lies between its two neighbours."""
    resolution = (7, 1, 1)
    values = np.array([0.0, 1, 2, 3, 4, 5, 6])[:, None]
    known = np.ones(7, bool)
    known[3] = False
    filled = s.push_pull(values, resolution, known, smooth=True)
    assert 2.0 <= filled[3, 0] <= 4.0


def test_nothing_known_gives_zeros_and_shapes_are_checked():
    np.testing.assert_array_equal(s.push_pull(np.ones((8, 3)), (2, 2, 2), np.zeros(8, bool)), 0.0)
    with pytest.raises(ValueError):
        s.push_pull(np.ones((7, 3)), (2, 2, 2), np.ones(7, bool))


def test_non_finite_unknown_values_do_not_leak():
    resolution = (5, 5, 5)
    known = np.zeros(125, bool)
    known[::3] = True
    values = np.where(known[:, None], 1.0, np.nan)
    values[1] = np.inf
    filled = s.push_pull(values, resolution, known)
    assert np.isfinite(filled).all()


# -- stream files ----------------------------------------------------------------------------------


def _grid(resolution, seed=0):
    rng = np.random.default_rng(seed)  # fixed seed
    v = int(np.prod(resolution))
    return rng.integers(0, 256, (v, 6, 3)).astype(np.uint8), rng.integers(0, 2**32, (v, 6), dtype=np.uint64).astype(
        np.uint32)


def test_stream_round_trip_and_prefixes():
    resolution = (5, 4, 3)
    directions, colors = _grid(resolution)
    order = s.progressive_order(resolution)
    data = s.encode_stream(resolution, (1.0, 2.0, 3.0), (0.5, 0.5, 0.5), order, directions, colors)
    full = s.decode_stream(data)
    assert full.resolution == resolution and full.total_records == 60
    np.testing.assert_array_equal(full.vertex_index, order)
    np.testing.assert_array_equal(full.directions, directions[order])
    np.testing.assert_array_equal(full.colors, colors[order])
    np.testing.assert_allclose(full.grid_origin, [1, 2, 3])
    # A byte prefix that cuts a record keeps only whole records.
    record = (len(data) - s.HEADER.size) // 60
    part = s.decode_stream(data[: s.HEADER.size + 10 * record + record // 2])
    np.testing.assert_array_equal(part.vertex_index, order[:10])
    assert len(s.decode_stream(data, records=7).vertex_index) == 7


def test_stream_rejects_garbage():
    with pytest.raises(ValueError, match="header"):
        s.decode_stream(b"abc")
    with pytest.raises(ValueError, match="magic"):
        s.decode_stream(b"X" * 100)
