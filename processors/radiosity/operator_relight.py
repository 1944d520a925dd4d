"""Relight by matrix-vector products with the multi-bounce operator, in the fastest form that fits.

Shcherbakov (MSU 2017), section 3.5 steps 2-4 with the operator of section 4.1:
indirect irradiance E_ind = M E0 with M = sum_h (F^C)^h the k-bounce operator
that ``form_factors`` compressed (section 4.2: top values exact in a sparse
part, the rest as log-quantized codes in BC1 blocks, rows and columns
reordered). The compressed operator is the stored and transferred form (the
.dds and the sparse .npz); an ``OperatorRelighter`` decodes it once, at load, into one
of two run-time forms:

- ``dense``: the float32 operator (12 n^2 bytes) multiplied by BLAS (numpy),
  when it fits the memory budget on a CPU; the fastest product there is.
- ``compressed``: each BC1 block's endpoints decoded once into its palette of
  byte codes (4 per channel, the same bytes as ``processors.radiosity.bc1.bc1_palette``), so a
  block is 16 bytes (2-bit texel codes + 12 palette codes, 1 byte an entry
  against the dense 12) and the kernel does no integer arithmetic beyond
  shifts and masks: 12 table lookups per block, then per texel three indexed
  loads and three multiply-adds. It never forms the float matrix and needs no
  scratch beyond x and y. Used when the dense form does not fit, and on CUDA.

Both work in the stored (permuted) order and give the same values to float
rounding (the sum order differs).
"""

from __future__ import annotations

import os

import numpy as np
import warp as wp

from .bc1 import bc1_palette_np
from .operator_codec import stored_operator
from ...kernels.tracer import launch_chunked

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

DENSE, COMPRESSED = "dense", "compressed"
CUDA_LANES = 32
"""Work items per block row on CUDA (one warp): a block row is too little work for a GPU thread, and
one item per row leaves most of the GPU idle below ~10^5 patches."""
BUDGET_FRACTION = 0.25
"""Default memory budget of the run-time operator: this share of the machine's physical memory (not
of the memory free now, which changes from run to run: the two forms differ in float rounding, and a
bake should not depend on what else the machine was doing)."""


@wp.struct
class CompressedRows:
    """The compressed operator on the device, in stored (permuted) order."""

    blocks: wp.array2d(dtype=wp.uint32)
    """(B, 4) per BC1 block: its 16 two-bit texel codes (texel k in bits 2k..2k+1), then per channel its
    4 palette byte codes (entry p in bits 8p..8p+7); block rows of ``blocks_per_row``."""
    blocks_per_row: int
    lut: wp.array(dtype=float)
    """(256,) code -> operator value (section 4.2: v = exp(code * scale + offset), 0 for code 0)."""
    row_scale: wp.array(dtype=wp.vec3)
    """(n,) per-row factor on the decoded BC1 part (row-sum correction)."""
    indptr: wp.array(dtype=int)
    indices: wp.array(dtype=int)
    values: wp.array(dtype=wp.vec3)
    """The exact top values (CSR): the part of the operator kept out of the BC1 texture."""
    size: int


@wp.struct
class BlockPalette:
    """The 4 operator values a block's 2-bit codes choose from, one vec4 per channel (entry p of ``red``
    is palette colour p's red value), so a texel's value is three indexed loads, not selects."""

    red: wp.vec4
    green: wp.vec4
    blue: wp.vec4


@wp.func
def channel_values(lut: wp.array(dtype=float), codes: int) -> wp.vec4:
    """The 4 byte codes packed in ``codes`` (entry p in bits 8p..8p+7) through the code table (section
    4.2: v = exp(code * scale + offset))."""
    return wp.vec4(lut[codes & 255], lut[(codes >> 8) & 255], lut[(codes >> 16) & 255], lut[(codes >> 24) & 255])


@wp.func
def block_row_product(bits: int, palette: BlockPalette, x0: wp.vec3, x1: wp.vec3, x2: wp.vec3,
                      x3: wp.vec3) -> wp.vec3:
    """Sum over the 4 texels of one block row (8 bits of codes, texel c in bits 2c..2c+1) of
    palette[code] * x_c per channel."""
    c0 = bits & 3
    c1 = (bits >> 2) & 3
    c2 = (bits >> 4) & 3
    c3 = (bits >> 6) & 3
    r = palette.red
    g = palette.green
    b = palette.blue
    return wp.vec3(r[c0] * x0[0] + r[c1] * x1[0] + r[c2] * x2[0] + r[c3] * x3[0],
                   g[c0] * x0[1] + g[c1] * x1[1] + g[c2] * x2[1] + g[c3] * x3[1],
                   b[c0] * x0[2] + b[c1] * x1[2] + b[c2] * x2[2] + b[c3] * x3[2])


@wp.struct
class BlockRowSums:
    """Partial sums of the 4 stored rows of one block row."""

    y0: wp.vec3
    y1: wp.vec3
    y2: wp.vec3
    y3: wp.vec3


@wp.func
def add_block(op: CompressedRows, k: int, bx: int, x: wp.array(dtype=wp.vec3), sums: BlockRowSums) -> BlockRowSums:
    """``sums`` plus block ``k`` (block column ``bx``) times x: its palette's 12 byte codes through the code
    table, then each of the 16 texels adds palette[code] * x_j; the float matrix is never formed."""
    palette = BlockPalette()
    palette.red = channel_values(op.lut, int(op.blocks[k, 1]))
    palette.green = channel_values(op.lut, int(op.blocks[k, 2]))
    palette.blue = channel_values(op.lut, int(op.blocks[k, 3]))
    bits = int(op.blocks[k, 0])
    j = 4 * bx
    x0 = x[j]
    x1 = x[j + 1]
    x2 = x[j + 2]
    x3 = x[j + 3]
    out = BlockRowSums()
    out.y0 = sums.y0 + block_row_product(bits & 255, palette, x0, x1, x2, x3)
    out.y1 = sums.y1 + block_row_product((bits >> 8) & 255, palette, x0, x1, x2, x3)
    out.y2 = sums.y2 + block_row_product((bits >> 16) & 255, palette, x0, x1, x2, x3)
    out.y3 = sums.y3 + block_row_product((bits >> 24) & 255, palette, x0, x1, x2, x3)
    return out


@wp.func
def zero_sums() -> BlockRowSums:
    sums = BlockRowSums()
    sums.y0 = wp.vec3(0.0, 0.0, 0.0)
    sums.y1 = wp.vec3(0.0, 0.0, 0.0)
    sums.y2 = wp.vec3(0.0, 0.0, 0.0)
    sums.y3 = wp.vec3(0.0, 0.0, 0.0)
    return sums


@wp.func
def row_total(op: CompressedRows, row: int, sums: BlockRowSums, r: int, exact: bool,
              x: wp.array(dtype=wp.vec3)) -> wp.vec3:
    """Row ``row`` (the block row's r-th) of the product: the decoded BC1 part times the row-sum
    correction, plus, with ``exact``, the exact sparse part (section 4.2: the top values are kept exact,
    the rest log-quantized in BC1 blocks)."""
    acc = wp.where(r >= 2, wp.where(r == 3, sums.y3, sums.y2), wp.where(r == 1, sums.y1, sums.y0))
    acc = wp.cw_mul(acc, op.row_scale[row])
    if exact:
        for e in range(op.indptr[row], op.indptr[row + 1]):
            acc += wp.cw_mul(op.values[e], x[op.indices[e]])
    return acc


@wp.kernel
def relight_blocks_kernel(start: int, op: CompressedRows, x: wp.array(dtype=wp.vec3), y: wp.array(dtype=wp.vec3)):
    """y = M x for the 4 stored rows of block row ``start + tid`` (stored order, x padded to 4): one
    work item a block row, summed in a fixed order (the CPU form: as many items as threads suffice)."""
    br = start + wp.tid()
    sums = zero_sums()
    base = br * op.blocks_per_row
    for bx in range(op.blocks_per_row):
        sums = add_block(op, base + bx, bx, x, sums)
    for r in range(4):
        row = 4 * br + r
        if row < op.size:
            y[row] = row_total(op, row, sums, r, True, x)


@wp.kernel
def relight_lanes_kernel(start: int, op: CompressedRows, lanes: int, x: wp.array(dtype=wp.vec3),
                         y: wp.array(dtype=wp.vec3)):
    """y += M x with ``lanes`` work items per block row (the GPU form; y zeroed before): item (br, lane)
    sums the block columns lane, lane + lanes, ..., so neighbouring items read neighbouring 16-byte blocks
    (coalesced), and adds its 4 partial rows atomically; lane 0 adds the exact sparse part."""
    item = start + wp.tid()
    br = item // lanes
    lane = item % lanes
    sums = zero_sums()
    base = br * op.blocks_per_row
    for bx in range(lane, op.blocks_per_row, lanes):
        sums = add_block(op, base + bx, bx, x, sums)
    for r in range(4):
        row = 4 * br + r
        if row < op.size:
            wp.atomic_add(y, row, row_total(op, row, sums, r, lane == 0, x))


def palette_blocks(blocks: np.ndarray) -> np.ndarray:
    """(B, 8) uint8 BC1 blocks -> (B, 4) uint32 run-time blocks: texel codes, then the red, green and blue
    palette byte codes (``bc1_palette_np``: Microsoft, "Block Compression (Direct3D 10)", BC1, rounded
    as OpenImageIO does), 4 to a word."""
    words = np.ascontiguousarray(blocks, np.uint8).reshape(-1, 8).view(np.uint32).reshape(-1, 2)
    palette = bc1_palette_np((words[:, 0] & 0xFFFF).astype(np.uint16), (words[:, 0] >> 16).astype(np.uint16))
    out = np.empty((len(words), 4), np.uint32)
    out[:, 0] = words[:, 1]
    for channel in range(3):
        codes = palette[:, :, channel].astype(np.uint32)
        out[:, 1 + channel] = codes[:, 0] | (codes[:, 1] << 8) | (codes[:, 2] << 16) | (codes[:, 3] << 24)
    return out


def physical_memory() -> int:
    """Bytes of physical memory (Linux/macOS sysconf); 0 where it cannot be read."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 0


def dense_nbytes(size: int) -> int:
    """Bytes of the dense float32 RGB operator of ``size`` patches."""
    return 12 * size * size


def relight_form(size: int, device, memory_budget: int | None = None) -> str:
    """DENSE when the float32 operator fits ``memory_budget`` bytes (default: BUDGET_FRACTION of the
    physical memory) on a CPU, else COMPRESSED (always on CUDA: the in-kernel decode)."""
    if wp.get_device(device).is_cuda:
        return COMPRESSED
    budget = int(BUDGET_FRACTION * physical_memory()) if memory_budget is None else int(memory_budget)
    return DENSE if dense_nbytes(size) <= budget else COMPRESSED


def launch_rows(kernel, dim: int, inputs: list, device, threads: int) -> None:
    """Launch a row kernel split across threads: rows are few but heavy, so any chunk is worth a thread."""
    launch_chunked(kernel, dim, inputs, device=device, threads=threads, min_chunk=1)


class OperatorRelighter:
    """The operator decoded once into its run-time form (``form``: DENSE or COMPRESSED, see the module
    docstring; ``relight_form`` picks by the memory budget); ``apply(E0)`` -> indirect irradiance."""

    def __init__(self, compressed, *, device="cpu", threads: int = 1, memory_budget: int | None = None,
                 form: str | None = None, lanes: int | None = None):
        self.size = compressed.size
        self.padded = compressed.padded
        self.device = wp.get_device(device)
        self.threads = threads
        self.permutation = np.asarray(compressed.permutation, np.int64)
        self.form = form or relight_form(self.size, self.device, memory_budget)
        if self.form not in (DENSE, COMPRESSED):
            raise ValueError(f"form={self.form!r}: expected {DENSE!r} or {COMPRESSED!r}")
        if self.form == DENSE and self.device.is_cuda:
            raise ValueError("the dense relight runs on the CPU (numpy BLAS); use form='compressed' on CUDA")
        if self.form == DENSE:
            self.matrix = stored_operator(compressed)
            self.x = np.zeros((3, self.size, 1), np.float32)  # channel-major: one batched BLAS call
            return
        self.lanes = (CUDA_LANES if self.device.is_cuda else 0) if lanes is None else int(lanes)
        """Work items per block row: 0 = relight_blocks_kernel (CPU), else relight_lanes_kernel (CUDA)."""
        self.op = CompressedRows()
        self.op.blocks = wp.array(palette_blocks(compressed.blocks), dtype=wp.uint32, device=self.device)
        self.op.blocks_per_row = self.padded // 4
        self.op.lut = wp.array(compressed.lut, dtype=float, device=self.device)
        self.op.row_scale = wp.array(compressed.row_scale, dtype=wp.vec3, device=self.device)
        self.op.indptr = wp.array(compressed.sparse_indptr, dtype=int, device=self.device)
        self.op.indices = wp.array(compressed.sparse_indices, dtype=int, device=self.device)
        self.op.values = wp.array(compressed.sparse_values.reshape(-1, 3), dtype=wp.vec3, device=self.device)
        self.op.size = self.size
        self.x = wp.zeros(self.padded, dtype=wp.vec3, device=self.device)
        self.y = wp.zeros(self.padded, dtype=wp.vec3, device=self.device)

    @property
    def nbytes(self) -> int:
        """Memory the run-time form holds: operator, sparse part, tables and the x and y buffers."""
        if self.form == DENSE:
            return int(self.matrix.nbytes + self.x.nbytes + self.permutation.nbytes)
        arrays = (self.op.blocks, self.op.lut, self.op.row_scale, self.op.indptr, self.op.indices, self.op.values,
                  self.x, self.y)
        return int(sum(a.capacity for a in arrays) + self.permutation.nbytes)

    def apply_stored(self):
        """y = M x in stored order on the buffers of the run-time form; what the relight timing measures."""
        if self.form == DENSE:
            return np.matmul(self.matrix, self.x)[:, :, 0].T
        if self.lanes > 0:
            self.y.zero_()
            launch_rows(relight_lanes_kernel, self.padded // 4 * self.lanes, [self.op, self.lanes, self.x, self.y],
                        self.device, self.threads)
        else:
            launch_rows(relight_blocks_kernel, self.padded // 4, [self.op, self.x, self.y], self.device, self.threads)
        return None

    def apply(self, irradiance: np.ndarray) -> np.ndarray:
        """(n, 3) direct irradiance per patch (patch order) -> (n, 3) indirect irradiance."""
        stored = np.asarray(irradiance, np.float32)[self.permutation]
        out = np.empty((self.size, 3), np.float32)
        if self.form == DENSE:
            self.x[:, :, 0] = stored.T
            out[self.permutation] = self.apply_stored()
            return out
        x = np.zeros((self.padded, 3), np.float32)
        x[:self.size] = stored
        self.x.assign(x)
        self.apply_stored()
        out[self.permutation] = self.y.numpy()[:self.size]
        return out


def relight_indirect(compressed, irradiance: np.ndarray, *, device="cpu", threads: int = 1,
            memory_budget: int | None = None) -> np.ndarray:
    """Indirect irradiance (n, 3) = M E0 with the operator in its fastest run-time form (see OperatorRelighter)."""
    return OperatorRelighter(compressed, device=device, threads=threads, memory_budget=memory_budget).apply(irradiance)
