"""The relight's two run-time forms (dense BLAS, compressed in-kernel decode) against a float64 product
of the decoded operator, and the memory budget that picks between them."""

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st
from tolerances import FLOAT32_ACCUMULATED
from usdbake.processors.radiosity.products import CompressedOperator
from usdbake.processors.radiosity import bc1
from usdbake.processors.radiosity.operator_relight import (COMPRESSED, DENSE, OperatorRelighter, dense_nbytes,
                                                          palette_blocks, relight_form)


def operator_from(block_bytes: bytes, size: int, seed: int) -> CompressedOperator:
    """A compressed operator with arbitrary BC1 blocks (both palette modes), a log table, row factors and
    a sparse part, permuted: every field a relight reads, with no structure to lean on."""
    rng = np.random.default_rng(seed)
    padded = (size + 3) // 4 * 4
    count = (padded // 4) ** 2
    blocks = np.frombuffer((block_bytes * (8 * count // max(1, len(block_bytes)) + 1))[:8 * count], np.uint8)
    nnz_rows = rng.integers(0, min(4, size + 1), size)
    indices = np.concatenate([rng.choice(size, k, replace=False) for k in nnz_rows]).astype(np.int32)
    lut = np.concatenate([[0.0], np.exp(np.linspace(-9, 0, 255))]).astype(np.float32)
    return CompressedOperator(
        size=size, blocks=blocks.reshape(count, 8).copy(), permutation=rng.permutation(size).astype(np.int32),
        sparse_indptr=np.concatenate([[0], np.cumsum(nnz_rows)]).astype(np.int32), sparse_indices=indices,
        sparse_values=rng.uniform(0, 0.1, (len(indices), 3)).astype(np.float32), lut=lut,
        log_scale=9 / 254, log_offset=-9.0, quantization="log",
        row_scale=rng.uniform(0.5, 1.5, (size, 3)).astype(np.float32))


def reference_operator(op: CompressedOperator) -> np.ndarray:
    """(3, n, n) float64 in patch order, decoded independently of the library's decoders: the whole BC1
    texture at once (``decode_bc1``, checked against OpenImageIO in test_bc1), the code table, the row
    factors, the sparse part added entry by entry, the permutation undone."""
    n, n4 = op.size, op.padded
    stored = op.lut[bc1.decode_bc1(op.blocks, n4, n4)[:n, :n]].astype(np.float64) * op.row_scale[:, None, :]
    for row in range(n):
        for e in range(op.sparse_indptr[row], op.sparse_indptr[row + 1]):
            stored[row, op.sparse_indices[e]] += op.sparse_values[e]
    out = np.empty_like(stored)
    out[np.ix_(op.permutation, op.permutation)] = stored
    return np.moveaxis(out, -1, 0)


@settings(max_examples=25, deadline=None)
@given(st.binary(min_size=8, max_size=256), st.integers(1, 23), st.integers(0, 2**16))
def test_both_forms_equal_the_decoded_operator(block_bytes, size, seed):
    op = operator_from(block_bytes, size, seed)
    x = np.random.default_rng(seed + 1).uniform(0, 1, (size, 3)).astype(np.float32)  # any light
    matrix = reference_operator(op)
    expected = np.stack([matrix[c] @ x[:, c] for c in range(3)], axis=1)
    scale = max(float(np.abs(expected).max()), 1e-30)
    # The compressed form as the CPU runs it (one item a block row) and as CUDA does (lanes per block row,
    # atomic partial sums; 3 lanes here so that lanes share block rows unevenly).
    for form, lanes in ((DENSE, None), (COMPRESSED, 0), (COMPRESSED, 3)):
        got = OperatorRelighter(op, form=form, threads=2, lanes=lanes).apply(x)
        np.testing.assert_allclose(got / scale, expected / scale, atol=FLOAT32_ACCUMULATED, err_msg=f"{form} {lanes}")


def test_run_time_blocks_hold_the_bc1_palette_bytes():
    rng = np.random.default_rng(5)  # fixed: arbitrary blocks, both palette modes
    blocks = rng.integers(0, 256, (4096, 8), dtype=np.uint8)
    runtime = palette_blocks(blocks)
    texels = bc1.decode_bc1_texels(blocks)  # (B, 16, 3) bytes, the reference decoder
    codes = (runtime[:, :1] >> (2 * np.arange(16, dtype=np.uint32))) & 3  # (B, 16) texel codes
    for channel in range(3):
        palette = (runtime[:, 1 + channel, None] >> (8 * np.arange(4, dtype=np.uint32))) & 255  # (B, 4)
        np.testing.assert_array_equal(np.take_along_axis(palette, codes.astype(np.int64), axis=1),
                                      texels[:, :, channel])


def test_memory_budget_picks_the_form():
    op = operator_from(bytes(range(256)), 40, 3)
    assert relight_form(40, "cpu", memory_budget=dense_nbytes(40)) == DENSE
    assert relight_form(40, "cpu", memory_budget=dense_nbytes(40) - 1) == COMPRESSED
    assert OperatorRelighter(op, memory_budget=0).form == COMPRESSED
    dense, compressed = OperatorRelighter(op, memory_budget=10**9), OperatorRelighter(op, memory_budget=0)
    assert dense.form == DENSE and dense.nbytes >= dense_nbytes(40)
    assert compressed.nbytes < 0.5 * dense_nbytes(40)  # 16 bytes a 4x4 block, plus the sparse part
    with pytest.raises(ValueError, match="form="):
        OperatorRelighter(op, form="sparse")


@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")
def test_cuda_runs_the_compressed_form_and_agrees():
    op = operator_from(bytes(range(256)), 57, 4)
    x = np.random.default_rng(2).uniform(0, 1, (57, 3)).astype(np.float32)
    on_gpu = OperatorRelighter(op, device="cuda:0")
    assert on_gpu.form == COMPRESSED
    np.testing.assert_allclose(on_gpu.apply(x), OperatorRelighter(op, form=DENSE).apply(x), rtol=FLOAT32_ACCUMULATED,
                               atol=FLOAT32_ACCUMULATED)
