"""Delaunay tetrahedralization of probe positions, point location by walking, barycentric interpolation.

Pure numpy + scipy (no Warp, no pxr). The light-probe interpolation of
Cupisz ("Light probe interpolation using tetrahedral tessellations", GDC
2012) as described by Sukys (Chalmers 2014, section 3.2.1):

- ``tetrahedralize``: Delaunay tetrahedra of the probes (scipy.spatial /
  Qhull) with the neighbour across the face opposite each vertex. Duplicate
  points are dropped (the first of each set is kept, tetrahedra index the
  original array); fewer than four distinct points or points that span less
  than 3D (coplanar, collinear) raise ``DegenerateProbesError`` naming the
  problem. Cospherical sets (cube corners) make Qhull's default output
  contain zero-volume slivers; those inputs are joggled (a fixed-seed
  perturbation of 1e-6 diagonals, what Qhull's 'QJ' does) and retried; only
  the tetrahedra that are flat in the exact positions use the joggled
  geometry for their barycentrics.
- ``locate``: the barycentric walk. From a start tetrahedron, compute the
  query's barycentric coordinates; while one is negative, step into the
  neighbour across the face opposite the most negative one. Tetrahedra already
  visited by a query end its walk (the paper's loop guard for points on shared
  faces); a walk that leaves the hull stops at the boundary tetrahedron with
  ``inside = False``. The walk is vectorized over queries.
- ``interpolate``: values at the four vertices blended by the barycentric
  weights; outside the hull the weights are clamped to >= 0 and renormalized
  on the boundary tetrahedron the walk stopped in.

Blocked edges (light leaks, see ``light_probes``): ``tet_blocked`` holds a
6-bit mask per tetrahedron, bit ``e`` set when the edge ``TET_EDGES[e]`` is
blocked by geometry. ``leak_weights`` applies the rule: the unblocked edges
split the four vertices into sides; the side with the largest total weight
is the query's, the other sides get weight 0 (and, within the side, a vertex
cut from the side's dominant vertex by a blocked edge), the rest are
renormalized.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, cKDTree

TET_EDGES = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
"""Local vertex pairs of a tetrahedron's six edges; bit e of a blocked-edge mask is edge e."""

SLIVER_VOLUME_RELATIVE = 1e-10
"""A tetrahedron whose volume is below this fraction of (bounding-box diagonal)^3 is a sliver
(Qhull's triangulated output of cospherical points); far below any tetrahedron of probes spaced
more than 1e-3 diagonals apart (volume ~ 1e-9 d^3 / 6), far above float64 rounding."""

JOGGLE_RELATIVE = 1e-6
"""Joggle of cospherical input as a fraction of the diagonal: far above Qhull's precision
(~1e-13 relative), far below any probe spacing."""

JOGGLE_SEED = 20140613
"""Fixed seed of the joggle, so a tetrahedralization is reproducible."""

DUPLICATE_RELATIVE = 1e-9
"""Points closer than this fraction of the bounding-box diagonal count as duplicates."""

BARY_TOLERANCE = 1e-9
"""A barycentric coordinate above -tolerance counts as inside (points on a shared face)."""


class DegenerateProbesError(ValueError):
    """The probe positions cannot be tetrahedralized (too few, coplanar, collinear, non-finite)."""


@dataclass(frozen=True)
class Tetrahedralization:
    """Delaunay tetrahedra over a point set."""

    points: np.ndarray
    """(P, 3) float64 the input points (duplicates included, never referenced)."""
    tet_vertices: np.ndarray
    """(T, 4) int32 point indices per tetrahedron, positively oriented."""
    tet_neighbors: np.ndarray
    """(T, 4) int32 tetrahedron across the face opposite vertex k; -1 on the hull."""
    tet_inverse: np.ndarray
    """(T, 3, 3) float64 maps (p - v0) to barycentrics (b1, b2, b3); b0 = 1 - b1 - b2 - b3."""
    tet_offset: np.ndarray | None = None
    """(T, 3) float64 subtracted from (p - v0) before tet_inverse: non-zero only for tetrahedra
    that are flat in the exact positions and use the joggled ones."""
    joggled: bool = False
    """True when the input was cospherical and had to be joggled."""
    tet_flat: np.ndarray | None = None
    """(T,) bool: zero-volume tetrahedra (their barycentrics use joggled positions)."""

    @property
    def num_tets(self) -> int:
        return len(self.tet_vertices)


def tetrahedralize(points: np.ndarray) -> Tetrahedralization:
    """Delaunay tetrahedralization of (P, 3) points; raises DegenerateProbesError on degenerate input."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if not np.isfinite(points).all():
        raise DegenerateProbesError("probe positions contain NaN or inf")
    keep = unique_points(points)
    if len(keep) < 4:
        raise DegenerateProbesError(f"{len(keep)} distinct probe positions; a tetrahedralization needs at least 4")
    unique = points[keep]
    centered = unique - unique.mean(axis=0)
    scale = float(np.abs(centered).max())
    singular = np.linalg.svd(centered / scale, compute_uv=False)
    if singular[2] <= 1e-9 * singular[0]:
        span = "coplanar" if singular[1] > 1e-9 * singular[0] else "collinear"
        raise DegenerateProbesError(
            f"the {len(keep)} distinct probe positions are {span} (they span less than 3D); "
            "a tetrahedralization needs 4 points that are not in one plane")
    diagonal = float(np.linalg.norm(unique.max(axis=0) - unique.min(axis=0)))
    sliver = SLIVER_VOLUME_RELATIVE * diagonal ** 3
    geometry = unique
    delaunay = Delaunay(unique, qhull_options="Qbb Qc Qz Q12 Qt")
    joggled = bool((np.abs(_volumes(unique, delaunay.simplices)) < sliver).any())
    if joggled:
        # Cospherical input: Qhull's triangulated output has flat tetrahedra. Joggle the points
        # (fixed seed, JOGGLE_RELATIVE of the diagonal) so every tetrahedron has a volume; flat
        # ones keep the joggled geometry for walking, all others the exact positions.
        geometry = joggle(unique)
        delaunay = Delaunay(geometry, qhull_options="Qbb Qc Qz Q12 Qt")
    tets = delaunay.simplices.astype(np.int64)
    neighbors = delaunay.neighbors.astype(np.int64)
    # Orient positively in the geometry Qhull saw (swap two vertices and their opposite neighbours).
    negative = _volumes(geometry, tets) < 0
    tets[negative] = tets[negative][:, [1, 0, 2, 3]]
    neighbors[negative] = neighbors[negative][:, [1, 0, 2, 3]]
    inverse, tet_offset, flat = _inverse_with_joggle(unique, tets, geometry)
    return Tetrahedralization(points=points, tet_vertices=keep[tets].astype(np.int32),
                              tet_neighbors=neighbors.astype(np.int32), tet_inverse=inverse,
                              tet_offset=tet_offset, joggled=joggled, tet_flat=flat)


def from_arrays(points: np.ndarray, tet_vertices: np.ndarray, tet_neighbors: np.ndarray) -> Tetrahedralization:
    """Rebuild a Tetrahedralization from stored arrays (e.g. read back from a LightProbeCloud)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    tets = np.asarray(tet_vertices, np.int64).reshape(-1, 4)
    neighbors = np.asarray(tet_neighbors, np.int64).reshape(-1, 4)
    if len(tets) and (tets.min() < 0 or tets.max() >= len(points)):
        raise ValueError(f"tetrahedra index probes outside [0, {len(points)})")
    if neighbors.shape != tets.shape or (len(neighbors) and (neighbors.min() < -1 or neighbors.max() >= len(tets))):
        raise ValueError("tetNeighbors must hold 4 entries per tetrahedron, each -1 or a tetrahedron index")
    inverse, offset, flat = _inverse_with_joggle(points, tets, joggle(points))
    return Tetrahedralization(points=points, tet_vertices=tets.astype(np.int32),
                              tet_neighbors=neighbors.astype(np.int32), tet_inverse=inverse, tet_offset=offset,
                              tet_flat=flat)


def joggle(points: np.ndarray) -> np.ndarray:
    """Points moved by a fixed-seed uniform perturbation of JOGGLE_RELATIVE diagonals."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) == 0:
        return points
    diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    rng = np.random.default_rng(JOGGLE_SEED)
    return points + rng.uniform(-1.0, 1.0, points.shape) * (JOGGLE_RELATIVE * diagonal)


def _inverse_with_joggle(points: np.ndarray, tets: np.ndarray, joggled: np.ndarray):
    """Barycentric matrices from the exact points; flat tetrahedra take the joggled geometry
    (and an offset so barycentrics are still measured from the exact v0)."""
    diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))) if len(points) else 0.0
    flat = np.abs(_volumes(points, tets)) < SLIVER_VOLUME_RELATIVE * diagonal ** 3
    inverse = _inverse_matrices(points, tets)
    offset = np.zeros((len(tets), 3))
    if flat.any():
        inverse[flat] = _inverse_matrices(joggled, tets[flat])
        offset[flat] = joggled[tets[flat, 0]] - points[tets[flat, 0]]
    return inverse, offset, flat


def unique_points(points: np.ndarray) -> np.ndarray:
    """(U,) int64 index of the first point of each group of (near-)duplicates, in input order."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0, np.int64)
    diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    cell = max(DUPLICATE_RELATIVE * diagonal, 1e-300)
    keys = np.round((points - points.min(axis=0)) / cell).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return np.sort(first)


def _volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    v = points[tets]
    return np.einsum("ij,ij->i", np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), v[:, 3] - v[:, 0]) / 6.0


def _inverse_matrices(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    v = points[tets]
    edges = np.stack([v[:, 1] - v[:, 0], v[:, 2] - v[:, 0], v[:, 3] - v[:, 0]], axis=2)  # columns
    det = np.linalg.det(edges)
    safe = np.abs(det) > 1e-300
    inverse = np.zeros_like(edges)
    inverse[safe] = np.linalg.inv(edges[safe])
    return inverse


def barycentric(tetra: Tetrahedralization, tets: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """(N, 4) barycentric coordinates of queries (N, 3) in tetrahedra tets (N,)."""
    queries = np.asarray(queries, np.float64).reshape(-1, 3)
    v0 = tetra.points[tetra.tet_vertices[tets, 0]]
    offset = tetra.tet_offset[tets] if tetra.tet_offset is not None else 0.0
    b = np.einsum("nij,nj->ni", tetra.tet_inverse[tets], queries - v0 - offset)
    return np.concatenate([1.0 - b.sum(axis=1, keepdims=True), b], axis=1)


def locate(tetra: Tetrahedralization, queries: np.ndarray, start: np.ndarray | int | None = None,
           *, max_steps: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Barycentric walk to the tetrahedron containing each query.

    Parameters
    ----------
    tetra : Tetrahedralization
    queries : (N, 3)
    start : start tetrahedron per query (or one for all); default: the tetrahedron whose
        centroid is nearest to each query (a KD-tree), so walks are a few steps long.

    Returns
    -------
    tet : (N,) int64 tetrahedron where each walk ended
    bary : (N, 4) float64 barycentrics of the query in it
    inside : (N,) bool, False where the query is outside the hull (the walk hit the boundary)
    """
    queries = np.asarray(queries, np.float64).reshape(-1, 3)
    n = len(queries)
    if start is None:
        centroids = tetra.points[tetra.tet_vertices].mean(axis=1)
        start = cKDTree(centroids).query(queries)[1] if n else 0
    current = np.broadcast_to(np.asarray(start, np.int64), (n,)).copy()
    max_steps = max_steps or tetra.num_tets + 1
    done = np.zeros(n, bool)
    inside = np.zeros(n, bool)
    visited: list[np.ndarray] = []
    active = np.arange(n)
    for _ in range(max_steps):
        if len(active) == 0:
            break
        bary = barycentric(tetra, current[active], queries[active])
        worst = np.argmin(bary, axis=1)
        found = bary[np.arange(len(active)), worst] >= -BARY_TOLERANCE
        nxt = tetra.tet_neighbors[current[active], worst].astype(np.int64)
        boundary = ~found & (nxt < 0)
        # Loop guard: stepping back into a tetrahedron this query already visited ends the walk.
        seen = np.zeros(len(active), bool)
        for previous in visited:
            seen |= previous[active] == nxt
        looped = ~found & ~boundary & seen
        inside[active[found | looped]] = True
        done[active[found | boundary | looped]] = True
        history = np.full(n, -1, np.int64)
        history[active] = current[active]
        visited.append(history)
        if len(visited) > 8:  # cycles in a Delaunay walk are short; keep the guard cheap
            visited.pop(0)
        move = ~(found | boundary | looped)
        current[active[move]] = nxt[move]
        active = active[move]
    if len(active):  # max_steps reached: fall back to an exhaustive search
        tet, _ = brute_force_locate(tetra, queries[active])
        ok = tet >= 0
        current[active[ok]] = tet[ok]
        inside[active[ok]] = True
    flat = tetra.tet_flat
    if flat is not None and flat[current].any():
        # A walk may stop in a zero-volume tetrahedron (cospherical or coplanar probes): its point lies
        # on a face of a proper neighbour; take the proper tetrahedron within 3 steps that contains it best.
        rows = np.flatnonzero(flat[current])
        best = _nearest_proper(tetra, current[rows], queries[rows])
        current[rows] = np.where(best >= 0, best, current[rows])
    bary = barycentric(tetra, current, queries)
    return current, bary, inside


def _nearest_proper(tetra: Tetrahedralization, start: np.ndarray, queries: np.ndarray, depth: int = 3) -> np.ndarray:
    """For each query, the non-flat tetrahedron within ``depth`` neighbour steps of start with the
    largest smallest barycentric (-1 if none)."""
    best = np.full(len(start), -1, np.int64)
    score = np.full(len(start), -np.inf)
    frontier = start[:, None]
    for _ in range(depth):
        frontier = tetra.tet_neighbors[frontier].reshape(len(start), -1).astype(np.int64)
        for column in range(frontier.shape[1]):
            tet = frontier[:, column]
            ok = (tet >= 0)
            ok[ok] &= ~tetra.tet_flat[tet[ok]]
            if not ok.any():
                continue
            value = np.full(len(start), -np.inf)
            value[ok] = barycentric(tetra, tet[ok], queries[ok]).min(axis=1)
            better = value > score
            best[better], score[better] = tet[better], value[better]
        frontier = np.where(frontier >= 0, frontier, start[:, None])
    return best


def brute_force_locate(tetra: Tetrahedralization, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N,) tetrahedron containing each query by testing all of them (-1 outside), and barycentrics."""
    queries = np.asarray(queries, np.float64).reshape(-1, 3)
    tets = np.full(len(queries), -1, np.int64)
    bary = np.zeros((len(queries), 4))
    for t in range(tetra.num_tets):
        b = barycentric(tetra, np.full(len(queries), t), queries)
        hit = (tets < 0) & (b.min(axis=1) >= -BARY_TOLERANCE)
        tets[hit] = t
        bary[hit] = b[hit]
    return tets, bary


def clamp_weights(bary: np.ndarray) -> np.ndarray:
    """Barycentrics clamped to >= 0 and renormalized (outside the hull: the nearest face's blend)."""
    w = np.maximum(np.asarray(bary, np.float64), 0.0)
    total = w.sum(axis=1, keepdims=True)
    return np.where(total > 0, w / np.where(total > 0, total, 1.0), 0.25)


def _component_table() -> np.ndarray:
    """(64, 4) int8: for each blocked-edge mask, a component label per vertex of the graph of the
    tetrahedron's *unblocked* edges (labels are the smallest vertex index in the component)."""
    table = np.zeros((64, 4), np.int8)
    for mask in range(64):
        label = list(range(4))
        changed = True
        while changed:
            changed = False
            for e, (a, b) in enumerate(TET_EDGES):
                if not (mask >> e) & 1 and label[a] != label[b]:
                    label[a] = label[b] = min(label[a], label[b])
                    changed = True
        table[mask] = label
    return table


COMPONENTS = _component_table()


def leak_weights(weights: np.ndarray, blocked: np.ndarray) -> np.ndarray:
    """Weights restricted to the query's side of the blockers, renormalized.

    weights : (N, 4) non-negative, summing to 1; blocked : (N,) 6-bit masks over TET_EDGES.
    1. The tetrahedron's vertices split into components joined by unblocked edges; the component
       with the largest total weight is the query's side, the others get weight 0.
    2. Inside that side, a vertex joined to the side's dominant (largest-weight) vertex by a blocked
       edge also gets 0 (a blocker between them that the other edges go around).
    The dominant vertex is never dropped, so the result always sums to 1.
    """
    weights = np.asarray(weights, np.float64)
    blocked = np.asarray(blocked, np.int64) & 63
    labels = COMPONENTS[blocked].astype(np.int64)  # (N, 4)
    same = labels[:, :, None] == labels[:, None, :]
    side_weight = np.einsum("nuv,nu->nv", same, weights)  # total weight of each vertex's component
    heaviest = np.argmax(side_weight + 1e-12 * weights, axis=1)
    keep = labels == labels[np.arange(len(labels)), heaviest][:, None]
    w = np.where(keep, weights, 0.0)
    dominant = np.argmax(w, axis=1)
    for e, (a, b) in enumerate(TET_EDGES):
        cut = (blocked >> e) & 1 == 1
        keep[cut & (dominant == a), b] = False
        keep[cut & (dominant == b), a] = False
    w = np.where(keep, weights, 0.0)
    return w / w.sum(axis=1, keepdims=True)


def edge_list(tet_vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique undirected edges (E, 2) int64 (a < b) and (T, 6) index of each tetrahedron edge into them."""
    tets = np.asarray(tet_vertices, np.int64).reshape(-1, 4)
    pairs = np.stack([tets[:, [a, b]] for a, b in TET_EDGES], axis=1)  # (T, 6, 2)
    pairs = np.sort(pairs, axis=2)
    edges, inverse = np.unique(pairs.reshape(-1, 2), axis=0, return_inverse=True)
    return edges, inverse.reshape(-1, 6)


def edge_masks(tet_edge_index: np.ndarray, edge_blocked: np.ndarray) -> np.ndarray:
    """(T,) uint8 6-bit masks from per-edge flags (E,) bool and the (T, 6) edge index."""
    bits = np.asarray(edge_blocked, bool)[tet_edge_index].astype(np.uint8)
    return (bits << np.arange(6, dtype=np.uint8)).sum(axis=1).astype(np.uint8)
