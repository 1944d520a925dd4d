"""Shading: a traced ``raycast.Frame`` -> the finished preview ``Image``.

Scalar channels in false colour (``color.false_color``) with a legend,
colour channels multiplied by the albedo and tone mapped (``color.tone_map``),
surfaces without the channel grey under a headlight, probe / grid spheres,
the wire overlay.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .color import BACKGROUND, auto_exposure, false_color, srgb_decode, tone_map
from .legend import Legend, draw_legend, legend_width
from .raycast import Frame

NO_DATA_GREY = 0.55
"""Display grey of surfaces that carry no value of the channel (times the headlight cosine)."""

WIRE_COLOR = np.array([0.02, 0.02, 0.02], np.float32)
WIRE_OPACITY = 0.85


def headlight(facing: np.ndarray) -> np.ndarray:
    """Shading factor 0.25 + 0.75 |n . d| of a light at the eye: grazing faces stay readable."""
    return 0.25 + 0.75 * facing


@dataclass(frozen=True)
class Image:
    """A finished preview."""

    display: np.ndarray
    """(H, W_total, 3) float32 display (sRGB) colour in [0, 1], legend included."""
    linear: np.ndarray
    """(H, W_view, 3) float32 linear colour of the 3D view after exposure, before the curve."""
    value: np.ndarray
    """(H, W_view, C) float32 raw channel value per pixel (0 where no data), C = 1 or 3."""
    coverage: np.ndarray
    """(H, W_view) float32: 1 where a surface or sphere was hit."""
    view_width: int
    exposure: float
    legend: Legend | None = None


def shade(frame: Frame, tri_albedo: np.ndarray, *, tri_has_value: np.ndarray | None, channels: int,
          style: str, value_range: tuple[float, float] | None = None, label: str = "",
          exposure: float | None = None, irradiance: bool = False, legend: bool = True,
          legend_panel: int | None = None, sphere_colors: np.ndarray | None = None) -> Image:
    """Turn a Frame into display colour.

    style : 'falsecolor' (scalar channel through VIRIDIS with a legend), 'shaded' (channel times
        albedo, tone mapped; irradiance channels are divided by pi: Lambertian radiance
        L = albedo * E / pi) or 'albedo' (no channel: albedo under a headlight).
    tri_has_value : (T,) bool, triangles that carry the channel (others are drawn grey).
    value_range : (lo, hi) of the false-colour scale; required for 'falsecolor'.
    legend_panel : width reserved for the legend (the frame is the view only).
    sphere_colors : (S, 3) float32 linear colours, or (H, W, 3) per-pixel colours of sphere hits.
    """
    height, width = frame.hit_triangle.shape
    tri = frame.hit_triangle
    surface = tri >= 0
    safe = np.where(surface, tri, 0)
    has_value = surface & (tri_has_value[safe] if tri_has_value is not None else surface)
    albedo = np.asarray(tri_albedo, np.float32)[safe] if len(tri_albedo) else np.zeros((height, width, 3), np.float32)
    value = frame.value[..., :channels]
    lit = headlight(frame.facing[..., None])

    linear = np.zeros((height, width, 3), np.float32)
    if style == "falsecolor":
        lo, hi = value_range if value_range is not None else (0.0, 1.0)
        display = np.where(has_value[..., None], false_color(frame.value[..., 0], lo, hi),
                           NO_DATA_GREY * lit).astype(np.float32)
        display = np.where(surface[..., None], display, BACKGROUND)
        linear = np.where(surface[..., None], srgb_decode(display), 0.0).astype(np.float32)
        used_exposure = 0.0
    else:
        if style == "shaded":
            lighting = value if channels == 3 else np.repeat(value, 3, axis=2)
            lighting = np.maximum(lighting, 0.0) / (np.pi if irradiance else 1.0)
            linear = np.where(has_value[..., None], albedo * lighting, albedo * lit * 0.5)
        else:
            linear = albedo * lit
        linear = np.where(surface[..., None], linear, 0.0).astype(np.float32)
        used_exposure = auto_exposure(linear[has_value if style == "shaded" else surface]) \
            if exposure is None else float(exposure)
        linear = linear * np.float32(2.0 ** used_exposure)
        display = np.where(surface[..., None], tone_map(linear), BACKGROUND).astype(np.float32)
        lo = hi = 0.0

    if sphere_colors is not None and (frame.sphere >= 0).any():
        on_sphere = frame.sphere >= 0
        colors = np.asarray(sphere_colors, np.float32)
        if colors.ndim == 3:  # per-pixel lighting (e.g. SH irradiance at the sphere normal): no headlight
            sphere_linear = colors
        else:
            sphere_linear = colors[np.where(on_sphere, frame.sphere, 0)] * lit
        sphere_linear = (sphere_linear * np.float32(2.0 ** used_exposure)).astype(np.float32)
        display = np.where(on_sphere[..., None], tone_map(sphere_linear), display)
        linear = np.where(on_sphere[..., None], sphere_linear, linear)
        surface = surface | on_sphere

    if frame.wire.any():
        wire = frame.wire[..., None] & (frame.sphere < 0)[..., None]
        display = np.where(wire, display * (1 - WIRE_OPACITY) + WIRE_COLOR * WIRE_OPACITY, display)

    raw = np.where((has_value & (frame.sphere < 0))[..., None], value, 0.0).astype(np.float32)
    drawn_legend = None
    if style == "falsecolor" and legend:
        panel_width = legend_panel if legend_panel is not None else legend_width(lo, hi, height)
        panel = np.zeros((height, panel_width, 3), np.float32)
        drawn_legend = draw_legend(panel, lo, hi, label, width)
        display = np.concatenate([display, panel], axis=1)
    return Image(display=np.clip(display, 0, 1).astype(np.float32), linear=linear, value=raw,
                 coverage=surface.astype(np.float32), view_width=width, exposure=used_exposure,
                 legend=drawn_legend)

