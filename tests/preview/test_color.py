"""preview/color.py against closed forms: Narkowicz's ACES fit written out in float64 (its zero, where it
reaches 1, clamping), the IEC 61966-2-1 sRGB transfer pair (published values, continuity at the breakpoints,
round trips as hypothesis properties), Rec. 709 luminance, the automatic exposure's middle grey and the
false-colour index rule (value k/255 of the range -> table entry k; NaN, out-of-range and empty ranges)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from tolerances import FLOAT32_ROUNDING, FLOAT32_STORAGE, QUOTED_6_DECIMALS

from usdbake.preview.color import (BACKGROUND, MIDDLE_GREY, VIRIDIS, VIRIDIS_KNOTS, aces_fitted, auto_exposure,
                                   false_color, luminance, srgb_decode, srgb_encode, tone_map)


def aces_reference(x):
    """Narkowicz 2015, f(x) = x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14), in float64, clamped."""
    x = np.maximum(np.asarray(x, np.float64), 0.0)
    return np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)


def srgb_reference(linear):
    """IEC 61966-2-1 encoding in float64."""
    linear = np.clip(np.asarray(linear, np.float64), 0.0, 1.0)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)


def test_aces_matches_the_published_curve():
    x = np.array([0.0, 0.01, 0.18, 0.5, 1.0, 2.0, 5.0])
    np.testing.assert_allclose(aces_fitted(x), aces_reference(x), rtol=FLOAT32_STORAGE)
    assert aces_fitted(0.0) == 0.0


def test_aces_clamps_negatives_and_saturates_where_the_fit_reaches_one():
    # f(x) = 1 where 0.08 x^2 - 0.56 x - 0.14 = 0: x* = (0.56 + sqrt(0.56^2 + 4 * 0.08 * 0.14)) / 0.16.
    x_star = (0.56 + np.sqrt(0.56 ** 2 + 4 * 0.08 * 0.14)) / 0.16
    assert aces_fitted(x_star * 0.99) < 1.0
    np.testing.assert_array_equal(aces_fitted([x_star * 1.01, 100.0, 1e6, 1e18]), 1.0)
    np.testing.assert_array_equal(aces_fitted([-1.0, -1e30, -np.inf]), 0.0)
    assert aces_fitted(np.ones((2, 3))).shape == (2, 3)


def test_aces_saturates_for_any_bright_input():
    with np.errstate(over="ignore", invalid="ignore"):
        np.testing.assert_array_equal(aces_fitted([1e20, 1e30, np.inf]), 1.0)


def test_srgb_encode_matches_the_standard():
    x = np.array([0.0, 0.001, 0.0031308, 0.01, 0.18, 0.5, 1.0])
    np.testing.assert_allclose(srgb_encode(x), srgb_reference(x), atol=FLOAT32_STORAGE)
    # Published figures: linear 0.5 encodes to 0.735357, 0.18 (middle grey) to 0.461356.
    np.testing.assert_allclose(srgb_encode([0.5, 0.18]), [0.735357, 0.461356], atol=QUOTED_6_DECIMALS)
    np.testing.assert_allclose(srgb_encode([-0.5, 0.0, 1.0, 7.0]), [0.0, 0.0, 1.0, 1.0], atol=FLOAT32_ROUNDING)


def test_srgb_branches_meet_at_the_breakpoints():
    lo, hi = np.nextafter(np.float32(0.0031308), 0), np.nextafter(np.float32(0.0031308), 1)
    assert abs(float(srgb_encode(hi)) - float(srgb_encode(lo))) < FLOAT32_STORAGE
    lo, hi = np.nextafter(np.float32(0.04045), 0), np.nextafter(np.float32(0.04045), 1)
    assert abs(float(srgb_decode(hi)) - float(srgb_decode(lo))) < FLOAT32_STORAGE
    np.testing.assert_allclose(srgb_decode([-1.0, 0.0, 1.0, 2.0]), [0.0, 0.0, 1.0, 1.0], atol=FLOAT32_ROUNDING)


@given(st.floats(0.0, 1.0))
def test_srgb_decode_inverts_encode(x):
    assert float(srgb_decode(srgb_encode(x))) == pytest.approx(x, abs=FLOAT32_STORAGE)


@given(st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_srgb_encode_is_monotone(a, b):
    a, b = sorted((a, b))
    assert srgb_encode(a) <= srgb_encode(b)


def test_luminance_uses_rec709_weights():
    rgb = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(luminance(rgb), [0.2126, 0.7152, 0.0722, 1.0, 0.0], atol=FLOAT32_ROUNDING)
    assert luminance(np.ones((4, 5, 3))).shape == (4, 5)


def test_auto_exposure_brings_the_median_to_middle_grey():
    rng = np.random.default_rng(3)  # fixed seed: 101 random grey-ish colours
    linear = rng.uniform(0.01, 5.0, (101, 3)).astype(np.float32)
    ev = auto_exposure(linear)
    exposed = luminance(linear * np.float32(2.0 ** ev))
    assert float(np.median(exposed)) == pytest.approx(MIDDLE_GREY, rel=FLOAT32_STORAGE)
    # A uniform grey of luminance 0.72 needs two stops down.
    assert auto_exposure(np.full((5, 3), 0.72, np.float32)) == pytest.approx(-2.0, abs=FLOAT32_STORAGE)


def test_auto_exposure_ignores_black_and_non_finite_pixels():
    linear = np.array([[0.0, 0.0, 0.0]] * 10 + [[0.09, 0.09, 0.09], [np.nan] * 3, [np.inf] * 3], np.float32)
    assert auto_exposure(linear) == pytest.approx(1.0, abs=FLOAT32_STORAGE)  # only 0.09 counts: one stop up
    assert auto_exposure(np.zeros((4, 3), np.float32)) == 0.0
    assert auto_exposure(np.zeros((0, 3), np.float32)) == 0.0


def test_tone_map_is_the_aces_fit_then_srgb():
    x = np.array([0.0, 0.05, 0.18, 1.0, 3.0, 50.0])
    np.testing.assert_allclose(tone_map(x), srgb_reference(aces_reference(x)), atol=FLOAT32_STORAGE)
    rgb = tone_map(np.array([[0.2, 1.0, 4.0]]))
    assert rgb.shape == (1, 3) and 0 < rgb[0, 0] < rgb[0, 1] < rgb[0, 2] <= 1  # per channel, order kept


def test_false_color_picks_entry_k_at_value_k_over_255():
    lo, hi = -2.0, 6.0
    k = np.arange(256)
    values = lo + k / 255.0 * (hi - lo)
    np.testing.assert_array_equal(false_color(values, lo, hi), VIRIDIS[k])
    np.testing.assert_array_equal(false_color(np.array([[lo, hi]]), lo, hi), VIRIDIS[[[0, 255]]])


def test_false_color_clamps_and_sends_nan_to_the_low_end():
    lo, hi = 1.0, 2.0
    with np.errstate(over="ignore"):  # infinities pass through nan_to_num as the largest floats
        np.testing.assert_array_equal(false_color([-10.0, np.nan, 50.0, np.inf, -np.inf], lo, hi),
                                      VIRIDIS[[0, 0, 255, 255, 0]])


def test_false_color_of_an_empty_range_uses_a_unit_span():
    # hi <= lo: the span is 1 from lo, so lo + 1 is the top of the map.
    np.testing.assert_array_equal(false_color([3.0, 3.5, 4.0], 3.0, 3.0), VIRIDIS[[0, 128, 255]])
    np.testing.assert_array_equal(false_color([3.0], 3.0, 1.0), VIRIDIS[[0]])


def test_viridis_table_runs_through_its_knots():
    assert VIRIDIS.shape == (256, 3) and VIRIDIS.dtype == np.float32
    np.testing.assert_array_equal(VIRIDIS[0], VIRIDIS_KNOTS[0])
    np.testing.assert_array_equal(VIRIDIS[255], VIRIDIS_KNOTS[-1])
    # Entry i sits at t = i / 255 on the piecewise-linear path through 33 knots at j / 32.
    t = 100 / 255
    j = int(t * 32)
    w = t * 32 - j
    expected = (1 - w) * VIRIDIS_KNOTS[j].astype(np.float64) + w * VIRIDIS_KNOTS[j + 1]
    np.testing.assert_allclose(VIRIDIS[100], expected, atol=FLOAT32_STORAGE)
    assert ((VIRIDIS >= 0) & (VIRIDIS <= 1)).all()


def test_background_is_a_dim_grey_that_no_map_entry_matches():
    assert BACKGROUND.shape == (3,) and (BACKGROUND < 0.2).all()
    assert np.abs(VIRIDIS - BACKGROUND).max(axis=1).min() > 0.05  # background never reads as data
