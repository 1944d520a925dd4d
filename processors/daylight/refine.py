"""Conforming adaptive refinement of triangle meshes (red / longest-edge green), pure numpy.

One refinement pass takes a conforming triangle mesh and a set of marked
triangles and returns a conforming mesh in which every marked triangle is
split into four triangles of a quarter of its area (all three edges
bisected). To keep the mesh conforming (no T-junctions: every split edge is
split on both of its sides), a closure propagates over shared edges until a
triangle with any split edge also has its longest edge split. Each split
triangle is then bisected at the midpoint of its longest edge, and each half
again at its other split edge (Rivara's longest-edge 2-, 3- and 4-triangle
patterns, Rivara 1984, doi:10.1002/nme.1620200412; angles stay bounded and
the propagation stays local along longest-edge paths).

Topology is read from a *welded* vertex id per point (points at the same
position on the same prim share it), so meshes authored with split vertices
along seams (faceted normals, UV seams) are refined crack-free too: both
sides get coincident midpoints although their vertex ids stay apart. A mesh
that was watertight (every welded edge shared by two triangles) stays
watertight. Winding is preserved.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Edge k of a triangle joins corners k and (k + 1) % 3; the opposite corner is (k + 2) % 3.
_NEXT = np.array([1, 2, 0])
_OPPOSITE = np.array([2, 0, 1])


@dataclass(frozen=True)
class Refinement:
    """The result of one refinement pass."""

    points: np.ndarray
    """(P', 3) float64: the input points followed by the new edge midpoints."""
    weld: np.ndarray
    """(P',) int64 welded vertex ids (input ids kept; coincident midpoints share one)."""
    triangles: np.ndarray
    """(T', 3) int64 triangles."""
    parent: np.ndarray
    """(T',) int64 index of the input triangle each output triangle lies in."""
    changed: np.ndarray
    """(T',) bool: the triangle is new (its parent was split)."""
    halvings: np.ndarray
    """(T',) int64 area halvings from the parent: 0 unchanged, 1 (half) or 2 (quarter)."""
    corner_weights: np.ndarray
    """(T', 3, 3) float64: corner i of output triangle t is sum_k corner_weights[t, i, k] * corner k of
    its parent (identity for unchanged triangles, halves at edge midpoints). Composing them over passes
    gives every corner's barycentric coordinates in the input triangle, which is how authored vertex
    and faceVarying data is interpolated onto the refined mesh."""


def weld_points(points: np.ndarray, groups: np.ndarray | None = None) -> np.ndarray:
    """(P,) int64 welded ids: points with exactly equal coordinates (and equal group) share an id."""
    points = np.ascontiguousarray(points)
    keys = points.reshape(len(points), -1)
    if groups is not None:
        keys = np.column_stack([keys.astype(np.float64), np.asarray(groups, np.float64)])
    if len(keys) == 0:
        return np.zeros(0, np.int64)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    return inverse.reshape(-1).astype(np.int64)


def triangle_edges(triangles: np.ndarray, weld: np.ndarray) -> tuple[np.ndarray, int]:
    """((T, 3) int64 edge id per triangle edge, number of edges), edges keyed by welded endpoints."""
    w = weld[triangles]
    a, b = w, w[:, _NEXT]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    keys = lo * (int(weld.max(initial=0)) + 1) + hi
    unique, inverse = np.unique(keys.ravel(), return_inverse=True)
    return inverse.reshape(-1, 3).astype(np.int64), len(unique)


def refine(points: np.ndarray, triangles: np.ndarray, marked: np.ndarray, *,
           weld: np.ndarray | None = None) -> Refinement:
    """Split the marked triangles into four and close the mesh conformingly.

    Parameters
    ----------
    points : (P, 3) float64
    triangles : (T, 3) int
    marked : (T,) bool
    weld : (P,) int, optional
        Welded vertex ids (default: each point its own id, i.e. topology from indices only).
    """
    points = np.asarray(points, np.float64)
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    marked = np.asarray(marked, bool)
    weld = np.arange(len(points), dtype=np.int64) if weld is None else np.asarray(weld, np.int64)
    n_tri = len(triangles)
    if n_tri == 0 or not marked.any():
        return Refinement(points, weld, triangles, np.arange(n_tri), np.zeros(n_tri, bool), np.zeros(n_tri, np.int64),
                          np.broadcast_to(np.eye(3), (n_tri, 3, 3)).copy())

    tri_edge, n_edges = triangle_edges(triangles, weld)
    corners = points[triangles]
    lengths = np.linalg.norm(corners[:, _NEXT] - corners, axis=2)  # (T, 3) length of edge k
    # Longest edge; ties broken by edge id so that both sides of an edge agree.
    rank = lengths + (tri_edge / max(n_edges, 1)) * 1e-12 * (lengths.max(initial=0.0) + 1e-300)
    longest = np.argmax(rank, axis=1)
    rows = np.arange(n_tri)

    split = np.zeros(n_edges, bool)
    split[tri_edge[marked].ravel()] = True
    # Closure: a triangle with any split edge has its longest edge split (propagates along the
    # longest-edge propagation path, so it stays local).
    while True:
        edge_split = split[tri_edge]
        need = edge_split.any(axis=1) & ~edge_split[rows, longest]
        if not need.any():
            break
        split[tri_edge[rows[need], longest[need]]] = True

    edge_split = split[tri_edge]
    count = edge_split.sum(axis=1)

    # Midpoints, one per (actual vertex pair) on a split edge; welded id per split (welded) edge.
    a_idx, b_idx = triangles, triangles[:, _NEXT]
    pair_lo, pair_hi = np.minimum(a_idx, b_idx), np.maximum(a_idx, b_idx)
    sel = edge_split
    pair_keys = pair_lo[sel] * len(points) + pair_hi[sel]
    unique_pairs, pair_inverse = np.unique(pair_keys, return_inverse=True)
    mid_lo = unique_pairs // len(points)
    mid_hi = unique_pairs % len(points)
    mid_points = 0.5 * (points[mid_lo] + points[mid_hi])
    mid_edge = np.zeros(len(unique_pairs), np.int64)
    mid_edge[pair_inverse] = tri_edge[sel]
    mid_weld = int(weld.max(initial=-1)) + 1 + mid_edge
    midpoint = np.full((n_tri, 3), -1, np.int64)
    midpoint[sel] = len(points) + pair_inverse

    new_points = np.concatenate([points, mid_points])
    new_weld = np.concatenate([weld, mid_weld])

    keep = count == 0
    parts = [triangles[keep]]
    parents = [rows[keep]]
    halvings = [np.zeros(int(keep.sum()), np.int64)]
    weights = [np.broadcast_to(np.eye(3), (int(keep.sum()), 3, 3))]

    # Split triangles: bisect the longest edge A-B (midpoint M, opposite corner C), then bisect
    # the half (A, M, C) at the midpoint N of C-A and the half (M, B, C) at the midpoint Q of B-C
    # when those edges are split too (Rivara's 2-, 3- and 4-triangle longest-edge patterns).
    cut = rows[count > 0]
    k = longest[cut]
    t = triangles[cut]
    i = np.arange(len(cut))
    a, b, c = t[i, k], t[i, _NEXT[k]], t[i, _OPPOSITE[k]]
    m = midpoint[cut, k]
    n = midpoint[cut, _OPPOSITE[k]]
    q = midpoint[cut, _NEXT[k]]
    # The same six vertices as weights over the parent's corners (rows of the identity, and midpoints).
    unit = np.eye(3)
    wa, wb, wc = unit[k], unit[_NEXT[k]], unit[_OPPOSITE[k]]
    wm, wn, wq = 0.5 * (wa + wb), 0.5 * (wc + wa), 0.5 * (wb + wc)
    for half_split, whole, pieces in (
        (n >= 0, ((a, wa), (m, wm), (c, wc)), (((a, wa), (m, wm), (n, wn)), ((m, wm), (c, wc), (n, wn)))),
        (q >= 0, ((m, wm), (b, wb), (c, wc)), (((m, wm), (b, wb), (q, wq)), ((m, wm), (q, wq), (c, wc)))),
    ):
        one = ~half_split
        for mask, corners_of, halving in [(one, whole, 1)] + [(half_split, piece, 2) for piece in pieces]:
            parts.append(np.stack([v[mask] for v, _ in corners_of], 1))
            weights.append(np.stack([w[mask] for _, w in corners_of], 1))
            parents.append(cut[mask])
            halvings.append(np.full(int(mask.sum()), halving, np.int64))

    new_triangles = np.concatenate(parts)
    parent = np.concatenate(parents)
    halv = np.concatenate(halvings)
    return Refinement(new_points, new_weld, new_triangles, parent, halv > 0, halv, np.concatenate(weights))


def boundary_edges(triangles: np.ndarray, weld: np.ndarray) -> np.ndarray:
    """(B, 2) welded endpoints of edges used by exactly one triangle (empty for a watertight mesh)."""
    w = np.asarray(weld)[np.asarray(triangles)]
    a, b = w.ravel(), w[:, _NEXT].ravel()
    keys = np.stack([np.minimum(a, b), np.maximum(a, b)], 1)
    unique, counts = np.unique(keys, axis=0, return_counts=True)
    return unique[counts == 1]


def is_watertight(triangles: np.ndarray, weld: np.ndarray) -> bool:
    """Every welded edge is used exactly twice, once in each direction (closed and consistently wound)."""
    w = np.asarray(weld)[np.asarray(triangles)]
    directed = np.stack([w.ravel(), w[:, _NEXT].ravel()], 1)
    forward = {tuple(e) for e in directed.tolist()}
    if len(forward) != len(directed):
        return False
    return all((b, a) in forward for a, b in forward)
