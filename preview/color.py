"""Colour of the preview: tone mapping for colour channels, viridis false colour for scalars.

Tone mapping (colour channels): ``linear * 2^EV`` then the ACES filmic fit
of Narkowicz (2015), f(x) = x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14)
clamped to [0, 1], then the sRGB transfer function. With ``exposure=None``
the exposure is automatic: the median luminance of the shaded pixels maps
to 0.18 (middle grey) before the curve.

False colour (scalar channels): ``VIRIDIS``, 33 knots of the viridis map
(van der Walt & Smith, matplotlib), linearly interpolated; within 2.5/255 of
matplotlib's 256-entry table (checked in tests when matplotlib is present).
The map's output is display (sRGB) colour: no tone mapping.

References
----------
Narkowicz, K. (2015). ACES Filmic Tone Mapping Curve.
https://knarkowicz.wordpress.com/2016/01/06/aces-filmic-tone-mapping-curve/
"""

from __future__ import annotations

import numpy as np

from ..kernels.lights import LUMINANCE

BACKGROUND = np.array([0.16, 0.16, 0.17], np.float32)
"""Display colour of pixels that hit nothing (and of the legend panel)."""

MIDDLE_GREY = 0.18
"""Linear luminance the automatic exposure maps the median to."""

# Viridis at 33 evenly spaced knots (matplotlib's table rounded to 4 decimals).
VIRIDIS_KNOTS = np.array([
    (0.2670, 0.0049, 0.3294), (0.2770, 0.0503, 0.3757), (0.2823, 0.0950, 0.4173), (0.2829, 0.1359, 0.4534),
    (0.2788, 0.1755, 0.4834), (0.2706, 0.2141, 0.5071), (0.2590, 0.2515, 0.5247), (0.2450, 0.2877, 0.5373),
    (0.2297, 0.3224, 0.5457), (0.2143, 0.3556, 0.5512), (0.1994, 0.3876, 0.5546), (0.1856, 0.4186, 0.5568),
    (0.1727, 0.4488, 0.5579), (0.1607, 0.4785, 0.5581), (0.1490, 0.5081, 0.5572), (0.1378, 0.5375, 0.5549),
    (0.1276, 0.5669, 0.5506), (0.1206, 0.5964, 0.5436), (0.1206, 0.6258, 0.5335), (0.1323, 0.6550, 0.5197),
    (0.1579, 0.6838, 0.5017), (0.1966, 0.7118, 0.4792), (0.2461, 0.7389, 0.4520), (0.3041, 0.7647, 0.4199),
    (0.3692, 0.7889, 0.3829), (0.4401, 0.8111, 0.3410), (0.5160, 0.8312, 0.2943), (0.5958, 0.8487, 0.2433),
    (0.6785, 0.8637, 0.1895), (0.7624, 0.8764, 0.1371), (0.8456, 0.8873, 0.0997), (0.9261, 0.8973, 0.1041),
    (0.9932, 0.9062, 0.1439),
], np.float32)


def _viridis_table() -> np.ndarray:
    t = np.linspace(0.0, 1.0, 256)
    knots = np.linspace(0.0, 1.0, len(VIRIDIS_KNOTS))
    return np.stack([np.interp(t, knots, VIRIDIS_KNOTS[:, c]) for c in range(3)], axis=1).astype(np.float32)


VIRIDIS = _viridis_table()
"""(256, 3) float32 sRGB viridis table."""


ACES_SATURATED = np.float32(1e4)
"""The fit is 1 (to float32 precision) from x ~ 7.24 on; inputs are clamped here so x * x cannot overflow."""


def aces_fitted(x: np.ndarray) -> np.ndarray:
    """Narkowicz's ACES filmic fit, clamped to [0, 1]."""
    x = np.clip(np.asarray(x, np.float32), 0.0, ACES_SATURATED)  # x * x stays finite in float32
    return np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """sRGB transfer function of linear values in [0, 1]."""
    linear = np.clip(np.asarray(linear, np.float32), 0.0, 1.0)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    encoded = np.clip(np.asarray(encoded, np.float32), 0.0, 1.0)
    return np.where(encoded <= 0.04045, encoded / 12.92, np.power((encoded + 0.055) / 1.055, 2.4))


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance of linear RGB (..., 3)."""
    return np.asarray(rgb, np.float32) @ LUMINANCE.astype(np.float32)


def auto_exposure(linear: np.ndarray) -> float:
    """EV that maps the median luminance of ``linear`` ((N, 3)) to middle grey; 0 when all dark."""
    lum = luminance(linear)
    lum = lum[np.isfinite(lum) & (lum > 0)]
    if len(lum) == 0:
        return 0.0
    return float(np.log2(MIDDLE_GREY / np.median(lum)))


def tone_map(linear: np.ndarray) -> np.ndarray:
    """Display sRGB in [0, 1] of exposed linear RGB (already times 2^EV): the ACES fit, then sRGB encoding."""
    return srgb_encode(aces_fitted(linear))


def false_color(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(..., 3) sRGB viridis colours of ``values`` normalized to [lo, hi] (NaN -> lo)."""
    span = hi - lo if hi > lo else 1.0
    t = np.nan_to_num((np.asarray(values, np.float64) - lo) / span, nan=0.0)
    index = np.clip(np.rint(t * 255.0), 0, 255).astype(np.int64)
    return VIRIDIS[index]

