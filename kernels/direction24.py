"""24-bit directions (8:8:8) on the six axis hemispheres, as Pacanowski et al. 2008, section 3.3.

An irradiance vector of hemisphere ``delta`` (+x, -x, +y, -y, +z, -z) points
into that hemisphere (it is an integral of ``L(w) w`` with ``w . delta >= 0``
and ``L >= 0``). Its unit direction is stored as three signed bytes, one per
component: ``q = round(127 d)`` in [-127, 127], kept as ``q + 128`` (uint8,
1..255), decoded as ``q / |q|``. Axis directions are exact (``q = (127, 0,
0)`` decodes to ``(1, 0, 0)``), so with the paper's colour ``c = I . delta /
(d' . delta)`` a surface facing an axis reads its irradiance exactly.

The component along ``delta`` is stored as at least 1 (in delta's sign), so a
decoded direction never leaves its hemisphere: its cosine to delta is at
least ``MIN_AXIS_COSINE`` and ``c`` stays finite. Each component is off by at
most 0.5/127, the clamped one by at most 1/127, so a decoded direction is
within ``MAX_ANGLE_ERROR_DEG`` of the encoded one.
"""

from __future__ import annotations

import math

import numpy as np

from .rgb9e5 import decode_rgb9e5

AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float32)
"""(6, 3) the hemisphere axes delta in storage order: +x, -x, +y, -y, +z, -z."""

STEPS = 127
"""Quantization steps per unit of a component: signed bytes without -128."""

MAX_ANGLE_ERROR_DEG = math.degrees(math.asin(math.sqrt(2 * (0.5 / STEPS) ** 2 + (1.0 / STEPS) ** 2)))
"""Bound on the angle between a unit vector and its decoded code (0.55 degrees): the error vector's
length bounds the sine of the angle."""

MIN_AXIS_COSINE = 1.0 / math.sqrt(1 + 2 * STEPS ** 2)
"""Smallest cosine of a decoded direction to its hemisphere's axis (components (1, 127, 127))."""


def encode_directions(vectors: np.ndarray, hemisphere: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 codes of the directions of ``vectors`` (N, 3), each in hemisphere ``hemisphere`` (N,)
    (indices into AXES). A zero or non-finite vector gets its hemisphere's axis."""
    v = np.nan_to_num(np.asarray(vectors, np.float64).reshape(-1, 3), nan=0.0, posinf=0.0, neginf=0.0)
    hemisphere = np.asarray(hemisphere, np.int64).reshape(-1)
    axes = AXES[hemisphere].astype(np.float64)
    length = np.linalg.norm(v, axis=1, keepdims=True)
    unit = np.where(length > 0, v / np.maximum(length, 1e-300), axes)
    q = np.rint(unit * STEPS).astype(np.int64)
    component, sign = hemisphere // 2, 1 - 2 * (hemisphere % 2)
    rows = np.arange(len(q))
    q[rows, component] = sign * np.maximum(sign * q[rows, component], 1)
    return (q + 128).astype(np.uint8)


def decode_directions(codes: np.ndarray) -> np.ndarray:
    """(N, 3) float32 unit directions of (N, 3) uint8 codes (the all-zero direction, which no encoding
    makes, decodes to zero)."""
    q = np.asarray(codes, np.float64).reshape(-1, 3) - 128.0
    length = np.linalg.norm(q, axis=1, keepdims=True)
    return np.where(length > 0, q / np.maximum(length, 1e-300), 0.0).astype(np.float32)


def dequantize_vectors(directions: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """(N, 6, 3) uint8 directions + (N, 6) uint32 RGB9E5 colours of irradiance-grid vertices -> (N, 6, 3, 3)
    float32 vectors c d' (rows = RGB): the decoder of the baker and of stream clients alike."""
    directions = np.asarray(directions, np.uint8).reshape(-1, 6, 3)
    n = len(directions)
    d = decode_directions(directions.reshape(-1, 3))
    c = decode_rgb9e5(np.asarray(colors, np.uint32).reshape(-1))
    return (c[:, :, None] * d[:, None, :]).reshape(n, 6, 3, 3).astype(np.float32)
