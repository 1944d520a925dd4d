"""processors/radiosity/sparse_operator.py on its own: the side file of a compressed operator.

- the archive holds exactly the module docstring's table: its keys, dtypes and shapes, stored (not
  deflated), readable without pickle, the same bytes for the same operator (the file is named by a digest
  of them) and other bytes for another;
- read back, its arrays with the BC1 blocks decode to the same operator as the CompressedOperator they came
  from, and its exact entries, taken through the stored permutation, are the operator's own values;
- an operator with no exact entries keeps the empty CSR shapes.
"""

from __future__ import annotations

import dataclasses
import io
import zipfile

import numpy as np
import pytest

from tolerances import FLOAT32_STORAGE
from usdbake.processors.radiosity import operator_codec as codec
from usdbake.processors.radiosity.sparse_operator import sparse_file_bytes

N = 22
"""Patches: not a multiple of 4, so the BC1 texture is padded."""


def operator(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)  # fixed by the caller: entries of many hues and a few large ones
    values = rng.exponential(1e-3, (3, N, N)).astype(np.float32)
    values[:, rng.integers(0, N, 12), rng.integers(0, N, 12)] = 0.3
    return values


@pytest.fixture(scope="module")
def compressed():
    return codec.compress_operator(operator(1), exact_fraction=0.05)


def read(data: bytes) -> dict:
    with np.load(io.BytesIO(data), allow_pickle=False) as archive:
        return {key: archive[key] for key in archive.files}


def test_the_archive_holds_the_documented_table(compressed):
    data = read(sparse_file_bytes(compressed))
    nnz = int(compressed.sparse_indptr[-1])
    assert nnz > 0  # the check below sees a real sparse part
    expected = {"indptr": ((N + 1,), np.int32), "indices": ((nnz,), np.int32), "values": ((nnz, 3), np.float32),
                "lut": ((256,), np.float32), "permutation": ((N,), np.int32), "row_scale": ((N, 3), np.float32)}
    assert set(data) == set(expected)
    for key, (shape, dtype) in expected.items():
        assert data[key].shape == shape and data[key].dtype == dtype, key
    np.testing.assert_array_equal(data["indptr"], compressed.sparse_indptr)
    np.testing.assert_array_equal(data["indices"], compressed.sparse_indices)
    np.testing.assert_array_equal(data["values"], compressed.sparse_values)
    np.testing.assert_array_equal(data["lut"], compressed.lut)
    np.testing.assert_array_equal(data["permutation"], compressed.permutation)
    np.testing.assert_array_equal(data["row_scale"], compressed.row_scale)
    # CSR invariants a reader relies on
    assert data["indptr"][0] == 0 and np.all(np.diff(data["indptr"]) >= 0)
    assert ((data["indices"] >= 0) & (data["indices"] < N)).all()
    np.testing.assert_array_equal(np.sort(data["permutation"]), np.arange(N))
    assert data["lut"][0] == 0.0


def test_the_archive_is_stored_uncompressed_and_its_bytes_repeat(compressed):
    data = sparse_file_bytes(compressed)
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        infos = archive.infolist()
    assert sorted(info.filename for info in infos) == sorted(
        f"{key}.npy" for key in ("indptr", "indices", "values", "lut", "permutation", "row_scale"))
    assert all(info.compress_type == zipfile.ZIP_STORED for info in infos)
    assert sparse_file_bytes(compressed) == data  # the file name is a digest of these bytes
    other = codec.compress_operator(operator(2), exact_fraction=0.05)
    assert sparse_file_bytes(other) != data


def test_read_back_it_decodes_to_the_same_operator(compressed):
    data = read(sparse_file_bytes(compressed))
    rebuilt = dataclasses.replace(compressed, sparse_indptr=data["indptr"], sparse_indices=data["indices"],
                                  sparse_values=data["values"], lut=data["lut"], permutation=data["permutation"],
                                  row_scale=data["row_scale"])
    decoded = codec.decompress_operator(rebuilt)
    np.testing.assert_array_equal(decoded, codec.decompress_operator(compressed))
    # stored entry (r, c) is patch pair (permutation[r], permutation[c]): there the decode is exact
    truth = operator(1)
    rows = np.repeat(np.arange(N), np.diff(data["indptr"]))
    perm = data["permutation"]
    i, j = perm[rows], perm[data["indices"]]
    # (the BC1 texel's value plus the stored difference: one float32 addition of values up to the largest)
    np.testing.assert_allclose(decoded[:, i, j], truth[:, i, j], rtol=0, atol=FLOAT32_STORAGE * float(truth.max()))
    # the large entries are among them
    large = np.argwhere(truth.max(axis=0) >= 0.3)
    exact = set(zip(i.tolist(), j.tolist()))
    assert all((a, b) in exact for a, b in large.tolist())


def test_an_operator_without_exact_entries_keeps_the_empty_shapes():
    smooth = np.full((3, N, N), 1e-3, np.float32)
    compressed = codec.compress_operator(smooth, exact_fraction=0.0, max_error=1.0)
    data = read(sparse_file_bytes(compressed))
    np.testing.assert_array_equal(data["indptr"], np.zeros(N + 1, np.int32))
    assert data["indices"].shape == (0,) and data["values"].shape == (0, 3)
    assert data["values"].dtype == np.float32 and data["indices"].dtype == np.int32
