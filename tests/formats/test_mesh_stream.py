"""mesh_stream: every whole-packet prefix decodes to exactly the level of detail of its vertex count
(``progressive_mesh.lod_faces``), the full stream is the original mesh, appearance levels equal a brute
force search, and broken data fails with a message."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import Delaunay

from usdbake.benchmarks.bench_progressive_mesh import height_field
from usdbake.formats import mesh_stream as ms
from usdbake.processors.irradiance_grid import progressive_mesh as pm


def random_mesh(seed: int, count: int):
    """A Delaunay triangulation of random points on a bumpy surface, plus a separate triangle (two pieces)."""
    rng = np.random.default_rng(seed)
    xy = rng.random((count, 2))
    tris = Delaunay(xy).simplices
    points = np.c_[xy, 0.2 * np.sin(6 * xy[:, 0]) * np.cos(5 * xy[:, 1])]
    points = np.vstack([points, [[5, 5, 0], [6, 5, 0], [5, 6, 0]]])
    return points, np.vstack([tris, [[count, count + 1, count + 2]]])


def as_rows(faces: np.ndarray) -> list[tuple]:
    return sorted(map(tuple, np.asarray(faces, np.int64).tolist()))


def check_prefixes(points, tris, packet_vertices):
    rank, collapse_to = pm.progressive_order(points, tris)
    data = ms.encode_mesh_stream(points, tris, rank, collapse_to, packet_vertices=packet_vertices)
    offsets = packet_ends(data)
    for end in offsets:
        prefix = ms.decode_mesh_stream(data[:end])
        k = len(prefix.positions)
        expected = rank[pm.lod_faces(tris, rank, collapse_to, k)]
        assert as_rows(prefix.faces) == as_rows(expected), k
        if len(prefix.faces):
            assert prefix.faces.min() >= 0 and prefix.faces.max() < k
    full = ms.decode_mesh_stream(data)
    order = np.argsort(rank)
    np.testing.assert_array_equal(full.positions, points[order].astype(np.float32))
    proper = tris[(tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])]
    assert as_rows(full.faces) == as_rows(rank[proper])  # the original mesh, vertices in stream order
    return data


def packet_ends(data: bytes) -> list[int]:
    """Byte offsets where each packet ends (the whole-packet prefixes)."""
    _, _, _, packets, table_bytes = ms.MESH_HEADER.unpack_from(data, 0)
    offset = ms.MESH_HEADER.size + table_bytes
    ends = [offset]
    for _ in range(packets):
        _, count, faces = ms.PACKET_HEADER.unpack_from(data, offset)
        offset += ms.PACKET_HEADER.size + 12 * count + 12 * faces
        ends.append(offset)
    assert offset == len(data)
    return ends


def test_every_packet_prefix_is_its_level_of_detail():
    check_prefixes(*height_field(12, bumps=3.0), packet_vertices=7)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.integers(8, 120), st.integers(1, 40))
def test_prefixes_of_random_meshes(seed, count, packet_vertices):
    check_prefixes(*random_mesh(seed, count), packet_vertices)


def test_appearance_levels_match_a_brute_force_search():
    points, tris = random_mesh(3, 60)
    rank, collapse_to = pm.progressive_order(points, tris)
    order = np.argsort(rank)
    table = np.where(collapse_to[order] >= 0, rank[np.maximum(collapse_to[order], 0)], -1)
    faces = rank[tris]
    levels = ms.appearance_levels(table, faces)
    for f, face in enumerate(tris):
        first = next(k for k in range(len(points) + 1) if len(pm.lod_faces(face[None], rank, collapse_to, k)))
        assert levels[f] == first, f


def test_a_truncated_stream_drops_the_partial_packet_and_broken_data_is_refused():
    points, tris = height_field(6, bumps=3.0)
    rank, collapse_to = pm.progressive_order(points, tris)
    data = ms.encode_mesh_stream(points, tris, rank, collapse_to, packet_vertices=10)
    ends = packet_ends(data)
    cut = ms.decode_mesh_stream(data[: ends[2] + 5])
    assert cut.packets == 2 and len(cut.positions) == 20
    assert ms.decode_mesh_stream(data[: ends[0]]).faces.shape == (0, 3)
    with pytest.raises(ValueError, match="bad magic"):
        ms.decode_mesh_stream(b"X" * 40)
    with pytest.raises(ValueError, match="inside the 36-vertex collapse table"):
        ms.decode_mesh_stream(data[: ms.MESH_HEADER.size + 8])
    with pytest.raises(ValueError, match="at least one vertex"):
        ms.encode_mesh_stream(points, tris, rank, collapse_to, packet_vertices=0)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.integers(0, 2**35 - 1), max_size=40))
def test_varints_round_trip(values):
    data = ms.encode_varints(np.array(values, np.int64))
    np.testing.assert_array_equal(ms.decode_varints(data, len(values)), values)
    assert len(data) == sum(1 + (v >= 2**7) + (v >= 2**14) + (v >= 2**21) + (v >= 2**28) for v in values)
    if values:
        with pytest.raises(ValueError, match="does not hold"):
            ms.decode_varints(data, len(values) + 1)
