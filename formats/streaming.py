"""Progressive streaming of a vertex grid: stratified coarse-to-fine order, 3D push-pull, stream files.

Pacanowski et al. 2008, "Efficient Streaming of 3D Scenes with Complex
Geometry and Complex Lighting", section 4.1: the server sends the eight
corners of the grid first, then constant-size bundles of vertices spread
over the whole grid; the client fills the vertices it has not received yet
with a 3D push-pull (which never modifies received data), smoothed after
each push step by a pyramidal filter.

**Order** (``progressive_order``). Vertex (i, j, k) of a grid of resolution
(nx, ny, nz) has index ``i + nx * (j + ny * k)`` (x fastest, as the
IrradianceVectorGrid arrays). Its *level* is the coarsest level of the
push-pull pyramid (below) it belongs to: level >= l means every coordinate
is a multiple of 2^l or sits on the grid's last plane of its axis. The order
is the levels from coarsest (the top, at most 2 x 2 x 2: the 8 corners the
paper sends first) to finest, so every prefix that ends at a level boundary
is exactly a pyramid level: the first ~eighth of the stream is the stride-2
sub-grid. Within a level, vertices are sorted by the bit-reversed Morton
code of ``(i, j, k) >> level``, a 3D van der Corput sequence: any run of a
level is spread over the whole grid instead of sweeping it slice by slice
(the paper draws random vertices per slice; this is the deterministic,
stratified equivalent).

**Push-pull** (``push_pull``), after Gortler et al. 1996 (the Lumigraph), in
3D on vertex-centred pyramids: coarse vertex ``J`` sits on fine vertex
``2J`` along each axis, and the last one on the axis's last fine vertex
(``n - 1``), so every level keeps the grid's faces (``pyramid_shapes``).

- *pull*: a coarse vertex copies its fine counterpart when that one is
  known, else takes the tent-weighted mean (weight 1 at its own position,
  1/2 at the fine neighbours that are not coarse vertices themselves) of its
  known fine neighbours; its weight is ``min(1, sum of the tent weights of
  known neighbours)``;
- *push*: going back down, a fine vertex of weight w becomes
  ``w * value + (1 - w) * up`` where ``up`` interpolates the coarse level
  linearly, axis by axis, by position; received vertices (w = 1) are never
  modified;
- *smoothing* (optional, the paper's pyramidal filter): after each push,
  vertices that were not fully known at that level are replaced by the
  [1, 2, 1] / 4 separable filter of the level (truncated and renormalized
  at the grid's faces).

Every filled value is a convex combination of received values, so it lies
within their range, and a constant field is reproduced exactly; a linear
field is reproduced exactly (without smoothing) when the received set is a
level-boundary prefix of the progressive order, because pull then copies
and push interpolates linearly.

**Stream file** (``encode_stream``/``decode_stream``), little-endian:

================ ========= =============================================
field            type      meaning
================ ========= =============================================
magic            8 bytes   ``b"USDBIVG2"``
vectors          uint32    vectors per vertex V (6)
resolution       3 int32   nx, ny, nz
grid_origin      3 float32 world position of vertex (0, 0, 0)
cell_size        3 float32 cell size along x, y, z
records          uint32    number of vertex records that follow
records          ...       ``records`` x (uint32 vertex index, V x 3 uint8
                           directions (8:8:8), V uint32 RGB9E5 colours),
                           in progressive order
================ ========= =============================================

A prefix of the file (any whole number of records) is a valid partial
stream; vertices inside geometry are not sent (the client fills them by
push-pull, as the baker did).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

STREAM_MAGIC = b"USDBIVG2"
HEADER = struct.Struct("<8sI3i3f3fI")
"""magic, vectors per vertex, resolution, grid origin, cell size, record count."""


# ---------------------------------------------------------------------------
# Order


def grid_coords(resolution) -> np.ndarray:
    """(V, 3) int64 (i, j, k) of every vertex, in storage order (x fastest)."""
    nx, ny, nz = (int(n) for n in resolution)
    k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    return np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1).astype(np.int64)


def _coarse_size(n: int) -> int:
    """Vertices along an axis of ``n`` one pyramid level up: the even indices and the last one."""
    return n // 2 + 1 if n > 1 else 1


def _centres(n: int) -> np.ndarray:
    """Fine index of each coarse vertex along an axis of size ``n``: 2J, the last clamped to n - 1."""
    return np.minimum(2 * np.arange(_coarse_size(n)), n - 1)


def pyramid_shapes(resolution) -> list[tuple[int, int, int]]:
    """(nx, ny, nz) of each pyramid level, finest first, until every axis has at most 2 vertices."""
    shapes = [tuple(int(n) for n in resolution)]
    while max(shapes[-1]) > 2:
        shapes.append(tuple(_coarse_size(n) for n in shapes[-1]))
    return shapes


def vertex_levels(resolution) -> np.ndarray:
    """(V,) int64 level of each vertex: the coarsest pyramid level it belongs to (0 = finest only).

    A vertex is on level l + 1 when it is a coarse vertex (even index, or the last index of
    its axis) at every step up to l; the top level (at most 2 x 2 x 2, the corners) has the
    largest level.
    """
    shapes = pyramid_shapes(resolution)
    coords = grid_coords(resolution)
    levels = np.zeros(len(coords), np.int64)
    current = coords.copy()
    alive = np.ones(len(coords), bool)
    for step, shape in enumerate(shapes[:-1]):
        coarse = np.empty_like(current)
        for axis in range(3):
            n = shape[axis]
            lookup = np.full(n, -1, np.int64)
            lookup[_centres(n)] = np.arange(_coarse_size(n))
            coarse[:, axis] = lookup[current[:, axis]]
        alive &= (coarse >= 0).all(axis=1)
        levels[alive] = step + 1
        current = np.where(alive[:, None], coarse, 0)
    return levels


def corner_mask(resolution) -> np.ndarray:
    """(V,) bool: the (up to) 8 corners of the grid."""
    coords = grid_coords(resolution)
    last = np.asarray(resolution, np.int64) - 1
    return ((coords == 0) | (coords == last)).all(axis=1)


def _reversed_morton(q: np.ndarray, bits: int) -> np.ndarray:
    """Bit-reversed Morton code of (N, 3) non-negative ints with ``bits`` bits per axis."""
    code = np.zeros(len(q), np.uint64)
    position = 0
    for b in range(bits):
        for axis in range(3):
            bit = ((q[:, axis] >> b) & 1).astype(np.uint64)
            # bit b of axis is Morton position 3b + axis; reversed, it goes to 3 bits - 1 - that.
            code |= bit << np.uint64(3 * bits - 1 - position)
            position += 1
    return code


def progressive_order(resolution) -> np.ndarray:
    """(V,) int64 permutation of the vertex indices: levels coarse to fine (module docstring)."""
    resolution = tuple(int(n) for n in resolution)
    if len(resolution) != 3 or min(resolution) < 1:
        raise ValueError(f"resolution must be 3 positive ints, got {resolution}")
    coords = grid_coords(resolution)
    levels = vertex_levels(resolution)
    bits = max(1, int(max(resolution)).bit_length())
    spread = _reversed_morton(coords >> levels[:, None], bits)
    order = np.lexsort((spread, -levels))  # last key first: level descending, then spread
    return order.astype(np.int64)


def level_prefix(resolution, level: int) -> int:
    """Length of the order's prefix holding every vertex of level >= ``level`` (the level's sub-grid)."""
    return int((vertex_levels(resolution) >= level).sum())


# ---------------------------------------------------------------------------
# Push-pull


def _tent_reduce(a: np.ndarray, axis: int) -> np.ndarray:
    """Along ``axis`` (size n): out[J] = a[P] + a[P - 1] / 2 + a[P + 1] / 2 with P = centre J; a
    neighbour counts only when it is in range and not a centre itself."""
    n = a.shape[axis]
    centres = _centres(n)
    out = np.take(a, centres, axis=axis)
    shape = [1] * a.ndim
    shape[axis] = len(centres)
    left = centres - 1
    left_ok = (left >= 0) & (left % 2 == 1)
    right = centres + 1
    right_ok = right <= n - 2
    out = out + 0.5 * np.take(a, np.clip(left, 0, n - 1), axis=axis) * left_ok.reshape(shape)
    out = out + 0.5 * np.take(a, np.clip(right, 0, n - 1), axis=axis) * right_ok.reshape(shape)
    return out


def _take_centres(a: np.ndarray) -> np.ndarray:
    """Fine values at the coarse vertices' positions (z, y, x leading axes)."""
    for axis in range(3):
        a = np.take(a, _centres(a.shape[axis]), axis=axis)
    return a


def _upsample(coarse: np.ndarray, shape, positions) -> np.ndarray:
    """Linear interpolation, axis by axis, of a coarse level onto the fine ``shape``: a fine vertex at
    a centre copies its coarse vertex, one between two centres interpolates them by position
    (``positions``: per array axis, the fine vertices' coordinates in finest-grid units; the
    clamped last vertices make the spacing uneven near the far faces)."""
    out = coarse
    for axis in range(3):
        n = shape[axis]
        idx = np.arange(n)
        lo = idx // 2
        hi = (idx + 1) // 2
        if n > 1 and n % 2 == 0:  # the last vertex is the clamped centre
            lo[-1] = hi[-1] = _coarse_size(n) - 1
        fine = positions[axis]
        centre = fine[_centres(n)]
        span = centre[hi] - centre[lo]
        t = np.where(span > 0, (fine - centre[lo]) / np.where(span > 0, span, 1.0), 0.0)
        view = [1] * out.ndim
        view[axis] = n
        t = t.reshape(view)
        out = (1.0 - t) * np.take(out, lo, axis=axis) + t * np.take(out, hi, axis=axis)
    return out


def _smooth(values: np.ndarray) -> np.ndarray:
    """Separable [1, 2, 1] / 4 filter, truncated and renormalized at the faces."""
    out = values
    for axis in range(3):
        if out.shape[axis] < 2:
            continue
        ones = np.ones(out.shape[axis])
        pad = [(0, 0)] * out.ndim
        pad[axis] = (1, 1)
        p = np.pad(out, pad)
        n = out.shape[axis]
        total = np.take(p, np.arange(n), axis=axis) + 2 * np.take(p, np.arange(n) + 1, axis=axis) \
            + np.take(p, np.arange(n) + 2, axis=axis)
        weight = 2 * ones
        weight[1:] += 1
        weight[:-1] += 1
        shape = [1] * out.ndim
        shape[axis] = n
        out = total / weight.reshape(shape)
    return out


def push_pull(values: np.ndarray, resolution, known: np.ndarray, *, smooth: bool = True) -> np.ndarray:
    """Fill the unknown vertices of a grid by 3D push-pull (module docstring).

    Parameters
    ----------
    values : (V, C) float, vertex-major in storage order (x fastest); unknown rows are ignored
    resolution : (nx, ny, nz)
    known : (V,) bool, the received vertices (their values are returned unchanged)
    smooth : apply the pyramidal [1, 2, 1] filter to filled vertices after each push

    Returns
    -------
    (V, C) float64; all zeros when nothing is known.
    """
    nx, ny, nz = (int(n) for n in resolution)
    values = np.asarray(values, np.float64)
    count = nx * ny * nz
    if values.ndim == 1:
        values = values[:, None]
    if values.shape[0] != count or np.asarray(known).shape != (count,):
        raise ValueError(f"push_pull: values {values.shape} / known {np.shape(known)} do not match {count} vertices")
    known = np.asarray(known, bool)
    channels = values.shape[1]
    if not known.any():
        return np.zeros((count, channels))
    grid = np.where(known[:, None], np.nan_to_num(values, nan=0.0, posinf=0.0, neginf=0.0), 0.0)
    grid = grid.reshape(nz, ny, nx, channels)
    weight = known.astype(np.float64).reshape(nz, ny, nx, 1)
    positions = tuple(np.arange(n, dtype=np.float64) for n in (nz, ny, nx))
    filled = _fill(grid, weight, smooth, positions)
    out = filled.reshape(count, channels)
    out[known] = values[known]  # bit-exact: received data is never modified
    return out


def _fill(values: np.ndarray, weight: np.ndarray, smooth: bool, positions) -> np.ndarray:
    """Recursive push-pull on (z, y, x, C) values with (z, y, x, 1) weights in [0, 1]; ``positions``:
    per axis, the vertices' coordinates in finest-grid units."""
    shape = values.shape[:3]
    if (weight >= 1.0).all():
        return values
    if max(shape) <= 2:
        total = weight.sum()
        mean = (values * weight).sum(axis=(0, 1, 2)) / total if total > 0 else np.zeros(values.shape[3])
        return weight * values + (1.0 - weight) * mean
    # pull
    wv = values * weight
    w = weight
    for axis in range(3):
        wv = _tent_reduce(wv, axis)
        w = _tent_reduce(w, axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        coarse = np.where(w > 0, wv / np.where(w > 0, w, 1.0), 0.0)
    coarse_weight = np.minimum(1.0, w)
    centre_known = _take_centres(weight) >= 1.0
    coarse = np.where(centre_known, _take_centres(values), coarse)
    coarse_weight = np.where(centre_known, 1.0, coarse_weight)
    coarse_positions = tuple(p[_centres(len(p))] for p in positions)
    coarse = _fill(coarse, coarse_weight, smooth, coarse_positions)
    # push
    up = _upsample(coarse, shape, positions)
    out = weight * values + (1.0 - weight) * up
    if smooth:
        out = np.where(weight >= 1.0, out, _smooth(out))
    return out


# ---------------------------------------------------------------------------
# Stream files


@dataclass(frozen=True)
class Stream:
    """A (possibly partial) decoded stream."""

    resolution: tuple[int, int, int]
    grid_origin: np.ndarray
    """(3,) float32 world position of vertex (0, 0, 0)."""
    cell_size: np.ndarray
    """(3,) float32."""
    vertex_index: np.ndarray
    """(R,) int64 received vertices, in stream order."""
    directions: np.ndarray
    """(R, V, 3) uint8 8:8:8 direction codes."""
    colors: np.ndarray
    """(R, V) uint32 RGB9E5."""
    total_records: int
    """Records the complete stream holds."""


def _record_dtype(vectors: int) -> np.dtype:
    return np.dtype([("index", "<u4"), ("directions", "u1", (vectors, 3)), ("colors", "<u4", (vectors,))])


def encode_stream(resolution, grid_origin, cell_size, order: np.ndarray, directions: np.ndarray,
                  colors: np.ndarray) -> bytes:
    """Bytes of a stream file holding the vertices ``order`` (in that order).

    directions : (N, V, 3) uint8 and colors : (N, V) uint32 for every vertex of the grid (storage order).
    """
    directions = np.asarray(directions, np.uint8).reshape(len(colors), -1, 3)
    colors = np.asarray(colors, np.uint32)
    order = np.asarray(order, np.int64)
    vectors = directions.shape[1]
    records = np.zeros(len(order), _record_dtype(vectors))
    records["index"] = order
    records["directions"] = directions[order]
    records["colors"] = colors[order]
    header = HEADER.pack(STREAM_MAGIC, vectors, *(int(n) for n in resolution),
                         *(float(x) for x in grid_origin), *(float(x) for x in cell_size), len(order))
    return header + records.tobytes()


def decode_stream(data: bytes, *, records: int | None = None) -> Stream:
    """Decode a stream file or a prefix of one (whole records; a trailing partial record is dropped).

    records : read at most this many records (the first ones), as a client that received them.
    """
    if len(data) < HEADER.size:
        raise ValueError(f"stream: {len(data)} bytes is shorter than the {HEADER.size}-byte header")
    magic, vectors, nx, ny, nz, ox, oy, oz, cx, cy, cz, total = HEADER.unpack_from(data, 0)
    if magic != STREAM_MAGIC:
        raise ValueError(f"stream: bad magic {magic!r} (expected {STREAM_MAGIC!r})")
    dtype = _record_dtype(vectors)
    available = min(total, (len(data) - HEADER.size) // dtype.itemsize)
    if records is not None:
        available = min(available, max(0, int(records)))
    body = np.frombuffer(data, dtype, count=available, offset=HEADER.size)
    return Stream((nx, ny, nz), np.array([ox, oy, oz], np.float32), np.array([cx, cy, cz], np.float32),
                  body["index"].astype(np.int64), body["directions"].copy(), body["colors"].copy(), int(total))
