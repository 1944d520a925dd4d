"""8-bit directions on the six axis hemispheres (hemi-octahedral, 4 + 4 bits).

An irradiance vector of hemisphere ``delta`` (+x, -x, +y, -y, +z, -z) always
points into that hemisphere (it is an integral of ``L(w) w`` with
``w . delta >= 0`` and ``L >= 0``), so its direction needs only half the
sphere: 256 codes over a hemisphere instead of the paper's 24 bits
(Pacanowski et al. 2008, section 3.3) or a full-sphere 8-bit code.

Mapping (code ``c``, ``i = c & 15``, ``j = c >> 4``):

1. In the hemisphere's frame (rows of ``HEMISPHERE_FRAMES[k]``: tangent t,
   bitangent b, axis delta), a unit vector ``(x, y, z)``, ``z >= 0``, goes to
   the diamond ``p = (x, y) / (|x| + |y| + z)``, ``|p.x| + |p.y| <= 1``
   (hemi-octahedral map);
2. rotated by 45 degrees onto the square ``u = p.x + p.y``, ``v = p.x - p.y``
   in ``[-1, 1]^2``;
3. a 16 x 16 grid of cells; cell (i, j) decodes to its centre
   ``u = (i + 0.5) / 8 - 1``, ``v = (j + 0.5) / 8 - 1``, and back through
   ``p = ((u + v) / 2, (u - v) / 2)``, ``z = 1 - |p.x| - |p.y|``, normalized.

Encoding picks the codebook direction nearest in angle (brute force over the
256 entries, not the cell the vector falls in), so the error is the codebook's
covering radius: ``MAX_ANGLE_ERROR_DEG`` (``max_angle_error_deg()``, measured on
first use, not at import). Decoded directions stay at least ``MIN_AXIS_COSINE``
above the hemisphere's rim, which keeps the paper's colour
``c = I . delta / (d . delta)`` bounded.
"""

from __future__ import annotations

import functools

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})

AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float32)
"""(6, 3) the hemisphere axes delta in storage order: +x, -x, +y, -y, +z, -z."""

HEMISPHERE_FRAMES = np.array([
    [[0, 1, 0], [0, 0, 1], [1, 0, 0]],     # +x: t = +y, b = +z
    [[0, 0, 1], [0, 1, 0], [-1, 0, 0]],    # -x: t = +z, b = +y
    [[0, 0, 1], [1, 0, 0], [0, 1, 0]],     # +y: t = +z, b = +x
    [[1, 0, 0], [0, 0, 1], [0, -1, 0]],    # -y: t = +x, b = +z
    [[1, 0, 0], [0, 1, 0], [0, 0, 1]],     # +z: t = +x, b = +y
    [[0, 1, 0], [1, 0, 0], [0, 0, -1]],    # -z: t = +y, b = +x
], np.float32)
"""(6, 3, 3) right-handed frames, rows (t, b, delta): local = frame @ world, world = local @ frame."""

GRID = 16
"""Cells per side of the square (4 bits each for u and v)."""


def _codebook() -> np.ndarray:
    c = np.arange(256)
    u = ((c & 15) + 0.5) / 8.0 - 1.0
    v = ((c >> 4) + 0.5) / 8.0 - 1.0
    px, py = (u + v) / 2.0, (u - v) / 2.0
    z = 1.0 - np.abs(px) - np.abs(py)
    d = np.stack([px, py, z], axis=1)
    return (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)


CODEBOOK = _codebook()
"""(256, 3) float32 unit local directions (z > 0) of the 256 codes."""

MIN_AXIS_COSINE = float(CODEBOOK[:, 2].min())
"""Smallest delta-cosine of a decoded direction (about 0.067: 3.8 degrees above the rim)."""


@functools.cache
def max_angle_error_deg() -> float:
    """Largest angle between a hemisphere direction and its decoded code, in degrees (about 8.8).

    Measured on a dense deterministic cover of the hemisphere (a 512 x 512 octahedral lattice, rim
    included) as the largest angle to the nearest code, plus the lattice's own spacing as a safety
    margin. A (262144, 256) product: computed on first use, then cached, never at import.
    """
    n = 512
    u, v = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    px, py = (u + v) / 2.0, (u - v) / 2.0
    z = 1.0 - np.abs(px) - np.abs(py)
    d = np.stack([px.ravel(), py.ravel(), z.ravel()], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    best = np.max(d @ CODEBOOK.T.astype(np.float64), axis=1)
    spacing = np.degrees(np.pi / 2 * 2.0 / (n - 1))
    return float(np.degrees(np.arccos(np.clip(best.min(), -1, 1))) + spacing)


def __getattr__(name: str):
    # PEP 562: ``MAX_ANGLE_ERROR_DEG`` reads as a module constant but is measured on first access.
    if name == "MAX_ANGLE_ERROR_DEG":
        return max_angle_error_deg()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def encode_hemisphere(directions: np.ndarray, hemisphere: np.ndarray) -> np.ndarray:
    """8-bit codes of directions in their hemispheres.

    Parameters
    ----------
    directions : (N, 3) float vectors (need not be unit; zero or non-finite -> the axis itself)
    hemisphere : (N,) int in 0..5 (index into AXES)

    Returns
    -------
    (N,) uint8 codes; directions below the hemisphere's rim map to the nearest code (near the rim).
    """
    directions = np.asarray(directions, np.float64).reshape(-1, 3)
    hemisphere = np.asarray(hemisphere, np.int64).reshape(-1)
    if len(directions) != len(hemisphere):
        raise ValueError(f"{len(directions)} directions but {len(hemisphere)} hemisphere indices")
    if len(hemisphere) and (hemisphere.min() < 0 or hemisphere.max() > 5):
        raise ValueError("hemisphere indices must be in 0..5")
    local = np.einsum("nij,nj->ni", HEMISPHERE_FRAMES[hemisphere].astype(np.float64), directions)
    length = np.linalg.norm(local, axis=1)
    bad = ~np.isfinite(length) | (length <= 0.0)
    local = np.where(bad[:, None], [0.0, 0.0, 1.0], local)
    codes = np.empty(len(local), np.uint8)
    book = CODEBOOK.T.astype(np.float64)
    for lo in range(0, len(local), 65536):  # (chunk, 256) dot products at a time
        codes[lo:lo + 65536] = np.argmax(local[lo:lo + 65536] @ book, axis=1)
    return codes


def decode_hemisphere(codes: np.ndarray, hemisphere: np.ndarray) -> np.ndarray:
    """(N,) uint8 codes + (N,) hemisphere indices -> (N, 3) float32 unit world directions."""
    codes = np.asarray(codes, np.uint8).reshape(-1)
    hemisphere = np.asarray(hemisphere, np.int64).reshape(-1)
    return np.einsum("ni,nij->nj", CODEBOOK[codes], HEMISPHERE_FRAMES[hemisphere]).astype(np.float32)


@wp.func
def hemisphere_decode(code: int, frame: wp.mat33) -> wp.vec3:
    """Warp twin of ``decode_hemisphere`` for one code; ``frame`` rows (t, b, delta).

    Decodes the 8-bit hemi-octahedral direction of an irradiance vector
    (usdbake's 8-bit replacement for the 24-bit direction of Pacanowski et al.
    2008, Sec. 3.3; the hemi-octahedral map of Cigolle et al. 2014, "A survey
    of efficient representations for independent unit vectors", JCGT 3(2)).
    Returns a unit world direction (dimensionless).
    """
    u = (float(code % 16) + 0.5) / 8.0 - 1.0
    v = (float(code // 16) + 0.5) / 8.0 - 1.0
    px = 0.5 * (u + v)
    py = 0.5 * (u - v)
    local = wp.normalize(wp.vec3(px, py, 1.0 - wp.abs(px) - wp.abs(py)))
    return wp.transpose(frame) * local
