"""The false-colour legend: a viridis bar with tick labels in a built-in 3 x 5 bitmap font (no font files)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .color import BACKGROUND, false_color

# ---------------------------------------------------------------------------
# Font

FONT_CHARACTERS = "0123456789.-+:/() _[]=%ABCDEFGHIJKLMNOPQRSTUVWXYZ"
FONT_GLYPHS = (
    "75557 26227 71747 71717 55711 74717 74757 71111 75757 75717 00002 00700 02720 02020 11244 24442 21112 "
    "00000 00007 64446 31113 07070 51245 25755 65656 34443 65556 74647 74644 34553 55755 72227 11152 55655 "
    "44447 57755 65555 25552 65644 25573 65655 34216 72222 55557 55522 55775 55255 55222 71247"
)
"""The 3 x 5 bitmap font, one glyph per FONT_CHARACTERS character: five octal digits, the rows top to
bottom, each digit's bits the columns (4 left, 2 middle, 1 right); "75557" is a zero."""

_GLYPH_BITS = {ch: np.array([[int(row) & bit != 0 for bit in (4, 2, 1)] for row in rows], bool)
               for ch, rows in zip(FONT_CHARACTERS, FONT_GLYPHS.split(), strict=True)}


def text_mask(text: str, scale: int = 1) -> np.ndarray:
    """(5 s, 4 s * len - s) bool mask of ``text`` in the built-in font (lower case drawn as upper case)."""
    if not text:
        return np.zeros((5 * scale, 0), bool)
    glyphs = [_GLYPH_BITS.get(ch.upper(), _GLYPH_BITS["-"] & False) for ch in text]
    row = np.zeros((5, 4 * len(glyphs) - 1), bool)
    for k, glyph in enumerate(glyphs):
        row[:, 4 * k:4 * k + 3] = glyph
    return np.kron(row, np.ones((scale, scale), bool)).astype(bool)


def draw_text(image: np.ndarray, text: str, x: int, y: int, color, scale: int = 1) -> None:
    """Draw ``text`` into ``image`` ((H, W, 3) float) with its top-left corner at (x, y), clipped."""
    mask = text_mask(text, scale)
    h, w = mask.shape
    y0, x0 = max(y, 0), max(x, 0)
    y1, x1 = min(y + h, image.shape[0]), min(x + w, image.shape[1])
    if y1 <= y0 or x1 <= x0:
        return
    region = mask[y0 - y:y1 - y, x0 - x:x1 - x]
    image[y0:y1, x0:x1][region] = np.asarray(color, np.float32)


def format_tick(value: float) -> str:
    return f"{value:.3g}".upper().replace("E+0", "E").replace("E-0", "E-")


# ---------------------------------------------------------------------------
# Legend


@dataclass(frozen=True)
class Legend:
    """The false-colour scale drawn beside the image."""

    lo: float
    hi: float
    label: str
    ticks: tuple[float, ...]
    bar_top: int
    """Row of the legend bar's top (value hi) in the composed image."""
    bar_bottom: int
    """Row of the legend bar's bottom (value lo), inclusive."""
    bar_x: tuple[int, int]
    """Columns [x0, x1) of the bar in the composed image."""


def legend_scale(height: int) -> int:
    """Font scale: 1 below 240 rows, then one more per 240 rows."""
    return max(1, height // 240)


def legend_width(lo: float, hi: float, height: int) -> int:
    s = legend_scale(height)
    chars = max(len(format_tick(v)) for v in np.linspace(lo, hi, 5))
    return 6 * s + 8 * s + 3 * s + 4 * s * chars + 4 * s


def draw_legend(panel: np.ndarray, lo: float, hi: float, label: str, x_offset: int) -> Legend:
    """Draw a vertical viridis bar (hi at the top) with 5 tick labels into ``panel`` ((H, w, 3) float)."""
    height = panel.shape[0]
    s = legend_scale(height)
    panel[:] = BACKGROUND
    top, bottom = 6 * s + 5 * s + 6 * s, height - 1 - 8 * s
    if bottom - top < 4:  # too small an image for a bar: keep the labels out, still draw a bar
        top, bottom = 1, max(2, height - 2)
    x0, x1 = 6 * s, 6 * s + 8 * s
    rows = np.arange(top, bottom + 1)
    t = (bottom - rows) / max(bottom - top, 1)
    panel[top:bottom + 1, x0:x1] = false_color(lo + t * (hi - lo), lo, hi)[:, None, :]
    draw_text(panel, label[: max(1, (panel.shape[1] - 2 * s) // (4 * s))], 2 * s, 4 * s, (0.9, 0.9, 0.9), s)
    ticks = tuple(float(v) for v in np.linspace(lo, hi, 5))
    for value in ticks:
        frac = 0.0 if hi == lo else (value - lo) / (hi - lo)
        row = int(round(bottom - frac * (bottom - top)))
        panel[row:row + s, x1 - 2 * s:x1] = (0.95, 0.95, 0.95) if frac < 0.5 else (0.05, 0.05, 0.05)
        draw_text(panel, format_tick(value), x1 + 3 * s, row - (5 * s) // 2, (0.9, 0.9, 0.9), s)
    return Legend(lo, hi, label, ticks, top, bottom, (x_offset + x0, x_offset + x1))

