"""Progressive mesh stream: vertices coarse-to-fine, each face in the packet that completes it.

Pacanowski et al. 2008, "Efficient Streaming of 3D Scenes with Complex
Geometry and Complex Lighting", section 4.2: a mesh ordered by half-edge
collapses (``processors/irradiance_grid/progressive_mesh.py``: a rank per vertex and the
vertex each collapses onto) is sent vertex by vertex, coarse first; a client
holding the first k vertices maps every face corner through the collapse
table to a received vertex and keeps the faces whose three corners stay
distinct -- the level of detail k.

**Stream order.** Vertices are renumbered by rank, so vertex r of the stream
is the r-th sent and collapses onto a vertex of lower number. A face is sent
in the packet holding the vertex that makes it *appear*: its appearance level
``a_f`` is the smallest k at which it is whole (``appearance_levels``), and a
face whole at level k stays whole at every later level (receiving vertex k
only splits the vertices that map to k's ancestor). So a client that has the
packets up to level k has exactly the faces of the level of detail k, and
the whole stream is the original mesh (vertices in stream order).

**Collapse table up front.** A face's corners may be vertices not yet
received; the client maps them through the table, so the table is sent
before the first packet, each entry as the distance ``r - target`` down the
stream (0: no target) in LEB128 varint bytes: 2.8 bytes a vertex on a 200k
height field instead of 4 (the targets are far apart in stream order, so the
distances are large, but rarely above 2^21).

**File** (little-endian):

================ ============ ==============================================
field            type         meaning
================ ============ ==============================================
magic            8 bytes      ``b"USDBPM01"``
vertices         uint32       P
faces            uint32       F
packets          uint32       N
table bytes      uint32       B
collapse table   B bytes      P varints: r - target of vertex r (0: none)
packets          ...          N x (uint32 first vertex, uint32 vertex count n,
                              uint32 face count m, n x 3 float32 positions,
                              m x 3 uint32 corners in stream order)
================ ============ ==============================================

A prefix holding the header, the table and any number of whole packets decodes
to a valid mesh (``decode_mesh_stream``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

MESH_MAGIC = b"USDBPM01"
MESH_HEADER = struct.Struct("<8sIIII")
PACKET_HEADER = struct.Struct("<III")


def encode_varints(values: np.ndarray) -> bytes:
    """LEB128 bytes of non-negative integers below 2^35: 7 bits a byte, low first, high bit = more follows."""
    v = np.asarray(values, np.uint64).reshape(-1)
    width = 1 + sum((v >= np.uint64(1 << (7 * j))).astype(np.int64) for j in range(1, 5))
    start = np.cumsum(width) - width
    out = np.zeros(int(width.sum()), np.uint8)
    for j in range(5):
        has = width > j
        more = (width[has] > j + 1).astype(np.uint64) << np.uint64(7)
        out[start[has] + j] = ((v[has] >> np.uint64(7 * j)) & np.uint64(0x7F)) | more
    return out.tobytes()


def decode_varints(data: bytes, count: int) -> np.ndarray:
    """(count,) int64 of ``encode_varints`` bytes; ValueError when they do not hold exactly that many."""
    b = np.frombuffer(data, np.uint8).astype(np.int64)
    last = (b & 0x80) == 0
    if int(last.sum()) != count or (len(b) and not last[-1]):
        raise ValueError(f"mesh stream: the collapse table does not hold {count} entries")
    value = np.cumsum(last) - last  # the entry each byte belongs to
    first = np.flatnonzero(np.r_[True, last[:-1]])
    shift = 7 * (np.arange(len(b)) - first[value])
    return np.bincount(value, weights=(b & 0x7F) * np.exp2(shift), minlength=count).astype(np.int64)


def _pointer_jump_depth_and_root(parent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(depth, root) of every node of a forest given by ``parent`` (-1 for roots), by pointer jumping."""
    depth = (parent >= 0).astype(np.int64)
    ancestor = parent.copy()
    while (ancestor >= 0).any():
        has = np.flatnonzero(ancestor >= 0)
        above = ancestor[has]
        depth[has] += depth[above]  # both read before either is written: a synchronous jump
        ancestor[has] = ancestor[above]
    root = np.where(parent >= 0, parent, np.arange(len(parent)))
    while True:
        jumped = root[root]
        if np.array_equal(jumped, root):
            return depth, root
        root = jumped


def _merge_levels(a: np.ndarray, b: np.ndarray, up: list[np.ndarray], depth: np.ndarray,
                  root: np.ndarray) -> np.ndarray:
    """Per pair (a, b) of distinct vertices: the largest level at which both map to one vertex, -1 if never.

    Below the lowest common ancestor each has a branch; at level k a vertex maps into its branch as soon as
    the branch's top (the child of the ancestor, the branch's lowest number) has been received, so the
    two coincide exactly while k <= min(top of a's branch, top of b's branch) (an empty branch: no bound).
    """
    big = np.iinfo(np.int64).max
    swap = depth[a] < depth[b]
    a, b = np.where(swap, b, a), np.where(swap, a, b)  # a is the deeper
    top_a = np.full(len(a), big)
    top_b = np.full(len(a), big)
    deeper = depth[a] > depth[b]
    lift = np.where(deeper, depth[a] - depth[b] - 1, 0)  # to one below b's depth
    x = a.copy()
    for j, table in enumerate(up):
        move = (lift >> j) & 1 == 1
        x[move] = table[x[move]]
    # Deeper a: x is a's ancestor one level below b; its parent is b when b is the common ancestor.
    b_is_ancestor = deeper & (up[0][x] == b)
    top_a[b_is_ancestor] = x[b_is_ancestor]
    y = np.where(deeper, up[0][x], a)  # a lifted to b's depth
    z = b.copy()
    rest = ~b_is_ancestor & (y != z)
    for table in reversed(up):
        differ = rest & (table[y] != table[z])
        y[differ], z[differ] = table[y[differ]], table[z[differ]]
    top_a[rest], top_b[rest] = y[rest], z[rest]
    level = np.minimum(top_a, top_b)
    return np.where(root[a] == root[b], level, -1)


def appearance_levels(collapse: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) int64 smallest level k (vertices 0..k-1 received, stream order) at which each face is whole:
    its corners map through ``collapse`` (stream order, each target numbered lower, -1 for none) to three
    distinct received vertices. Faces must have three distinct corners."""
    parent = np.asarray(collapse, np.int64)
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    depth, root = _pointer_jump_depth_and_root(parent)
    first = np.where(parent >= 0, parent, np.arange(len(parent)))
    up = [first]
    while (1 << len(up)) <= max(1, int(depth.max(initial=0))):
        up.append(up[-1][up[-1]])
    level = root[faces].max(axis=1) + 1  # the corners' trees must have arrived
    for i, j in ((0, 1), (1, 2), (0, 2)):
        level = np.maximum(level, _merge_levels(faces[:, i], faces[:, j], up, depth, root) + 1)
    return level


def encode_mesh_stream(points: np.ndarray, tri_vertices: np.ndarray, rank: np.ndarray, collapse_to: np.ndarray,
                       *, packet_vertices: int = 4096) -> bytes:
    """Bytes of the stream of a mesh with its progressive order (``progressive_mesh.progressive_order``):
    packets of ``packet_vertices`` vertices and the faces they complete. Faces with repeated corners hold
    no surface and are left out."""
    if packet_vertices < 1:
        raise ValueError(f"packet_vertices {packet_vertices}: a packet holds at least one vertex")
    rank = np.asarray(rank, np.int64)
    order = np.argsort(rank)
    collapse_to = np.asarray(collapse_to, np.int64)
    table = np.where(collapse_to[order] >= 0, rank[np.maximum(collapse_to[order], 0)], -1)
    faces = rank[np.asarray(tri_vertices, np.int64).reshape(-1, 3)]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    appear = appearance_levels(table, faces)
    by_level = np.argsort(appear, kind="stable")
    faces, appear = faces[by_level], appear[by_level]
    positions = np.ascontiguousarray(np.asarray(points, np.float32).reshape(-1, 3)[order])
    starts = np.arange(0, len(rank), packet_vertices)
    distances = encode_varints(np.where(table >= 0, np.arange(len(table)) - table, 0))
    chunks = [MESH_HEADER.pack(MESH_MAGIC, len(rank), len(faces), len(starts), len(distances)), distances]
    for start in starts:
        stop = min(len(rank), start + packet_vertices)
        lo, hi = np.searchsorted(appear, [start + 1, stop + 1])  # faces whose level lies in (start, stop]
        chunks += [PACKET_HEADER.pack(int(start), int(stop - start), int(hi - lo)),
                   positions[start:stop].tobytes(), faces[lo:hi].astype(np.uint32).tobytes()]
    return b"".join(chunks)


@dataclass(frozen=True)
class MeshPrefix:
    """What a client holds after a prefix of the stream."""

    positions: np.ndarray
    """(k, 3) float32 the received vertices, stream order."""
    faces: np.ndarray
    """(M, 3) int64 the level of detail k: received faces mapped to received vertices."""
    total_vertices: int
    total_faces: int
    packets: int
    """Whole packets received."""


def decode_mesh_stream(data: bytes) -> MeshPrefix:
    """The level of detail held by a prefix of a stream (a trailing partial packet is dropped)."""
    if len(data) < MESH_HEADER.size:
        raise ValueError(f"mesh stream: {len(data)} bytes is shorter than the {MESH_HEADER.size}-byte header")
    magic, vertices, total_faces, packets, table_bytes = MESH_HEADER.unpack_from(data, 0)
    if magic != MESH_MAGIC:
        raise ValueError(f"mesh stream: bad magic {magic!r} (expected {MESH_MAGIC!r})")
    offset = MESH_HEADER.size + table_bytes
    if len(data) < offset:
        raise ValueError(f"mesh stream: {len(data)} bytes ends inside the {vertices}-vertex collapse table")
    distance = decode_varints(data[MESH_HEADER.size:offset], vertices)
    table = np.where(distance > 0, np.arange(vertices) - distance, -1)
    positions, faces, received = [], [], 0
    for _ in range(packets):
        if offset + PACKET_HEADER.size > len(data):
            break
        start, count, face_count = PACKET_HEADER.unpack_from(data, offset)
        end = offset + PACKET_HEADER.size + 12 * count + 12 * face_count
        if end > len(data):
            break
        body = offset + PACKET_HEADER.size
        positions.append(np.frombuffer(data, np.float32, count=3 * count, offset=body).reshape(-1, 3))
        faces.append(np.frombuffer(data, np.uint32, count=3 * face_count, offset=body + 12 * count).reshape(-1, 3))
        offset, received = end, received + 1
    level = sum(len(p) for p in positions)
    corners = (np.concatenate(faces) if faces else np.zeros((0, 3), np.uint32)).astype(np.int64)
    while True:  # each unreceived corner up its collapse chain to a received vertex
        pending = corners >= level
        if not pending.any():
            break
        corners[pending] = table[corners[pending]]
    return MeshPrefix(np.concatenate(positions) if positions else np.zeros((0, 3), np.float32), corners,
                      int(vertices), int(total_faces), received)
