"""RGB9E5 shared-exponent colour packing (OpenGL EXT_texture_shared_exponent, DirectX R9G9B9E5).

One 32-bit word holds three 9-bit mantissas and one shared 5-bit exponent::

    bits  0.. 8  red mantissa      bits 18..26  blue mantissa
    bits  9..17  green mantissa    bits 27..31  exponent (bias B = 15)

    value_c = mantissa_c * 2^(exponent - B - N),   N = 9 mantissa bits

Encoding follows the extension's reference algorithm exactly (section
"Encoding as GL_UNSIGNED_INT_5_9_9_9_REV"): each component is clamped to
``[0, MAX_RGB9E5]`` (NaN -> 0, negative -> 0, +inf -> MAX), the shared exponent
is ``max(-B - 1, floor(log2(max_c))) + 1 + B``, bumped by one when the largest
mantissa rounds to 2^N, and mantissas are rounded to nearest.

Error: every component is within half a mantissa step of its clamped value,
i.e. ``|decoded - clamped| <= 2^-9 * max_c * (1024 / 1023)`` (the factor
covers the bumped-exponent case), and at most ``2^-25`` absolutely for
colours below the smallest normal step (exponent 0).
"""

from __future__ import annotations

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

MANTISSA_BITS = 9
EXPONENT_BIAS = 15
MAX_EXPONENT = 31
MAX_RGB9E5 = float((2**MANTISSA_BITS - 1) / 2**MANTISSA_BITS * 2.0 ** (MAX_EXPONENT - EXPONENT_BIAS))
"""65408.0: the largest representable component."""

RELATIVE_ERROR = 2.0**-MANTISSA_BITS * 1024.0 / 1023.0
"""Bound on |decoded - clamped| / max component: half a mantissa step (see module docstring)."""

ABSOLUTE_ERROR = 2.0 ** -(EXPONENT_BIAS + MANTISSA_BITS + 1)
"""Bound on |decoded - clamped| for colours in the exponent-0 range (half of 2^-24)."""


def encode_rgb9e5(rgb: np.ndarray) -> np.ndarray:
    """Pack colours into RGB9E5 words.

    Parameters
    ----------
    rgb : (..., 3) array-like, any float dtype; NaN and negatives become 0, large values MAX_RGB9E5.

    Returns
    -------
    (...) uint32
    """
    rgb = np.asarray(rgb, np.float64)
    if rgb.shape[-1:] != (3,):
        raise ValueError(f"encode_rgb9e5: expected (..., 3) colours, got shape {rgb.shape}")
    clamped = np.nan_to_num(rgb, nan=0.0, posinf=MAX_RGB9E5, neginf=0.0)
    clamped = np.clip(clamped, 0.0, MAX_RGB9E5)
    max_c = clamped.max(axis=-1)
    _, e = np.frexp(max_c)  # max_c = m 2^e, m in [0.5, 1): floor(log2(max_c)) = e - 1
    floor_log2 = np.where(max_c > 0.0, e - 1, -EXPONENT_BIAS - 1)
    exp_shared = np.maximum(-EXPONENT_BIAS - 1, floor_log2) + 1 + EXPONENT_BIAS
    max_s = np.floor(max_c / np.exp2(exp_shared - EXPONENT_BIAS - MANTISSA_BITS) + 0.5)
    exp_shared = np.where(max_s >= 2**MANTISSA_BITS, exp_shared + 1, exp_shared)
    scale = np.exp2(exp_shared - EXPONENT_BIAS - MANTISSA_BITS)[..., None]
    mantissa = np.floor(clamped / scale + 0.5).astype(np.uint32)
    mantissa = np.minimum(mantissa, 2**MANTISSA_BITS - 1)  # unreachable by the algorithm; keeps bits apart
    return (mantissa[..., 0] | (mantissa[..., 1] << 9) | (mantissa[..., 2] << 18)
            | (exp_shared.astype(np.uint32) << 27)).astype(np.uint32)


def decode_rgb9e5(packed: np.ndarray) -> np.ndarray:
    """(...) uint32 RGB9E5 words -> (..., 3) float32 colours (exact: every value is a float32)."""
    packed = np.asarray(packed, np.uint32)
    mantissa = np.stack([(packed >> shift) & 0x1FF for shift in (0, 9, 18)], axis=-1).astype(np.float64)
    exponent = ((packed >> 27) & 0x1F).astype(np.float64)
    return (mantissa * np.exp2(exponent - EXPONENT_BIAS - MANTISSA_BITS)[..., None]).astype(np.float32)


@wp.func
def rgb9e5_decode(packed: wp.uint32) -> wp.vec3:
    """Warp twin of ``decode_rgb9e5`` for one word.

    value_c = mantissa_c * 2^(exponent - B - N), B = 15, N = 9: the shared
    exponent colour conversion of OpenGL EXT_texture_shared_exponent, the
    R9_G9_B9_E5 format Pacanowski et al. 2008, Sec. 3.3 store irradiance
    colours in (a shared-exponent relative of Ward's RGBE, "Real pixels",
    Graphics Gems II, 1991). The colour keeps the units it was encoded in
    (W/m^2 for irradiance).
    """
    r = float(int(packed & wp.uint32(0x1FF)))
    g = float(int((packed >> wp.uint32(9)) & wp.uint32(0x1FF)))
    b = float(int((packed >> wp.uint32(18)) & wp.uint32(0x1FF)))
    e = float(int((packed >> wp.uint32(27)) & wp.uint32(0x1F)))
    scale = wp.pow(2.0, e - 24.0)  # 2^(e - B - N)
    return wp.vec3(r * scale, g * scale, b * scale)
