"""Compression of the multi-bounce radiosity operator: exact top entries + log-quantized BC1 codes.

Shcherbakov (MSU 2017), section 4.2 ("DXT compression of the form-factor
matrix"), for a (3, n, n) operator of dimensionless transfer factors (the
multi-bounce sum of section 4.1, eq. 7):

1. the largest ``exact_fraction`` of the entries (the thesis' 4 %, by their
   largest channel) are kept exact in a sparse CSR part and zeroed in the rest;
2. the rest is divided by its largest value, so it lies in [0, 1], and its
   logarithm is mapped to byte codes 0..255 (the thesis adds the constant 25
   to ln v and scales to 0..255; here an explicit floor takes the place of
   that constant: code 0 = below the floor = zero, codes 1..255 uniform in
   ln v from the floor to the maximum; ``quantization="linear"`` codes v/vmax);
3. rows and columns are reordered by the thesis' greedy nearest-neighbour
   passes (L1 distance, "the sum of distances between the vectors'
   coordinates"; first rows, then columns; the same permutation on both so
   the matrix still maps patch light to patch light);
4. the RGB codes are BC1 (DXT1) encoded in 4x4 blocks (processors/radiosity/bc1.py),
   texel (x=j, y=i) = stored entry (i, j).

Beyond the thesis: the exact entries are free texels of the BC1 fit (weight 0)
and the exact part stores what their texels miss, so a block is not bent
around the holes the top entries leave; every coded entry that still decodes
further than MAX_ERROR of the largest coded value from its value joins the
exact part the same way (a 4-colour line in RGB cannot reach a texel of
another hue: such texels missed by 0.8 of the largest value, whatever the
ordering); each decoded row is rescaled per channel so its coded entries sum as
the true ones do (``row_scale``, (n, 3) float32), which removes the bias of the
quantization for smooth light; and the reordering compares rows by at most
SIGNATURE_DIMS column-group sums. The errors reported
(``compression_errors``) are the thesis' table in 4.2: mean, maximum and
summed absolute error of the coded entries, relative to the largest one.

Numpy, and one Warp kernel for the greedy ordering's distances: ``processors.radiosity.operator_relight`` decodes the blocks' palettes at load
and the texel codes in its kernel; ``decompress_operator`` is the reference
decoder for tests and benchmarks.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .products import CompressedOperator
from .bc1 import blocks_to_image, decode_bc1_texels, encode_bc1

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

AUTO_FLOOR_MASS = 1e-3
"""Automatic log floor: the residual entries coded as zero sum to at most this share of the residual."""
MAX_ERROR = 0.2
"""A coded entry decoding further than this from its value (relative to the largest coded value) joins
the exact part (measured: 0.6 % of cornell_box's entries at 2k patches; 0.8 of the largest value missed
before, by texels of another hue than their block's colour line)."""
ROW_SCALE_LIMIT = 4.0
"""Bound on the row-sum correction factor (a row whose decoded sum is off by more is left clipped)."""
DECODE_ROWS = 256
"""Rows ``stored_operator`` decodes at a time (bounds its temporaries to ~12 * 256 * n bytes)."""
SIGNATURE_DIMS = 256
"""Reordering compares rows by L1 distance over at most this many column-group sums, keeping the
greedy pass O(n^2 * 256) instead of O(n^3)."""



def log_codes(values: np.ndarray, floor: float, vmax: float) -> tuple[np.ndarray, float, float]:
    """Float codes in {0} U [1, 255]: 0 below ``floor``, else 1 + 254 ln(v/floor) / ln(vmax/floor).

    The logarithmic quantization of Shcherbakov (MSU 2017), section 4.2 (values
    over the largest one, logarithm, shifted and scaled to 0..255), with the
    explicit ``floor`` in place of the thesis' constant shift of 25. ``values``
    are dimensionless operator entries; returns the codes (same shape, float32,
    BC1 rounds them) and (scale, offset) with ln v = code * scale + offset.
    """
    span = max(math.log(vmax / floor), 1e-6)
    scale = span / 254.0
    offset = math.log(floor) - scale
    with np.errstate(divide="ignore", invalid="ignore"):
        codes = np.where(values >= floor, 1.0 + 254.0 * np.log(np.maximum(values, floor) / floor) / span, 0.0)
    return np.clip(codes, 0.0, 255.0).astype(np.float32), scale, offset


def linear_codes(values: np.ndarray, vmax: float) -> tuple[np.ndarray, float, float]:
    """Float codes in [0, 255] = 255 v / vmax; value = code * scale + offset (offset 0).

    usdbake's linear alternative to the log codes of Shcherbakov (MSU 2017), section 4.2.
    """
    return np.clip(values * (255.0 / vmax), 0.0, 255.0).astype(np.float32), vmax / 255.0, 0.0


def code_lut(scale: float, offset: float, quantization: str = "log") -> np.ndarray:
    """(256,) float32 byte code -> value (code 0 is exactly 0 in both schemes).

    Inverts ``log_codes`` (v = exp(code * scale + offset)) or ``linear_codes``
    (v = code * scale + offset); the relight kernel reads this table.
    """
    codes = np.arange(256, dtype=np.float64)
    lut = np.exp(offset + scale * codes) if quantization == "log" else offset + scale * codes
    lut[0] = 0.0
    return lut.astype(np.float32)


def auto_floor(residual_max: np.ndarray, vmax: float, mass: float = AUTO_FLOOR_MASS) -> float:
    """Largest floor such that entries below it sum to at most ``mass`` of the residual (sampled).

    usdbake's choice of the log floor (the thesis, section 4.2, uses a fixed
    shift of 25 in ln v instead). ``residual_max`` : (n, n) float32 largest
    channel of each coded entry.
    """
    flat = residual_max[residual_max > 0].astype(np.float64)
    if len(flat) == 0:
        return vmax * 1e-6
    if len(flat) > 4_000_000:
        flat = np.random.default_rng(0).choice(flat, 4_000_000, replace=False)
    flat.sort()
    cum = np.cumsum(flat)
    k = int(np.searchsorted(cum, mass * cum[-1], side="right"))
    floor = flat[min(k, len(flat) - 1)]
    return float(min(max(floor, vmax * 1e-12), vmax * 0.5))


SIGNATURE_WIDTH = wp.constant(SIGNATURE_DIMS)


@wp.kernel
def l1_distances_kernel(signatures: wp.array(dtype=wp.uint16), candidates: wp.array(dtype=wp.int32),
                        current: int, distance: wp.array(dtype=wp.int32)):
    """distance[i] = sum_c |S[candidates[i], c] - S[current, c]|: the L1 distance between two rows' integer
    signatures (SIGNATURE_WIDTH each, row-major; a constant width lets the compiler vectorize the loop),
    exact in any summation order."""
    i = wp.tid()
    row = candidates[i] * SIGNATURE_WIDTH
    base = current * SIGNATURE_WIDTH
    total = int(0)
    for c in range(SIGNATURE_WIDTH):
        total += wp.abs(int(signatures[row + c]) - int(signatures[base + c]))
    distance[i] = total


def greedy_order(signatures: np.ndarray) -> np.ndarray:
    """The thesis' greedy pass: starting at item 0, repeatedly append the nearest (L1) remaining item, the
    lowest index among equally near ones.

    Shcherbakov (MSU 2017), section 4.2: the ordering is a travelling-salesman
    problem over rows with the L1 distance; the greedy heuristic puts after each
    row the closest one not yet placed. ``signatures`` : (n, d) integers in
    [0, 65535]; returns the (n,) int64 order. Each step's distances are one Warp
    launch over the remaining rows (``l1_distances_kernel``: 16-bit signatures,
    ~30x numpy's temporaries-bound step), and the remaining rows stay compact
    (the last moves into the chosen one's place), so a pass is n^2 d / 2 byte
    reads: ~5 s at 16k rows x 256 where numpy took ~54 s. Integer distances make
    the order independent of summation order.
    """
    n = len(signatures)
    order = np.empty(n, np.int64)
    if n == 0:
        return order
    values = np.asarray(signatures).reshape(n, -1)
    if values.size and (values.min() < 0 or values.max() > np.iinfo(np.uint16).max):
        raise ValueError(f"signatures in [{values.min()}, {values.max()}]: expected integers in [0, 65535]")
    if values.shape[1] > SIGNATURE_DIMS:
        raise ValueError(f"signatures of {values.shape[1]} values: at most {SIGNATURE_DIMS}")
    padded = np.zeros((n, SIGNATURE_DIMS), np.uint16)  # zero columns add nothing to a distance
    padded[:, :values.shape[1]] = values
    sig = wp.array(padded.ravel(), dtype=wp.uint16, device="cpu")
    remaining = wp.array(np.arange(n, dtype=np.int32), dtype=wp.int32, device="cpu")
    distance = wp.empty(n, dtype=wp.int32, device="cpu")
    left, dist = remaining.numpy(), distance.numpy()  # views of the Warp arrays: no copies per step
    current, chosen, count = 0, 0, n  # item 0 first, in slot 0
    for step in range(n):
        order[step] = current
        left[chosen] = left[count - 1]
        count -= 1
        if count == 0:
            break
        wp.launch(l1_distances_kernel, dim=count, inputs=[sig, remaining, current, distance], device="cpu")
        d = dist[:count]
        ties = np.flatnonzero(d == d.min())
        chosen = int(ties[np.argmin(left[ties])]) if len(ties) > 1 else int(ties[0])
        current = int(left[chosen])
    return order


def _signatures(code_sums: np.ndarray) -> np.ndarray:
    """Rows of an (n, n) integer code matrix reduced to at most SIGNATURE_DIMS column-group sums (uint16: at
    most 765 x 64 for MAX_PATCHES; larger sums are divided down to fit)."""
    n = code_sums.shape[1]
    groups = min(n, SIGNATURE_DIMS)
    edges = np.linspace(0, n, groups + 1).astype(np.int64)
    sums = np.add.reduceat(code_sums, edges[:-1], axis=1, dtype=np.int64)
    limit = np.iinfo(np.uint16).max
    if sums.size and sums.max() > limit:
        sums //= -(-int(sums.max()) // limit)
    return sums.astype(np.uint16)


def reorder(code_sums: np.ndarray, passes: int) -> np.ndarray:
    """(n,) permutation from ``passes`` greedy passes: rows first, then columns (same order for both).

    Shcherbakov (MSU 2017), section 4.2 (fig. 6): two passes, the first on rows,
    the second on columns; swapping rows i and j also swaps columns i and j so
    the matrix still maps patch light to patch light. ``code_sums`` : (n, n)
    integer codes summed over the RGB channels.
    """
    n = len(code_sums)
    perm = np.arange(n)
    for p in range(passes):
        current = code_sums[np.ix_(perm, perm)]
        sig = _signatures(current if p % 2 == 0 else np.ascontiguousarray(current.T))
        perm = perm[greedy_order(sig)]
    return perm


def compress_operator(operator: np.ndarray, *, exact_fraction: float = 0.04, log_floor: float = 0.0,
                      reorder_passes: int = 2, row_correction: bool = True,
                      quantization: str = "log", max_error: float = MAX_ERROR) -> CompressedOperator:
    """Compress a (3, n, n) float32 operator: exact top entries + BC1 log codes.

    Shcherbakov (MSU 2017), section 4.2 (steps 1-4 of the module docstring);
    the operator is the dimensionless multi-bounce matrix of section 4.1, eq. 7.
    Beyond the thesis, the exact entries are free texels of the BC1 fit (weight 0:
    the sparse part stores the exact value minus what their texel decodes to, so
    the sum is exact), and every coded entry whose decoded value misses by more
    than ``max_error`` of the largest coded value joins the exact part the same
    way (the few texels a 4-colour line cannot reach). ``stats`` holds the
    thesis' errors over the coded entries (``compression_errors``) before and,
    with ``row_correction``, after the row-sum rescaling, the entries promoted,
    and the memory ratio against dense float32 RGB (12 n^2 bytes).
    """
    _, n, _ = operator.shape
    magnitude = operator.max(axis=0)
    keep = int(round(exact_fraction * n * n))
    exact = np.zeros((n, n), bool)
    if keep > 0:
        flat = magnitude.ravel()
        top = np.argpartition(flat, -keep)[-keep:]
        top = top[flat[top] > 0]
        exact.ravel()[top] = True
    residual = np.where(exact[None], 0.0, operator).astype(np.float32)
    residual_max = residual.max(axis=0)
    vmax = float(residual_max.max()) if n else 0.0
    if vmax <= 0:
        vmax = 1.0
    if quantization == "log":
        floor = log_floor * vmax if log_floor > 0 else auto_floor(residual_max, vmax)
        codes, scale, offset = log_codes(np.moveaxis(residual, 0, -1), floor, vmax)  # (n, n, 3)
    elif quantization == "linear":
        floor = 0.0
        codes, scale, offset = linear_codes(np.moveaxis(residual, 0, -1), vmax)
    else:
        raise ValueError(f"quantization={quantization!r} is not 'log' or 'linear'")
    perm = reorder(codes.sum(axis=2, dtype=np.int32), reorder_passes) if reorder_passes > 0 else np.arange(n)
    n4 = (n + 3) // 4 * 4
    image = np.zeros((n4, n4, 3), np.float32)
    image[:n, :n] = codes[np.ix_(perm, perm)]
    exact_p = exact[np.ix_(perm, perm)]
    weights = np.zeros((n4, n4), np.float32)  # padding and exact entries are free texels
    weights[:n, :n] = ~exact_p
    lut = code_lut(scale, offset, quantization)
    compressed = CompressedOperator(
        size=n, blocks=encode_bc1(image, weights), permutation=perm.astype(np.int32),
        sparse_indptr=np.zeros(n + 1, np.int32), sparse_indices=np.zeros(0, np.int32),
        sparse_values=np.zeros((0, 3), np.float32), lut=lut, log_scale=scale, log_offset=offset,
        quantization=quantization, row_scale=np.ones((n, 3), np.float32))
    residual_stored = residual[:, perm][:, :, perm]
    raw = stored_operator(compressed)  # (3, n, n) the BC1 part in stored order (no sparse part yet, scale 1)
    coded = ~exact_p
    for _ in range(2):  # promote by the error after the row correction the remaining entries get
        row_scale = _row_scale(raw, residual_stored, coded) if row_correction else compressed.row_scale
        decoded = raw * np.moveaxis(row_scale, -1, 0)[:, :, None]
        coded &= ~(np.abs(decoded - residual_stored).max(axis=0) > max_error * vmax)
    if row_correction:
        row_scale = _row_scale(raw, residual_stored, coded)
        object.__setattr__(compressed, "row_scale", row_scale)
        decoded = raw * np.moveaxis(row_scale, -1, 0)[:, :, None]
        # The last scale moved some entries past the bound: they too go exact (the scale stays: their
        # rows' sums move by what the bound allows at most).
        coded &= ~(np.abs(decoded - residual_stored).max(axis=0) > max_error * vmax)
    promoted = coded != ~exact_p
    exact_p = ~coded
    stats = compression_errors(raw, residual_stored, vmax, coded)
    if row_correction:
        stats.update({f"corrected_{k}": v for k, v in compression_errors(decoded, residual_stored, vmax, coded).items()})
    # The exact part holds what the texels of its entries miss: decoded + sparse = operator there.
    rows, cols = np.nonzero(exact_p)
    truth = np.moveaxis(operator, 0, -1)[perm[rows], perm[cols]].astype(np.float64)
    values = (truth - np.moveaxis(decoded, 0, -1)[rows, cols]).astype(np.float32)
    indptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    object.__setattr__(compressed, "sparse_indptr", indptr.astype(np.int32))
    object.__setattr__(compressed, "sparse_indices", cols.astype(np.int32))
    object.__setattr__(compressed, "sparse_values", values)
    stats.update({"floor": floor, "residual_max": vmax, "exact_entries": int(len(rows)),
                  "promoted_entries": int(promoted.sum()), "dense_bytes": int(12 * n * n),
                  "compressed_bytes": compressed.nbytes, "memory_ratio": compressed.nbytes / max(12 * n * n, 1)})
    object.__setattr__(compressed, "stats", stats)
    return compressed


def _row_scale(decoded: np.ndarray, residual_stored: np.ndarray, coded: np.ndarray) -> np.ndarray:
    """(n, 3) float32 factors making each decoded row's coded entries sum as the true ones do: removes the
    bias of quantization (codes rounded to 0, exp of noisy log codes) for smooth inputs."""
    decoded_sum = np.where(coded[None], decoded, 0.0).sum(axis=2, dtype=np.float64)  # (3, n)
    true_sum = np.where(coded[None], residual_stored, 0.0).sum(axis=2, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(decoded_sum > 0, true_sum / decoded_sum, 1.0)
    return np.clip(ratio, 1.0 / ROW_SCALE_LIMIT, ROW_SCALE_LIMIT).T.astype(np.float32).copy()


def compression_errors(decoded: np.ndarray, residual_stored: np.ndarray, vmax: float, coded: np.ndarray) -> dict:
    """Thesis-style errors of the BC1 part over its coded entries, normalized by the largest residual value.

    The mean, maximum and summed absolute errors of the table in Shcherbakov
    (MSU 2017), section 4.2 (dimensionless). ``decoded`` and ``residual_stored``:
    (3, n, n) float32 in stored order; ``coded`` (n, n) bool: the entries the
    BC1 part carries (the exact part carries the others whole).
    """
    err = (np.abs(decoded - residual_stored) / vmax)[:, coded]
    return {"error_mean": float(err.mean()) if err.size else 0.0, "error_max": float(err.max()) if err.size else 0.0,
            "error_sum": float(err.sum(dtype=np.float64))}


def stored_operator(compressed: CompressedOperator) -> np.ndarray:
    """(3, n, n) float32 operator in stored order (the BC1 part with its row correction, plus the exact
    sparse part), decoded DECODE_ROWS rows at a time so the temporaries stay small."""
    n, n4 = compressed.size, compressed.padded
    blocks = np.ascontiguousarray(compressed.blocks, np.uint8).reshape(n4 // 4, n4 // 4, 8)
    out = np.empty((3, n, n), np.float32)
    for lo in range(0, n, DECODE_ROWS):  # DECODE_ROWS is a multiple of 4: a strip is whole block rows
        hi = min(n, lo + DECODE_ROWS)
        strip = blocks[lo // 4:(hi + 3) // 4]
        codes = blocks_to_image(decode_bc1_texels(strip.reshape(-1, 8)), 4 * len(strip), n4)[:hi - lo, :n]
        values = compressed.lut[codes] * compressed.row_scale[lo:hi, None, :]
        out[:, lo:hi] = np.moveaxis(values, -1, 0)
    rows = np.repeat(np.arange(n), np.diff(compressed.sparse_indptr))
    out[:, rows, compressed.sparse_indices] += compressed.sparse_values.T
    return out


def decompress_operator(compressed: CompressedOperator) -> np.ndarray:
    """(3, n, n) float32 operator in patch order, decoded (``stored_operator`` permuted back)."""
    stored = stored_operator(compressed)
    out = np.empty_like(stored)
    perm = compressed.permutation
    out[:, perm[:, None], perm[None, :]] = stored
    return out
