"""Host-side build of the tracer's 8-wide BVH (numpy): binned SAH, collapsed to 8 children per node.

Written here rather than taken from Warp (``wp.Mesh`` builds a binary BVH whose nodes Python cannot
read) or a library (none on PyPI exposes its nodes in a layout a Warp kernel can walk): the layout is
the point. The build follows Wald, "On fast construction of SAH-based bounding volume hierarchies"
(RT 2007): primitives are binned by centroid into ``BINS`` slabs per axis and each node splits at
the slab boundary of least surface-area cost

    C = C_trav + (A_left / A) N_left + (A_right / A) N_right          (N counted in packets of ``packet``)

or becomes a leaf when that is cheaper and it holds at most ``max_leaf`` primitives. All nodes of a
tree level are split at once with array operations, so the Python loop runs once per level. The
binary tree is then collapsed into 8-wide nodes (Wald, Benthin & Boulos, "Getting rid of packets",
RT 2008): a node adopts the children of its largest internal child until it has eight. Zero-area
triangles and all but the first of each set of copies of a triangle are left out (``build_triangle_bvh``).

Node layout (``NODE_FLOATS`` float32 per node, read by ``kernels.traversal``)::

    [lo_x 8 | lo_y 8 | lo_z 8 | hi_x 8 | hi_y 8 | hi_z 8 | child 8 (int32) | child count (int32) | pad 7]

A child >= 0 is an inner node; a leaf is ``-1 - (first << LEAF_COUNT_BITS | count)``: ``count``
consecutive items (triangle packets, or instances for a top-level tree) from ``first``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

WIDTH = 8
NODE_FLOATS = 8 * WIDTH
CHILD_OFFSET = 6 * WIDTH
COUNT_OFFSET = 7 * WIDTH
LEAF_COUNT_BITS = 3
MAX_LEAF_ITEMS = (1 << LEAF_COUNT_BITS) - 1
BINS = 32
SMALL_NODE_BINS = 8
"""Slabs per axis for a tree level whose nodes hold on average fewer than SMALL_NODE_PRIMITIVES (fewer
slabs than primitives buy nothing, and the per-level cost is nodes x slabs)."""
SMALL_NODE_PRIMITIVES = 128
PACKET = 4
"""Triangles intersected together in one leaf packet (SIMD lanes of ``kernels.traversal``)."""


@dataclass(frozen=True)
class BinaryTree:
    """A binary BVH in breadth-first order; node 0 is the root."""

    lower: np.ndarray
    """(N, 3) float32 node bounds."""
    upper: np.ndarray
    left: np.ndarray
    """(N,) int64 left child (the right child is left + 1), -1 for a leaf."""
    first: np.ndarray
    """(N,) int64 leaf's first position in ``order``."""
    count: np.ndarray
    """(N,) int64 primitives under the node."""
    order: np.ndarray
    """(T,) int64 primitive indices in leaf order."""


def half_area(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Half the surface area of boxes (0 for empty ones, whose upper < lower)."""
    e = np.maximum(upper - lower, 0.0)
    return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]


def build_binary(lower: np.ndarray, upper: np.ndarray, *, max_leaf: int, packet: int = 1,
                 traversal_cost: float = 1.0) -> BinaryTree:
    """Binned-SAH binary BVH over boxes ``lower``/``upper`` (T, 3), level by level (see module doc)."""
    lower = np.asarray(lower, np.float32)
    upper = np.asarray(upper, np.float32)
    count = len(lower)
    centroid = 0.5 * (lower + upper)
    order = np.arange(count, dtype=np.int64)
    levels = []  # per level: node ids, lower, upper, left, first, count
    next_id = 1
    ids, starts, counts = np.array([0]), np.array([0]), np.array([count])
    while len(ids):
        nodes = len(ids)
        offsets = np.cumsum(counts) - counts
        node_of = np.repeat(np.arange(nodes), counts)
        rank = np.arange(len(node_of)) - offsets[node_of]
        positions = starts[node_of] + rank
        items = order[positions]
        item_lower, item_upper, item_centroid = lower[items], upper[items], centroid[items]
        box_lower = np.minimum.reduceat(item_lower, offsets)
        box_upper = np.maximum.reduceat(item_upper, offsets)
        c_lower = np.minimum.reduceat(item_centroid, offsets)
        extent = np.maximum.reduceat(item_centroid, offsets) - c_lower
        bins = BINS if counts.mean() >= SMALL_NODE_PRIMITIVES else SMALL_NODE_BINS
        cost, axis, split, item_bins = _best_splits(item_lower, item_upper, item_centroid, node_of, c_lower,
                                                    extent, counts, packet, bins)
        split_cost = traversal_cost + cost / np.maximum(half_area(box_lower, box_upper), 1e-30)
        leaf = (counts <= 1) | ((counts <= max_leaf) & (np.ceil(counts / packet) <= split_cost))
        # Nodes whose centroids coincide cannot be binned: split them by position, in halves.
        by_position = ~leaf & ~np.isfinite(cost)
        right = item_bins[np.arange(len(items)), axis[node_of]] > split[node_of]
        right = np.where(by_position[node_of], rank >= counts[node_of] // 2, right)
        order[positions] = items[np.lexsort((right, node_of))]
        left_count = np.bincount(node_of, weights=~right, minlength=nodes).astype(np.int64)

        inner = ~leaf
        left_ids = np.full(nodes, -1, np.int64)
        left_ids[inner] = next_id + 2 * np.arange(inner.sum())
        next_id += 2 * int(inner.sum())
        levels.append((ids, box_lower, box_upper, left_ids, starts, counts))
        ids = np.concatenate([left_ids[inner], left_ids[inner] + 1])
        starts, counts = (np.concatenate([starts[inner], starts[inner] + left_count[inner]]),
                          np.concatenate([left_count[inner], counts[inner] - left_count[inner]]))
    position = np.empty(next_id, np.int64)
    position[np.concatenate([level[0] for level in levels])] = np.arange(next_id)

    def gather(k):
        return np.concatenate([level[k] for level in levels])[position]

    return BinaryTree(gather(1).astype(np.float32), gather(2).astype(np.float32), gather(3), gather(4), gather(5),
                      order)


def _best_splits(item_lower, item_upper, item_centroid, node_of, c_lower, extent, counts, packet, bins):
    """Per node, the least SAH cost over ``bins`` slabs on each axis: (cost, axis, split bin, item bins)."""
    nodes = len(counts)
    best_cost = np.full(nodes, np.inf)
    best_axis = np.zeros(nodes, np.int64)
    best_split = np.zeros(nodes, np.int64)
    item_bins = np.empty((len(node_of), 3), np.int64)
    for axis in range(3):
        width = extent[:, axis]
        scale = np.where(width > 0, bins / np.where(width > 0, width, 1.0), 0.0)
        slab = np.clip(((item_centroid[:, axis] - c_lower[node_of, axis]) * scale[node_of]).astype(np.int64),
                       0, bins - 1)
        item_bins[:, axis] = slab
        key = node_of * bins + slab
        in_bin = np.bincount(key, minlength=nodes * bins).reshape(nodes, bins)
        bin_lower = np.full((3, nodes * bins), np.inf, np.float32)
        bin_upper = np.full((3, nodes * bins), -np.inf, np.float32)
        for k in range(3):  # one component at a time: ufunc.at is fast on 1-D arrays only
            np.minimum.at(bin_lower[k], key, item_lower[:, k])
            np.maximum.at(bin_upper[k], key, item_upper[:, k])
        bin_lower = bin_lower.T.reshape(nodes, bins, 3)
        bin_upper = bin_upper.T.reshape(nodes, bins, 3)
        left_area = half_area(np.minimum.accumulate(bin_lower, axis=1), np.maximum.accumulate(bin_upper, axis=1))
        right_area = half_area(np.minimum.accumulate(bin_lower[:, ::-1], axis=1),
                               np.maximum.accumulate(bin_upper[:, ::-1], axis=1))[:, ::-1]
        left_n = np.cumsum(in_bin, axis=1)[:, :-1]
        right_n = counts[:, None] - left_n
        cost = left_area[:, :-1] * np.ceil(left_n / packet) + right_area[:, 1:] * np.ceil(right_n / packet)
        cost = np.where((left_n > 0) & (right_n > 0), cost, np.inf)
        split = np.argmin(cost, axis=1)
        chosen = cost[np.arange(nodes), split]
        better = chosen < best_cost
        best_cost[better], best_axis[better], best_split[better] = chosen[better], axis, split[better]
    return best_cost, best_axis, best_split, item_bins


def collapse(tree: BinaryTree, leaf_refs: np.ndarray) -> np.ndarray:
    """8-wide nodes (M, NODE_FLOATS) float32 from a binary tree; ``leaf_refs`` (N,) int32 is the child
    code of each binary leaf (``leaf_ref``). Each wide node repeatedly opens its largest inner child."""
    area = half_area(tree.lower, tree.upper)
    is_inner = tree.left >= 0
    if not is_inner[0]:  # a single leaf: one wide node holding it
        return _write_nodes(np.array([[0] + [-1] * (WIDTH - 1)]), tree, leaf_refs, np.zeros(0, np.int64))
    rows, wide_index = [], {}
    level = np.array([0])
    total = 0
    while len(level):
        kids = np.full((len(level), WIDTH), -1, np.int64)
        kids[:, 0], kids[:, 1] = tree.left[level], tree.left[level] + 1
        for slot in range(2, WIDTH):
            openable = (kids >= 0) & is_inner[np.maximum(kids, 0)]
            if not openable.any():
                break
            pick = np.argmax(np.where(openable, area[np.maximum(kids, 0)], -1.0), axis=1)
            rows_open = np.flatnonzero(openable.any(axis=1))
            opened = kids[rows_open, pick[rows_open]]
            kids[rows_open, pick[rows_open]] = tree.left[opened]
            kids[rows_open, slot] = tree.left[opened] + 1
        rows.append(kids)
        inner_kids = kids[(kids >= 0) & is_inner[np.maximum(kids, 0)]]
        wide_index[total] = inner_kids
        total += len(level)
        level = inner_kids
    kids = np.concatenate(rows)
    inner_order = np.concatenate([wide_index[k] for k in sorted(wide_index)])
    return _write_nodes(kids, tree, leaf_refs, inner_order)


def _write_nodes(kids: np.ndarray, tree: BinaryTree, leaf_refs: np.ndarray, inner_order: np.ndarray) -> np.ndarray:
    """Fill the node layout; an inner binary node's wide index is 1 + its place in ``inner_order``."""
    wide_of = np.full(len(tree.left), -1, np.int64)
    wide_of[inner_order] = 1 + np.arange(len(inner_order))
    nodes = np.zeros((len(kids), NODE_FLOATS), np.float32)
    ints = nodes.view(np.int32)
    valid = kids >= 0
    safe = np.maximum(kids, 0)
    for axis in range(3):
        nodes[:, axis * WIDTH:(axis + 1) * WIDTH] = np.where(valid, tree.lower[safe, axis], 0.0)
        nodes[:, (3 + axis) * WIDTH:(4 + axis) * WIDTH] = np.where(valid, tree.upper[safe, axis], 0.0)
    child = np.where(tree.left[safe] >= 0, wide_of[safe], leaf_refs[safe])
    ints[:, CHILD_OFFSET:CHILD_OFFSET + WIDTH] = np.where(valid, child, 0)
    ints[:, COUNT_OFFSET] = valid.sum(axis=1)
    return nodes


def leaf_ref(first: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Child code of a leaf holding ``count`` items from ``first``."""
    return (-1 - ((np.asarray(first, np.int64) << LEAF_COUNT_BITS) | np.asarray(count, np.int64))).astype(np.int32)


@dataclass(frozen=True)
class TriangleBvh:
    """A triangle mesh's wide BVH with its triangles in leaf packets."""

    nodes: np.ndarray
    """(M, NODE_FLOATS) float32, root at 0."""
    packets: np.ndarray
    """(P, 9, PACKET) float32: per packet v0.xyz, v1.xyz, v2.xyz, one lane per triangle; NaN in an empty lane.

    NaN, not 0: a lane of zeros is a point triangle at the origin, whose edge functions the watertight test
    computes as exactly 0 (no hit) only if no product and difference are fused into an FMA; fused (CUDA's
    default contraction), they are one rounding error each, of one sign, and the lane was hit at the
    origin's depth (issue 33). Every comparison with NaN is false, so a NaN lane is never hit, whatever
    the arithmetic, at no cost to the traversal."""
    packet_triangle: np.ndarray
    """(P, PACKET) int32 triangle index of each lane, -1 for an empty lane."""


def first_copies(corners: np.ndarray) -> np.ndarray:
    """(K,) int64 ascending indices of the first triangle of each set of copies among ``corners`` (T, 3, 3)
    float32: copies have the same three corners, bit for bit (-0 = +0), in the same cyclic order (the same
    face with the same winding; a back-to-back twin is not a copy).

    O(T log T): each row is rotated to the least of its three cyclic rotations, hashed, sorted by hash
    (stably, so the first copy comes first) and compared with its sorted neighbour. A hash collision only
    keeps a copy it could have dropped; it never drops a distinct triangle.
    """
    corners = np.asarray(corners, np.float32).reshape(-1, 3, 3) + np.float32(0.0)  # -0.0 + 0.0 is +0.0
    if len(corners) < 2:
        return np.arange(len(corners), dtype=np.int64)
    bits = corners.view(np.uint32).reshape(-1, 9)
    rows = bits
    for shift in (3, 6):  # the least rotation, comparing words in order
        rotated = np.roll(bits, -shift, axis=1)
        rows = np.where(_less(rotated, rows)[:, None], rotated, rows)
    digest = np.zeros(len(rows), np.uint64)
    for k in range(9):  # FNV-1a over the nine words (uint64 arithmetic wraps)
        digest = (digest ^ rows[:, k].astype(np.uint64)) * np.uint64(0x100000001B3)
    order = np.argsort(digest, kind="stable")
    ranked = rows[order]
    copy = np.zeros(len(rows), bool)
    copy[1:] = (ranked[1:] == ranked[:-1]).all(axis=1)
    return np.sort(order[~copy])


def _less(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(T,) bool: row a[t] < row b[t] lexicographically (word by word)."""
    differ = a != b
    first = np.argmax(differ, axis=1)
    pick = np.arange(len(a))
    return differ[pick, first] & (a[pick, first] < b[pick, first])


def build_triangle_bvh(points: np.ndarray, tri_vertices: np.ndarray) -> TriangleBvh:
    """Wide BVH of triangles; leaves hold up to two packets of PACKET triangles.

    Zero-area triangles are left out (the watertight test would see a sliver of rounding error in them), and
    so are copies of a triangle (``first_copies``): a ray meets every copy at the same t, so the first one
    stands for them all (the closest hit names it), and the neighbourhood query of ``surface_origin`` would
    otherwise visit all N copies from each of their 3N vertices: N^2 work on N stacked copies (issue 27).
    """
    corners = np.asarray(points, np.float32)[np.asarray(tri_vertices, np.int64)]
    edges = corners[:, 1:].astype(np.float64) - corners[:, :1]
    traced = np.flatnonzero(np.abs(np.cross(edges[:, 0], edges[:, 1])).max(axis=1) > 0)
    traced = traced[first_copies(corners[traced])]
    if len(traced) == 0:  # nothing to hit: one empty leaf
        return TriangleBvh(_empty_nodes(), np.full((1, 9, PACKET), np.nan, np.float32), np.full((1, PACKET), -1, np.int32))
    tree = build_binary(corners[traced].min(axis=1), corners[traced].max(axis=1), max_leaf=2 * PACKET, packet=PACKET)
    leaves = np.flatnonzero(tree.left < 0)
    leaf_count = tree.count[leaves]
    leaf_packets = (leaf_count + PACKET - 1) // PACKET
    first_packet = np.cumsum(leaf_packets) - leaf_packets
    refs = np.zeros(len(tree.left), np.int32)
    refs[leaves] = leaf_ref(first_packet, leaf_packets)
    # Lane of each triangle: its rank within its leaf, packet by packet.
    rank = np.arange(leaf_count.sum()) - np.repeat(np.cumsum(leaf_count) - leaf_count, leaf_count)
    packet = np.repeat(first_packet, leaf_count) + rank // PACKET
    triangle = traced[tree.order[np.repeat(tree.first[leaves], leaf_count) + rank]]
    packets = np.full((int(leaf_packets.sum()), 9, PACKET), np.nan, np.float32)  # NaN: empty lanes (see TriangleBvh)
    packet_triangle = np.full((len(packets), PACKET), -1, np.int32)
    packets[packet, :, rank % PACKET] = corners[triangle].reshape(-1, 9)
    packet_triangle[packet, rank % PACKET] = triangle
    return TriangleBvh(collapse(tree, refs), packets, packet_triangle)


def _empty_nodes() -> np.ndarray:
    """A root with one leaf of one packet (whose lanes are all empty)."""
    nodes = np.zeros((1, NODE_FLOATS), np.float32)
    ints = nodes.view(np.int32)
    ints[0, CHILD_OFFSET] = leaf_ref(0, 1)
    ints[0, COUNT_OFFSET] = 1
    return nodes


def build_instance_bvh(lower: np.ndarray, upper: np.ndarray, max_leaf: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Wide BVH over instance bounds: (nodes, instance order); leaves address runs of that order."""
    tree = build_binary(lower, upper, max_leaf=max_leaf)
    leaves = tree.left < 0
    refs = np.zeros(len(tree.left), np.int32)
    refs[leaves] = leaf_ref(tree.first[leaves], tree.count[leaves])
    return collapse(tree, refs), tree.order


@dataclass(frozen=True)
class TraceArrays:
    """Host arrays of a whole traceable scene (the fields of ``kernels.traversal.TraceScene``)."""

    nodes: np.ndarray
    packets: np.ndarray
    packet_triangle: np.ndarray
    instance_to_object: np.ndarray
    """(I, 3, 4) float32."""
    instance_to_world: np.ndarray
    instance_root: np.ndarray
    instance_face: np.ndarray
    instance_mirrored: np.ndarray
    top_instances: np.ndarray
    top_root: int

    def array_names(self) -> list[str]:
        """The fields that are arrays (every one but ``top_root``), as ``TraceScene`` names them."""
        return [f.name for f in fields(self) if f.name != "top_root"]

    @property
    def nbytes(self) -> int:
        return sum(getattr(self, name).nbytes for name in self.array_names())


def single_level(bvh: TriangleBvh) -> TraceArrays:
    """A scene of one triangle tree in world space (lane triangles are scene triangles)."""
    identity = np.eye(3, 4, dtype=np.float32)[None]
    zero = np.zeros(1, np.int32)
    return TraceArrays(bvh.nodes, bvh.packets, bvh.packet_triangle, identity, identity, zero, zero, zero, zero, -1)


def two_level(bottoms: list[TriangleBvh], instance_bottom: np.ndarray, to_world: np.ndarray,
              instance_face: np.ndarray, instance_mirrored: np.ndarray) -> TraceArrays:
    """Instances of bottom-level trees under a top-level tree of their world bounds.

    instance_bottom (I,) indexes ``bottoms``; to_world (I, 3, 4) maps a bottom tree's space to the world
    (x_world = M[:, :3] x + M[:, 3]); instance_face (I,) is added to lane triangles to give scene triangles.
    """
    node_offsets = np.cumsum([0] + [len(b.nodes) for b in bottoms])
    packet_offsets = np.cumsum([0] + [len(b.packets) for b in bottoms])
    nodes = [_offset_refs(b.nodes, int(n), int(p)) for b, n, p in zip(bottoms, node_offsets, packet_offsets)]
    to_world = np.asarray(to_world, np.float64).reshape(-1, 3, 4)
    lower, upper = _instance_bounds([b.nodes[0] for b in bottoms], instance_bottom, to_world)
    top_nodes, order = build_instance_bvh(lower, upper)
    nodes.append(_offset_refs(top_nodes, int(node_offsets[-1]), 0))
    square = np.zeros((len(to_world), 4, 4))
    square[:, :3], square[:, 3, 3] = to_world, 1.0
    to_object = np.linalg.inv(square)[:, :3]
    return TraceArrays(
        np.concatenate(nodes), np.concatenate([b.packets for b in bottoms]),
        np.concatenate([b.packet_triangle for b in bottoms]), to_object.astype(np.float32),
        to_world.astype(np.float32), node_offsets[:-1][instance_bottom].astype(np.int32),
        np.asarray(instance_face, np.int32), np.asarray(instance_mirrored, np.int32), order.astype(np.int32),
        int(node_offsets[-1]))


def _offset_refs(nodes: np.ndarray, node_offset: int, item_offset: int) -> np.ndarray:
    """Nodes with inner children moved by node_offset and leaf items by item_offset."""
    nodes = nodes.copy()
    ints = nodes.view(np.int32)
    child = ints[:, CHILD_OFFSET:CHILD_OFFSET + WIDTH].astype(np.int64)
    valid = np.arange(WIDTH)[None] < ints[:, COUNT_OFFSET:COUNT_OFFSET + 1]
    code = -1 - child
    moved = np.where(child >= 0, child + node_offset,
                     -1 - ((((code >> LEAF_COUNT_BITS) + item_offset) << LEAF_COUNT_BITS) | (code & MAX_LEAF_ITEMS)))
    ints[:, CHILD_OFFSET:CHILD_OFFSET + WIDTH] = np.where(valid, moved, 0)
    return nodes


def _instance_bounds(roots: list[np.ndarray], instance_bottom: np.ndarray, to_world: np.ndarray):
    """World boxes of instances: each bottom tree's root box (union of its children) through the transform."""
    boxes = []
    for root in roots:
        count = root.view(np.int32)[COUNT_OFFSET]
        lo = np.array([root[a * WIDTH:a * WIDTH + count].min() for a in range(3)])
        hi = np.array([root[(3 + a) * WIDTH:(3 + a) * WIDTH + count].max() for a in range(3)])
        boxes.append((lo, hi))
    lo = np.array([b[0] for b in boxes])[instance_bottom]
    hi = np.array([b[1] for b in boxes])[instance_bottom]
    center, half = (lo + hi) / 2, (hi - lo) / 2
    world_center = np.einsum("ijk,ik->ij", to_world[:, :, :3], center) + to_world[:, :, 3]
    world_half = np.einsum("ijk,ik->ij", np.abs(to_world[:, :, :3]), half)
    pad = 1e-6 * np.abs(world_center).max(axis=1, keepdims=True) + 1e-30  # float32 rounding of the transforms
    return world_center - world_half - pad, world_center + world_half + pad
