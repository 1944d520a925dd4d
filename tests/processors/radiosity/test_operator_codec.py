"""processors/radiosity/operator_codec.py on synthetic operators (no scene): the byte codes and their table,
the automatic floor's definition, the guarantees of compress/decompress (exact entries exact, every coded
entry within MAX_ERROR, row sums kept by the row correction) and its refusals. The box-scene tests of the
codec (top entries, relight, reordering, the greedy pass against a plain one) are in test_form_factors.py."""

import numpy as np
import pytest
from tolerances import FLOAT32_ACCUMULATED, FLOAT32_LONG_CHAIN, FLOAT32_ROUNDING, FLOAT32_STORAGE, UINT8_HALF_STEP
from usdbake.processors.radiosity import operator_codec as codec


def smooth_operator(n: int) -> np.ndarray:
    """(3, n, n) float32 transfer factors falling off with |i - j|, one hue per channel: every entry of a
    row lies on a line in RGB, which BC1 codes well."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    base = 0.02 * np.exp(-np.abs(i - j) / 9.0) + 1e-4
    return np.stack([base, 0.8 * base, 0.5 * base]).astype(np.float32)


def noisy_operator(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)  # fixed by the caller: entries of many hues, a few large ones
    operator = rng.exponential(1e-3, (3, n, n)).astype(np.float32)
    operator[:, rng.integers(0, n, 20), rng.integers(0, n, 20)] = 0.3
    return operator


def test_linear_codes_and_their_table_round_trip_to_half_a_step():
    values = np.linspace(0.0, 2.0, 1001)
    codes, scale, offset = codec.linear_codes(values, 2.0)
    decoded = codec.code_lut(scale, offset, "linear")[np.rint(codes).astype(int)]
    np.testing.assert_allclose(decoded, values, rtol=0, atol=2.0 * (UINT8_HALF_STEP + FLOAT32_STORAGE))


def test_log_codes_put_the_floor_at_code_one_and_the_maximum_at_255():
    floor, vmax = 1e-4, 0.5
    codes, scale, offset = codec.log_codes(np.array([0.0, 0.5 * floor, floor, vmax]), floor, vmax)
    np.testing.assert_allclose(codes, [0, 0, 1, 255], rtol=0, atol=FLOAT32_ROUNDING * 255)
    lut = codec.code_lut(scale, offset, "log")
    assert lut[0] == 0.0
    np.testing.assert_allclose(lut[[1, 255]], [floor, vmax], rtol=FLOAT32_STORAGE)
    np.testing.assert_allclose(np.diff(np.log(lut[1:].astype(np.float64))), np.log(vmax / floor) / 254,
                               rtol=FLOAT32_LONG_CHAIN)  # uniform steps in ln v


def test_auto_floor_codes_at_most_its_mass_of_the_residual_as_zero():
    rng = np.random.default_rng(3)  # fixed: a long-tailed residual
    residual = rng.pareto(1.5, (200, 200)).astype(np.float32)
    vmax = float(residual.max())
    floor = codec.auto_floor(residual, vmax, mass=1e-3)
    below = residual[residual < floor].sum(dtype=np.float64)
    assert below <= 1e-3 * residual.sum(dtype=np.float64)
    next_up = np.sort(residual.ravel())[np.searchsorted(np.sort(residual.ravel()), floor, side="right")]
    assert below + next_up > 1e-3 * residual.sum(dtype=np.float64)  # the largest such floor
    assert codec.auto_floor(np.zeros((4, 4), np.float32), 1.0) == pytest.approx(1e-6, rel=FLOAT32_ROUNDING)


def test_with_every_entry_exact_the_operator_comes_back_whole():
    operator = noisy_operator(24, seed=1)
    compressed = codec.compress_operator(operator, exact_fraction=1.0)
    np.testing.assert_allclose(codec.decompress_operator(compressed), operator, rtol=FLOAT32_ROUNDING,
                               atol=FLOAT32_ROUNDING * operator.max())


@pytest.mark.parametrize("quantization", ["log", "linear"])
def test_every_entry_decodes_within_max_error_of_the_largest_coded_value(quantization):
    operator = noisy_operator(40, seed=2)
    compressed = codec.compress_operator(operator, quantization=quantization)
    vmax = compressed.stats["residual_max"]
    error = np.abs(codec.decompress_operator(compressed) - operator)
    assert error.max() <= codec.MAX_ERROR * vmax * (1 + FLOAT32_ACCUMULATED)
    assert sorted(compressed.permutation) == list(range(40))


def test_row_correction_keeps_each_rows_sum():
    """On a smooth operator nothing is promoted after the last rescale, so each decoded row sums, per
    channel, as the operator's row does (the correction's purpose: unbiased light per patch)."""
    operator = smooth_operator(48)
    compressed = codec.compress_operator(operator, exact_fraction=0.04)
    decoded = codec.decompress_operator(compressed)
    np.testing.assert_allclose(decoded.sum(axis=2, dtype=np.float64), operator.sum(axis=2, dtype=np.float64),
                               rtol=FLOAT32_LONG_CHAIN)
    uncorrected = codec.decompress_operator(codec.compress_operator(operator, row_correction=False))
    assert np.abs(uncorrected.sum(axis=2) / operator.sum(axis=2) - 1).max() > 10 * FLOAT32_LONG_CHAIN


def test_reported_errors_are_the_mean_max_and_sum_over_coded_entries():
    decoded = np.zeros((3, 2, 2), np.float32)
    truth = np.full((3, 2, 2), 0.5, np.float32)
    coded = np.array([[True, False], [True, True]])
    errors = codec.compression_errors(decoded, truth, 2.0, coded)
    assert errors == {"error_mean": 0.25, "error_max": 0.25, "error_sum": 0.25 * 9}


def test_memory_figures_add_up():
    compressed = codec.compress_operator(smooth_operator(32))
    stats = compressed.stats
    assert stats["dense_bytes"] == 12 * 32 * 32 and stats["compressed_bytes"] == compressed.nbytes
    assert stats["memory_ratio"] == compressed.nbytes / (12 * 32 * 32)


def test_an_all_zero_operator_decodes_to_zero():
    compressed = codec.compress_operator(np.zeros((3, 8, 8), np.float32))
    assert not codec.decompress_operator(compressed).any()


def test_greedy_order_on_a_line_walks_it_in_order():
    """Items on a line with item 0 at one end: the nearest remaining one is always the next along the line."""
    positions = np.array([0, 50, 7, 300, 12, 90, 1000])
    order = codec.greedy_order(positions[:, None])
    np.testing.assert_array_equal(positions[order], np.sort(positions))


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="quantization"):
        codec.compress_operator(smooth_operator(4), quantization="cubic")
    with pytest.raises(ValueError, match="expected integers"):
        codec.greedy_order(np.array([[70_000]]))
    with pytest.raises(ValueError, match="at most"):
        codec.greedy_order(np.zeros((2, codec.SIGNATURE_DIMS + 1), np.int64))
