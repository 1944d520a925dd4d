"""Per-vertex irradiance read back at points on the baked surfaces (numpy; ``usdbake.irradiance_at``).

A query point takes the closest point on the triangles (Ericson, "Real-Time Collision Detection", 2005,
section 5.1.5) and the barycentric blend of that triangle's vertex values: exactly a vertex's value at
the vertex, linear along each triangle. Candidates come from a kd-tree of triangle centroids: the
``SHORTLIST`` nearest give an upper bound d on the distance, and every triangle whose centroid lies within
d + its circumradius (about the centroid) is tested, so the closest triangle is never missed however
large it is. Among triangles equally near (faces meeting at an unwelded corner or seam, coincident
surfaces), those whose fronts face the query normal most are read, and the distinct points they blend
averaged: at an unwelded seam, where coincident points each hold their own estimate, their mean.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ...core.errors import UsageError

SHORTLIST = 8
"""Nearest centroids whose exact distances bound the search."""
ON_SURFACE_RELATIVE = 1e-3
"""Default ``max_distance``: this fraction of the surfaces' bounding-box diagonal (1.7 cm in a 10 m room),
well above float32 world coordinates (~1e-7 relative) and below a gap between objects worth telling."""
TIE_RELATIVE = 1e-6
"""Triangles within this fraction of the diagonal of the nearest count as equally near (float32 points
put coincident surfaces ~1e-7 relative apart)."""
FACING_TIE = 1e-6
"""Equally near triangles whose normals face the query normal within this (cosine) all count, and their values
are averaged: coplanar triangles from float32 points agree to ~1e-7."""
BARY_ZERO = 1e-9
"""A barycentric below this is a corner the point does not read (a point on an edge or at a vertex)."""
RADIUS_CLASSES = 8
"""Triangles are grouped by circumradius (factors of 2 apart) so a few huge ones do not widen the search
around every point."""


def closest_on_triangles(points: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """(M,) distances and (M, 3) barycentrics of the closest point of triangle (a, b, c) to each point
    (all (M, 3) float64; Ericson 5.1.5). Degenerate triangles whose closest point is undefined get
    distance inf."""
    ab, ac = b - a, c - a
    dot = lambda u, v: np.einsum("ij,ij->i", u, v)  # noqa: E731
    ap, bp, cp = points - a, points - b, points - c
    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(invalid="ignore", divide="ignore"):
        total = va + vb + vc
        v, w = vb / total, vc / total  # inside the face
        bary = np.stack([1.0 - v - w, v, w], axis=1)
        # Voronoi regions of the edges and corners, lowest priority first so Ericson's order wins.
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        regions = [
            ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), np.stack([0 * t, 1 - t, t], axis=1)),  # edge bc
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), _edge(d2 / (d2 - d6), 0, 2)),  # edge ac
            ((d6 >= 0) & (d5 <= d6), np.array([0.0, 0.0, 1.0])),  # corner c
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), _edge(d1 / (d1 - d3), 0, 1)),  # edge ab
            ((d3 >= 0) & (d4 <= d3), np.array([0.0, 1.0, 0.0])),  # corner b
            ((d1 <= 0) & (d2 <= 0), np.array([1.0, 0.0, 0.0])),  # corner a
        ]
        for mask, value in regions:
            bary = np.where(mask[:, None], value, bary)
        closest = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
        distance = np.linalg.norm(points - closest, axis=1)
    return np.where(np.isfinite(distance), distance, np.inf), bary


def _edge(t: np.ndarray, first: int, second: int) -> np.ndarray:
    """(M, 3) barycentrics 1 - t on corner ``first``, t on ``second``."""
    bary = np.zeros((len(t), 3))
    bary[:, first], bary[:, second] = 1.0 - t, t
    return bary


def surface_values_at(points: np.ndarray, normals: np.ndarray, surface_points: np.ndarray, triangles: np.ndarray,
                      point_values: np.ndarray, *, max_distance: float | None = None) -> np.ndarray:
    """(N, C) float64 values at points (N, 3) on the surfaces: the closest point's barycentric blend of
    ``point_values`` (P, C) over ``triangles`` (T, 3) of ``surface_points`` (P, 3) (module docstring).

    max_distance : farthest a point may be from every triangle (default ``ON_SURFACE_RELATIVE`` of the
        surfaces' bounding-box diagonal); UsageError naming the first point beyond it.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    normals = np.asarray(normals, np.float64).reshape(-1, 3)
    corners = np.asarray(surface_points, np.float64)[np.asarray(triangles, np.int64)]
    if len(corners) == 0:
        raise UsageError("the baked surfaces have no triangles")
    diagonal = float(np.linalg.norm(np.ptp(corners.reshape(-1, 3), axis=0)))
    number = isinstance(max_distance, (int, float, np.integer, np.floating)) and not isinstance(max_distance, bool)
    if max_distance is not None and not (number and np.isfinite(max_distance) and max_distance >= 0):
        raise UsageError(f"max_distance={max_distance!r}: expected a distance >= 0 in stage units")
    limit = ON_SURFACE_RELATIVE * diagonal if max_distance is None else float(max_distance)
    if len(points) == 0:
        return np.zeros((0, point_values.shape[1]))
    query, tri = _candidates(points, corners)
    distance, bary = closest_on_triangles(points[query], *corners[tri].transpose(1, 0, 2))
    starts = np.flatnonzero(np.r_[True, query[1:] != query[:-1]])
    nearest = np.minimum.reduceat(distance, starts)
    far = np.flatnonzero(nearest > limit)
    if len(far):
        p = points[far[0]]
        raise UsageError(f"points[{far[0]}] = ({p[0]:.6g}, {p[1]:.6g}, {p[2]:.6g}) is {nearest[far[0]]:.4g} stage "
                         f"units from the nearest baked surface, beyond max_distance={limit:.4g} ({len(far)} such "
                         f"points); radiosity stores irradiance on the surfaces only")
    facing = np.einsum("ij,ij->i", _triangle_normals(corners)[tri], normals[query])
    facing = np.where(distance <= nearest[query] + TIE_RELATIVE * diagonal, facing, -np.inf)
    chosen = np.flatnonzero(facing >= np.maximum.reduceat(facing, starts)[query] - FACING_TIE)
    # Triangles of one surface meeting at the point read the same points: count each set of points once.
    corners_read = np.where(bary[chosen] > BARY_ZERO, np.asarray(triangles, np.int64)[tri[chosen]], -1)
    _, first = np.unique(np.c_[query[chosen], np.sort(corners_read, axis=1)], axis=0, return_index=True)
    chosen = chosen[first]
    values = np.asarray(point_values, np.float64)[np.asarray(triangles, np.int64)[tri[chosen]]]
    blended = np.einsum("nk,nkc->nc", bary[chosen], values)
    total = np.zeros((len(points), blended.shape[1]))
    np.add.at(total, query[chosen], blended)
    return total / np.bincount(query[chosen], minlength=len(points))[:, None]


def _triangle_normals(corners: np.ndarray) -> np.ndarray:
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    return np.where(length > 0, normal / np.where(length > 0, length, 1.0), 0.0)


def _candidates(points: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(query, triangle) index pairs, sorted by query, holding every point's closest triangle."""
    centroids = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centroids[:, None], axis=2).max(axis=1)
    shortlist = np.asarray(cKDTree(centroids).query(points, k=min(SHORTLIST, len(centroids)))[1]).reshape(
        len(points), -1)
    pairs = np.repeat(np.arange(len(points)), shortlist.shape[1])
    bound = closest_on_triangles(points[pairs], *corners[shortlist.ravel()].transpose(1, 0, 2))[0]
    bound = bound.reshape(len(points), -1).min(axis=1)
    bound = np.where(np.isfinite(bound), bound, np.inf)
    top = max(float(radius.max()), 1e-300)
    rank = np.minimum(np.floor(np.log2(top / np.maximum(radius, top * 1e-300))), RADIUS_CLASSES - 1).astype(int)
    queries, triangles = [], []
    for group in np.unique(rank):
        members = np.flatnonzero(rank == group)
        reach = bound + radius[members].max()
        found = cKDTree(centroids[members]).query_ball_point(points, np.where(np.isfinite(reach), reach, np.inf))
        counts = np.fromiter((len(f) for f in found), np.int64, len(found))
        queries.append(np.repeat(np.arange(len(points)), counts))
        triangles.append(members[np.concatenate(found).astype(np.int64)] if counts.sum() else np.zeros(0, np.int64))
    query, tri = np.concatenate(queries), np.concatenate(triangles)
    order = np.argsort(query, kind="stable")
    return query[order], tri[order]
