"""BC1 (DXT1) block compression: a vectorized numpy encoder and decoder.

A BC1 block codes 4x4 RGB texels in 8 bytes: two RGB565 endpoints (little-endian
uint16 ``color0``, ``color1``) and 16 two-bit palette indices (texel ``k = 4*y + x``
in bits ``2k .. 2k+1`` of the following little-endian uint32). With
``color0 > color1`` the palette is {c0, c1, (2 c0 + c1) / 3, (c0 + 2 c1) / 3};
otherwise {c0, c1, (c0 + c1) / 2, black}. Endpoints expand from 5/6 bits to 8
bits as round(v * 255 / 31) (or / 63) and the interpolated colours round to
the nearest byte, round((2 a + b) / 3) and round((a + b) / 2) -- the
convention OpenImageIO's DDS reader uses, so both decode to identical bytes
(tests check it). The decoder returns exact bytes and a 256-entry table can map
bytes to values (``processors.radiosity.operator_relight`` decodes each block's palette once,
at load, and its kernel reads the texel codes).

The encoder is a range fit along the principal axis of each block's colours,
followed by one least-squares refinement of the two endpoints given the
chosen indices, keeping per block whichever has the smaller squared error.
It always emits the 4-colour mode (``color0 > color1``), or a constant block
with all indices 0 when both endpoints quantize to the same colour.

References
----------
Microsoft, "Block Compression (Direct3D 10)", BC1 format.
"""

from __future__ import annotations

import numpy as np

BLOCK_BYTES = 8
CHUNK_BLOCKS = 1 << 16
"""Blocks encoded per numpy step (bounds the temporaries to ~50 MB)."""


# ---------------------------------------------------------------------------
# numpy: RGB565 helpers


def _expand565(color: np.ndarray) -> np.ndarray:
    """(N,) uint16 RGB565 -> (N, 3) int32 8-bit channels, round(v * 255 / 31) and round(v * 255 / 63)."""
    color = color.astype(np.int32)
    r = (color >> 11) & 31
    g = (color >> 5) & 63
    b = color & 31
    return np.stack([(r * 510 + 31) // 62, (g * 510 + 63) // 126, (b * 510 + 31) // 62], axis=-1)


def _quantize565(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) float in [0, 255] -> (...) uint16 RGB565 (rounded to the nearest level)."""
    rgb = np.clip(rgb, 0.0, 255.0)
    r = np.rint(rgb[..., 0] * (31.0 / 255.0)).astype(np.int32)
    g = np.rint(rgb[..., 1] * (63.0 / 255.0)).astype(np.int32)
    b = np.rint(rgb[..., 2] * (31.0 / 255.0)).astype(np.int32)
    return ((r << 11) | (g << 5) | b).astype(np.uint16)


def bc1_palette_np(color0: np.ndarray, color1: np.ndarray) -> np.ndarray:
    """(N,) uint16 endpoints -> (N, 4, 3) int32 palette bytes (both BC1 modes)."""
    a = _expand565(color0)
    b = _expand565(color1)
    four = (color0 > color1)[:, None]
    p2 = np.where(four, (4 * a + 2 * b + 3) // 6, (a + b + 1) // 2)
    p3 = np.where(four, (2 * a + 4 * b + 3) // 6, 0)
    return np.stack([a, b, p2, p3], axis=1)


# ---------------------------------------------------------------------------
# numpy: blocks <-> images


def image_to_blocks(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) -> (H/4 * W/4, 16, 3), blocks in row-major order, texels row-major within a block."""
    h, w, c = image.shape
    if h % 4 or w % 4:
        raise ValueError(f"image size {w}x{h} is not a multiple of 4")
    return image.reshape(h // 4, 4, w // 4, 4, c).transpose(0, 2, 1, 3, 4).reshape(-1, 16, c)


def blocks_to_image(texels: np.ndarray, height: int, width: int) -> np.ndarray:
    """Inverse of image_to_blocks."""
    c = texels.shape[-1]
    return texels.reshape(height // 4, width // 4, 4, 4, c).transpose(0, 2, 1, 3, 4).reshape(height, width, c)


def _best_indices(texels: np.ndarray, palette: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest palette entry per texel: (N, 16) indices and (N,) weighted summed squared error."""
    d = ((texels[:, :, None, :] - palette[:, None, :, :].astype(np.float32)) ** 2).sum(-1)  # (N, 16, 4)
    index = d.argmin(-1)
    return index, (np.take_along_axis(d, index[..., None], -1)[..., 0] * weights).sum(-1)


def _pack(color0: np.ndarray, color1: np.ndarray, index: np.ndarray) -> np.ndarray:
    bits = (index.astype(np.uint32) << (2 * np.arange(16, dtype=np.uint32))).sum(-1, dtype=np.uint64)
    out = np.empty((len(color0), 2), np.uint32)
    out[:, 0] = color0.astype(np.uint32) | (color1.astype(np.uint32) << 16)
    out[:, 1] = bits.astype(np.uint32)
    return out.view(np.uint8).reshape(-1, BLOCK_BYTES)


def _endpoints_to_blocks(texels: np.ndarray, weights: np.ndarray, e0: np.ndarray, e1: np.ndarray):
    """Quantize float endpoints, order them for 4-colour mode, pick indices: (color0, color1, index, sse)."""
    c0 = _quantize565(e0)
    c1 = _quantize565(e1)
    swap = c0 < c1
    c0, c1 = np.where(swap, c1, c0), np.where(swap, c0, c1)
    palette = bc1_palette_np(c0, c1)
    index, sse = _best_indices(texels, palette, weights)
    # c0 == c1 is the 3-colour mode: a constant block, index 0 everywhere is exact for it.
    index = np.where((c0 == c1)[:, None], 0, index)
    return c0, c1, index, sse


def _encode_chunk(texels: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(N, 16, 3) float32 in [0, 255] and (N, 16) texel weights (each block's sum 1 or 0) -> (N, 8) uint8
    blocks. The fit minimizes the weighted squared error; a texel of weight 0 is free (any colour)."""
    mean = np.einsum("nk,nkc->nc", weights, texels)[:, None, :]
    centred = texels - mean
    cov = np.einsum("nk,nki,nkj->nij", weights, centred, centred)
    # Principal axis: the eigenvector of the largest eigenvalue of each block's 3x3 covariance (a
    # power iteration started from grey misses colours that vary at right angles to grey, such as a
    # red-green ramp). Flat blocks get some unit axis and t = 0, so both endpoints are the mean.
    axis = np.linalg.eigh(cov.astype(np.float64))[1][:, :, -1].astype(np.float32)
    t = np.einsum("nki,ni->nk", centred, axis)
    counted = weights > 0  # the range spans the texels that count (all of them in a block of zero weight)
    counted |= ~counted.any(axis=1, keepdims=True)
    e0 = mean[:, 0] + axis * np.where(counted, t, -np.inf).max(axis=1, keepdims=True)
    e1 = mean[:, 0] + axis * np.where(counted, t, np.inf).min(axis=1, keepdims=True)
    c0, c1, index, sse = _endpoints_to_blocks(texels, weights, e0, e1)

    # One weighted least-squares refit of the endpoints given the indices: texel ~ w a + (1 - w) b.
    weight = np.array([1.0, 0.0, 2.0 / 3.0, 1.0 / 3.0], np.float32)[index]  # (N, 16)
    aa = (weights * weight * weight).sum(1)
    bb = (weights * (1 - weight) ** 2).sum(1)
    ab = (weights * weight * (1 - weight)).sum(1)
    ax = np.einsum("nk,nkc->nc", weights * weight, texels)
    bx = np.einsum("nk,nkc->nc", weights * (1 - weight), texels)
    det = aa * bb - ab * ab
    ok = np.abs(det) > 1e-6
    safe = np.where(ok, det, 1.0)[:, None]
    fa = np.where(ok[:, None], (bb[:, None] * ax - ab[:, None] * bx) / safe, e0)
    fb = np.where(ok[:, None], (aa[:, None] * bx - ab[:, None] * ax) / safe, e1)
    r0, r1, rindex, rsse = _endpoints_to_blocks(texels, weights, fa, fb)
    better = rsse < sse
    c0 = np.where(better, r0, c0)
    c1 = np.where(better, r1, c1)
    index = np.where(better[:, None], rindex, index)
    return _pack(c0, c1, index)


def encode_bc1(image: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Encode an RGB image to BC1 blocks.

    Parameters
    ----------
    image : (H, W, 3) float or uint8, values in [0, 255]; H and W multiples of 4.
    weights : (H, W) non-negative texel weights of the squared error the fit minimizes (default: all
        equal); a texel of weight 0 may decode to anything (a value stored elsewhere).

    Returns
    -------
    (H/4 * W/4, 8) uint8 blocks, block rows top to bottom, as stored in a DDS file.
    """
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got {image.shape}")
    texels = image_to_blocks(np.nan_to_num(image.astype(np.float32), nan=0.0))
    if weights is None:
        weights = np.ones(image.shape[:2], np.float32)
    if weights.shape != image.shape[:2]:
        raise ValueError(f"weights {weights.shape} do not match the image {image.shape[:2]}")
    texel_weights = image_to_blocks(np.nan_to_num(np.asarray(weights, np.float32), nan=0.0)[..., None])[..., 0]
    texel_weights = np.maximum(texel_weights, 0.0)
    totals = texel_weights.sum(axis=1, keepdims=True)
    texel_weights = np.where(totals > 0, texel_weights / np.where(totals > 0, totals, 1.0), 0.0)
    out = np.empty((len(texels), BLOCK_BYTES), np.uint8)
    for lo in range(0, len(texels), CHUNK_BLOCKS):
        out[lo:lo + CHUNK_BLOCKS] = _encode_chunk(np.clip(texels[lo:lo + CHUNK_BLOCKS], 0.0, 255.0),
                                                  texel_weights[lo:lo + CHUNK_BLOCKS].astype(np.float32))
    return out


def decode_bc1_texels(blocks: np.ndarray) -> np.ndarray:
    """(N, 8) uint8 blocks -> (N, 16, 3) uint8 texels."""
    words = np.ascontiguousarray(blocks, np.uint8).reshape(-1, 8).view(np.uint32)
    color0 = (words[:, 0] & 0xFFFF).astype(np.uint16)
    color1 = (words[:, 0] >> 16).astype(np.uint16)
    palette = bc1_palette_np(color0, color1)
    index = (words[:, 1:2] >> (2 * np.arange(16, dtype=np.uint32))) & 3
    return np.take_along_axis(palette, index[..., None].astype(np.int64), axis=1).astype(np.uint8)


def decode_bc1(blocks: np.ndarray, height: int, width: int) -> np.ndarray:
    """(H/4 * W/4, 8) uint8 blocks -> (H, W, 3) uint8 image."""
    return blocks_to_image(decode_bc1_texels(blocks), height, width)
