"""Relight by matrix-vector products with the compressed multi-bounce operator, decoding BC1 on the fly.

Shcherbakov (MSU 2017), section 3.5 steps 2-4 with the operator of section 4.1:
indirect irradiance E_ind = M E0 with M = sum_h (F^C)^h the k-bounce operator
that ``form_factors`` compressed (section 4.2: top values exact
in a sparse part, the rest as log-quantized codes in BC1 blocks, rows and
columns reordered). The kernels decode each block's two endpoints into a
4-entry palette of codes, look the codes up in a 256-entry table and never
materialize the float matrix; they work in the stored (permuted) order.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .bc1 import bc1_palette, block_words
from .tracer import launch_chunked

wp.set_module_options({"enable_backward": False})


@wp.struct
class CompressedRows:
    """The compressed operator on the device, in stored (permuted) order."""

    words: wp.array(dtype=wp.int64)
    """Two words per BC1 block (endpoints, then 16 two-bit codes), block rows of ``blocks_per_row``."""
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
    """The 4 operator values (RGB) one BC1 block's 2-bit codes choose from."""

    p0: wp.vec3
    p1: wp.vec3
    p2: wp.vec3
    p3: wp.vec3


@wp.func
def lut_color(lut: wp.array(dtype=float), code: wp.vec3i) -> wp.vec3:
    """Operator value per channel of an 8-bit log code (section 4.2: v = exp(code * scale + offset))."""
    return wp.vec3(lut[code[0]], lut[code[1]], lut[code[2]])


@wp.func
def block_palette(lut: wp.array(dtype=float), word0: int) -> BlockPalette:
    """The operator values of a block's BC1 palette (``bc1_palette``), looked up in the code table."""
    codes = bc1_palette(word0)
    palette = BlockPalette()
    palette.p0 = lut_color(lut, codes.c0)
    palette.p1 = lut_color(lut, codes.c1)
    palette.p2 = lut_color(lut, codes.c2)
    palette.p3 = lut_color(lut, codes.c3)
    return palette


@wp.func
def row_product(bits: int, palette: BlockPalette, x0: wp.vec3, x1: wp.vec3, x2: wp.vec3, x3: wp.vec3) -> wp.vec3:
    """Sum over the 4 texels of one block row (8 bits of codes) of palette[code] * x (per channel)."""
    acc = wp.vec3(0.0, 0.0, 0.0)
    for c in range(4):
        code = (bits >> (2 * c)) & 3
        value = wp.where(code >= 2, wp.where(code == 3, palette.p3, palette.p2),
                         wp.where(code == 1, palette.p1, palette.p0))
        xc = wp.where(c >= 2, wp.where(c == 3, x3, x2), wp.where(c == 1, x1, x0))
        acc += wp.cw_mul(value, xc)
    return acc


@wp.func
def finish_block_row(op: CompressedRows, br: int, y0: wp.vec3, y1: wp.vec3, y2: wp.vec3, y3: wp.vec3,
                     x: wp.array(dtype=wp.vec3), y: wp.array(dtype=wp.vec3)):
    """Rows 4 br .. 4 br + 3 of y: the decoded BC1 part times the row-sum correction, plus the exact sparse
    part (section 4.2: the top values are kept exact, the rest log-quantized in BC1 blocks)."""
    for r in range(4):
        row = 4 * br + r
        if row < op.size:
            acc = wp.where(r >= 2, wp.where(r == 3, y3, y2), wp.where(r == 1, y1, y0))
            acc = wp.cw_mul(acc, op.row_scale[row])
            for e in range(op.indptr[row], op.indptr[row + 1]):
                acc += wp.cw_mul(op.values[e], x[op.indices[e]])
            y[row] = acc


@wp.kernel
def relight_bc1_kernel(start: int, op: CompressedRows, x: wp.array(dtype=wp.vec3), y: wp.array(dtype=wp.vec3)):
    """y = M x for the 4 stored rows of block row ``start + tid`` (stored order, x padded to 4).

    Per block: decode the two endpoints into a 4-entry palette (12 table lookups), then 16
    texel codes pick palette entries; the float matrix is never formed.
    """
    br = start + wp.tid()
    y0 = wp.vec3(0.0, 0.0, 0.0)
    y1 = wp.vec3(0.0, 0.0, 0.0)
    y2 = wp.vec3(0.0, 0.0, 0.0)
    y3 = wp.vec3(0.0, 0.0, 0.0)
    base = br * op.blocks_per_row
    for bx in range(op.blocks_per_row):
        palette = block_palette(op.lut, int(op.words[2 * (base + bx)]))
        word1 = int(op.words[2 * (base + bx) + 1])
        j = 4 * bx
        x0 = x[j]
        x1 = x[j + 1]
        x2 = x[j + 2]
        x3 = x[j + 3]
        y0 += row_product(word1 & 255, palette, x0, x1, x2, x3)
        y1 += row_product((word1 >> 8) & 255, palette, x0, x1, x2, x3)
        y2 += row_product((word1 >> 16) & 255, palette, x0, x1, x2, x3)
        y3 += row_product((word1 >> 24) & 255, palette, x0, x1, x2, x3)
    finish_block_row(op, br, y0, y1, y2, y3, x, y)


@wp.kernel
def code_sums_kernel(start: int, x: wp.array(dtype=wp.vec3), sums: wp.array2d(dtype=wp.vec3)):
    """Per block column bx and row byte b (4 two-bit codes): sums[bx * 256 + b, p] = sum of the x_j
    of that block row whose code is p. Built once per relight (n/4 * 256 items, 1/16 of the texels)."""
    item = start + wp.tid()
    bx = item // 256
    byte = item % 256
    s0 = wp.vec3(0.0, 0.0, 0.0)
    s1 = wp.vec3(0.0, 0.0, 0.0)
    s2 = wp.vec3(0.0, 0.0, 0.0)
    s3 = wp.vec3(0.0, 0.0, 0.0)
    for c in range(4):
        code = (byte >> (2 * c)) & 3
        xc = x[4 * bx + c]
        if code == 0:
            s0 += xc
        elif code == 1:
            s1 += xc
        elif code == 2:
            s2 += xc
        else:
            s3 += xc
    sums[item, 0] = s0
    sums[item, 1] = s1
    sums[item, 2] = s2
    sums[item, 3] = s3


@wp.func
def row_from_sums(sums: wp.array2d(dtype=wp.vec3), t: int, palette: BlockPalette) -> wp.vec3:
    """Sum over the 4 palette entries p of palette[p] * (the x_j whose code is p), for table row t."""
    return (wp.cw_mul(palette.p0, sums[t, 0]) + wp.cw_mul(palette.p1, sums[t, 1])
            + wp.cw_mul(palette.p2, sums[t, 2]) + wp.cw_mul(palette.p3, sums[t, 3]))


@wp.kernel
def relight_bc1_sums_kernel(start: int, op: CompressedRows, x: wp.array(dtype=wp.vec3),
                            sums: wp.array2d(dtype=wp.vec3), y: wp.array(dtype=wp.vec3)):
    """relight_bc1_kernel with the texel loop replaced by code_sums lookups: per block row of 4
    texels, y += sum_p palette[p] * sums[bx, codes, p] (4 products instead of 4 selects + 4)."""
    br = start + wp.tid()
    y0 = wp.vec3(0.0, 0.0, 0.0)
    y1 = wp.vec3(0.0, 0.0, 0.0)
    y2 = wp.vec3(0.0, 0.0, 0.0)
    y3 = wp.vec3(0.0, 0.0, 0.0)
    base = br * op.blocks_per_row
    for bx in range(op.blocks_per_row):
        palette = block_palette(op.lut, int(op.words[2 * (base + bx)]))
        word1 = int(op.words[2 * (base + bx) + 1])
        t = bx * 256
        y0 += row_from_sums(sums, t + (word1 & 255), palette)
        y1 += row_from_sums(sums, t + ((word1 >> 8) & 255), palette)
        y2 += row_from_sums(sums, t + ((word1 >> 16) & 255), palette)
        y3 += row_from_sums(sums, t + ((word1 >> 24) & 255), palette)
    finish_block_row(op, br, y0, y1, y2, y3, x, y)


def launch_rows(kernel, dim: int, inputs: list, device, threads: int) -> None:
    """Launch a row kernel split across threads: rows are few but heavy, so any chunk is worth a thread."""
    launch_chunked(kernel, dim, inputs, device=device, threads=threads, min_chunk=1)


class Relighter:
    """The compressed operator uploaded once; ``apply(E0)`` -> indirect irradiance, per relight."""

    def __init__(self, compressed, *, device="cpu", threads: int = 1):
        self.size = compressed.size
        self.padded = compressed.padded
        self.device = wp.get_device(device)
        self.threads = threads
        self.permutation = np.asarray(compressed.permutation, np.int64)
        self.op = CompressedRows()
        self.op.words = wp.array(block_words(compressed.blocks), dtype=wp.int64, device=self.device)
        self.op.blocks_per_row = self.padded // 4
        self.op.lut = wp.array(compressed.lut, dtype=float, device=self.device)
        self.op.row_scale = wp.array(compressed.row_scale, dtype=wp.vec3, device=self.device)
        self.op.indptr = wp.array(compressed.sparse_indptr, dtype=int, device=self.device)
        self.op.indices = wp.array(compressed.sparse_indices, dtype=int, device=self.device)
        self.op.values = wp.array(compressed.sparse_values.reshape(-1, 3), dtype=wp.vec3, device=self.device)
        self.op.size = self.size
        self.x = wp.zeros(self.padded, dtype=wp.vec3, device=self.device)
        self.y = wp.zeros(self.padded, dtype=wp.vec3, device=self.device)
        self.sums = wp.zeros((self.padded // 4 * 256, 4), dtype=wp.vec3, device=self.device)

    def apply_stored(self, *, texel_loop: bool = False) -> None:
        """y = M x on the device buffers (stored order); what the relight timing measures.

        Default: code sums per block column (code_sums_kernel), then 4 palette products per block
        row; ``texel_loop`` runs the plain per-texel decode instead (same result to rounding).
        """
        if texel_loop:
            launch_rows(relight_bc1_kernel, self.padded // 4, [self.op, self.x, self.y], self.device, self.threads)
            return
        launch_rows(code_sums_kernel, self.padded // 4 * 256, [self.x, self.sums], self.device, self.threads)
        launch_rows(relight_bc1_sums_kernel, self.padded // 4, [self.op, self.x, self.sums, self.y], self.device,
                    self.threads)

    def apply(self, irradiance: np.ndarray) -> np.ndarray:
        """(n, 3) direct irradiance per patch (patch order) -> (n, 3) indirect irradiance."""
        x = np.zeros((self.padded, 3), np.float32)
        x[:self.size] = np.asarray(irradiance, np.float32)[self.permutation]
        self.x.assign(x)
        self.apply_stored()
        out = np.empty((self.size, 3), np.float32)
        out[self.permutation] = self.y.numpy()[:self.size]
        return out


def relight(compressed, irradiance: np.ndarray, *, device="cpu", threads: int = 1) -> np.ndarray:
    """Indirect irradiance (n, 3) = M E0 with the compressed operator (see Relighter)."""
    return Relighter(compressed, device=device, threads=threads).apply(irradiance)
