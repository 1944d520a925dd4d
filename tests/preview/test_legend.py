"""preview/legend.py: the 3 x 5 font's glyphs against their bitmaps written out by hand, text masks and clipped
drawing, tick formatting (every character drawable), the legend's scale and width (labels never clipped), and
the drawn bar: its colours ordered from hi at the top to lo at the bottom, tick rows, small and flat ranges."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from usdbake.preview.color import BACKGROUND, VIRIDIS, luminance, srgb_decode
from usdbake.preview.legend import (FONT_CHARACTERS, draw_legend, draw_text, format_tick, legend_scale,
                                    legend_width, text_mask)

ZERO = ["###", "#.#", "#.#", "#.#", "###"]
ONE = [".#.", "##.", ".#.", ".#.", "###"]
MINUS = ["...", "...", "###", "...", "..."]


def bitmap(rows):
    return np.array([[c == "#" for c in row] for row in rows], bool)


def test_glyphs_match_their_bitmaps():
    np.testing.assert_array_equal(text_mask("0"), bitmap(ZERO))
    np.testing.assert_array_equal(text_mask("1"), bitmap(ONE))
    np.testing.assert_array_equal(text_mask("-"), bitmap(MINUS))
    assert not text_mask(" ").any()


def test_text_is_glyphs_with_one_blank_column_between():
    mask = text_mask("10")
    assert mask.shape == (5, 4 * 2 - 1)
    np.testing.assert_array_equal(mask[:, :3], bitmap(ONE))
    assert not mask[:, 3].any()
    np.testing.assert_array_equal(mask[:, 4:], bitmap(ZERO))


def test_scale_repeats_each_pixel_in_a_square():
    for scale in (1, 2, 3):
        mask = text_mask("0.25", scale)
        assert mask.shape == (5 * scale, (4 * 4 - 1) * scale) and mask.dtype == bool
        np.testing.assert_array_equal(mask, np.repeat(np.repeat(text_mask("0.25"), scale, 0), scale, 1))


def test_empty_text_lower_case_and_unknown_characters():
    assert text_mask("", 3).shape == (15, 0)
    np.testing.assert_array_equal(text_mask("abc"), text_mask("ABC"))
    unknown = text_mask("0#0")
    assert unknown.shape == (5, 11) and not unknown[:, 4:7].any()  # a blank where the font has no glyph
    assert all(text_mask(ch).any() for ch in FONT_CHARACTERS if ch != " ")  # every other glyph draws something


def test_draw_text_paints_only_the_mask_and_clips_at_the_borders():
    image = np.zeros((8, 8, 3), np.float32)
    draw_text(image, "0", 1, 2, (1.0, 0.5, 0.25))
    painted = (image != 0).any(axis=2)
    expected = np.zeros((8, 8), bool)
    expected[2:7, 1:4] = bitmap(ZERO)
    np.testing.assert_array_equal(painted, expected)
    np.testing.assert_array_equal(image[painted], np.tile([1.0, 0.5, 0.25], (painted.sum(), 1)))

    clipped = np.zeros((4, 4, 3), np.float32)
    draw_text(clipped, "0", -1, -2, (1, 1, 1))  # the glyph's top-left corner outside the image
    expected = np.zeros((4, 4), bool)
    expected[0:3, 0:2] = bitmap(ZERO)[2:5, 1:3]
    np.testing.assert_array_equal(clipped[..., 0] > 0, expected)

    untouched = np.zeros((4, 4, 3), np.float32)
    for x, y in ((10, 0), (0, 10), (-20, 0), (0, -20)):
        draw_text(untouched, "00", x, y, (1, 1, 1))
    assert not untouched.any()


@pytest.mark.parametrize("value, text", [
    (0.25, "0.25"), (1.0, "1"), (0.0, "0"), (-1.5, "-1.5"), (1234.0, "1.23E3"), (123456.0, "1.23E5"),
    (1e-5, "1E-5"), (0.000123, "0.000123"), (-2.5e10, "-2.5E+10"), (1e100, "1E+100"), (float("nan"), "NAN"),
])
def test_format_tick(value, text):
    assert format_tick(value) == text


@given(st.floats(allow_nan=True, allow_infinity=True))
def test_every_tick_is_drawable_in_the_font(value):
    assert set(format_tick(value)) <= set(FONT_CHARACTERS)


def test_legend_scale_grows_one_step_per_240_rows():
    assert [legend_scale(h) for h in (1, 239, 240, 479, 480, 1000)] == [1, 1, 1, 1, 2, 4]


@pytest.mark.parametrize("lo, hi, height", [(0.0, 1.0, 120), (-12345.0, 0.001, 480), (1e-7, 3e9, 720),
                                            (0.5, 0.5, 100)])
def test_legend_width_holds_every_label(lo, hi, height):
    """Drawn into its own width and into a wider panel, the legend is the same and the extra columns stay
    background: nothing was clipped."""
    width = legend_width(lo, hi, height)
    tight = np.zeros((height, width, 3), np.float32)
    wide = np.zeros((height, width + 30, 3), np.float32)
    draw_legend(tight, lo, hi, "", 0)
    draw_legend(wide, lo, hi, "", 0)
    np.testing.assert_array_equal(wide[:, :width], tight)
    np.testing.assert_array_equal(wide[:, width:], np.broadcast_to(BACKGROUND, (height, 30, 3)))


def test_the_bar_runs_from_hi_at_the_top_to_lo_at_the_bottom():
    height, x_offset = 240, 100
    panel = np.zeros((height, legend_width(2.0, 10.0, height), 3), np.float32)
    legend = draw_legend(panel, 2.0, 10.0, "ao", x_offset)
    assert (legend.lo, legend.hi, legend.label) == (2.0, 10.0, "ao")
    assert legend.ticks == (2.0, 4.0, 6.0, 8.0, 10.0)
    assert 0 < legend.bar_top < legend.bar_bottom < height - 1
    x0, x1 = legend.bar_x[0] - x_offset, legend.bar_x[1] - x_offset
    assert 0 < x0 < x1 <= panel.shape[1]
    column = panel[legend.bar_top:legend.bar_bottom + 1, x0]
    np.testing.assert_array_equal(column[0], VIRIDIS[255])
    np.testing.assert_array_equal(column[-1], VIRIDIS[0])
    assert (np.diff(luminance(srgb_decode(column))) <= 0).all()  # viridis gets darker with the value
    # Every colour of the bar is a map entry, the same across the bar's width.
    assert all(np.abs(VIRIDIS - c).max(axis=1).min() == 0 for c in column)
    np.testing.assert_array_equal(panel[legend.bar_top:legend.bar_bottom + 1, x0:x1 - 2],
                                  np.repeat(column[:, None], x1 - 2 - x0, axis=1))
    # Outside the bar, the label and the tick labels, the panel is background.
    assert (panel[-1] == BACKGROUND).all() and (panel[:, 0] == BACKGROUND).all()


def test_tick_marks_sit_at_their_values():
    height = 300
    panel = np.zeros((height, legend_width(0.0, 1.0, height), 3), np.float32)
    legend = draw_legend(panel, 0.0, 1.0, "", 0)
    x1 = legend.bar_x[1]
    for value in legend.ticks:
        row = int(round(legend.bar_bottom - value * (legend.bar_bottom - legend.bar_top)))
        mark = panel[row, x1 - 1]
        # Light marks on the dark lower half of the bar, dark ones on the light upper half.
        np.testing.assert_array_equal(mark, np.full(3, 0.95 if value < 0.5 else 0.05, np.float32))


def test_the_label_is_drawn_and_cut_to_the_panel():
    height = 120
    width = legend_width(0.0, 1.0, height)
    with_label = np.zeros((height, width, 3), np.float32)
    without = np.zeros((height, width, 3), np.float32)
    draw_legend(with_label, 0.0, 1.0, "irradianceDirect+irradianceIndirect", 0)
    draw_legend(without, 0.0, 1.0, "", 0)
    differs = (with_label != without).any(axis=2)
    rows = np.flatnonzero(differs.any(axis=1))
    assert rows.min() == 4 and rows.max() == 8  # one 5-row line at the top: cut to the panel, not wrapped
    cols = np.flatnonzero(differs.any(axis=0))
    chars = (width - 2) // 4  # the characters that fit beside the 2-pixel margin at scale 1
    assert cols.min() == 2 and cols.max() <= 2 + 4 * chars - 2


def test_a_flat_range_and_a_tiny_panel():
    flat = np.zeros((100, legend_width(3.0, 3.0, 100), 3), np.float32)
    legend = draw_legend(flat, 3.0, 3.0, "", 0)
    assert legend.ticks == (3.0,) * 5 and np.isfinite(flat).all()
    tiny = np.zeros((10, 30, 3), np.float32)
    legend = draw_legend(tiny, 0.0, 1.0, "", 0)
    assert (legend.bar_top, legend.bar_bottom) == (1, 8)  # no room for labels: the bar fills the height
    np.testing.assert_array_equal(tiny[1, legend.bar_x[0]], VIRIDIS[255])
    np.testing.assert_array_equal(tiny[8, legend.bar_x[0]], VIRIDIS[0])
