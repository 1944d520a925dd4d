"""The sparse side file of a compressed radiosity operator (``usdbake_radiosity_<hash>_sparse.npz``).

Everything a relight needs beside the BC1 blocks of the .dds (processors/radiosity/dds.py),
as one uncompressed NumPy .npz archive (``numpy.savez``):

=========== ============== ===================================================
key         array          meaning
=========== ============== ===================================================
indptr      (n + 1,) int32 CSR row pointers of the exact entries (stored order)
indices     (nnz,) int32   stored column of each exact entry
values      (nnz, 3) f32   exact RGB values
lut         (256,) f32     byte code -> value (code 0 is 0)
permutation (n,) int32     patch stored at row/column i
row_scale   (n, 3) f32     per stored row and channel factor on the decoded BC1 part
=========== ============== ===================================================

The layout is that of processors/radiosity/operator_codec.py (Shcherbakov, MSU 2017,
section 4.2: the largest entries kept exact beside the DXT texture).
"""

from __future__ import annotations

import io

import numpy as np

from .products import CompressedOperator


def sparse_file_bytes(compressed: CompressedOperator) -> bytes:
    """The .npz archive of the table above, as bytes (written next to the .dds)."""
    buffer = io.BytesIO()
    np.savez(buffer, indptr=compressed.sparse_indptr, indices=compressed.sparse_indices,
             values=compressed.sparse_values, lut=compressed.lut, permutation=compressed.permutation,
             row_scale=compressed.row_scale)
    return buffer.getvalue()
