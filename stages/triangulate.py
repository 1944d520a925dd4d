"""Polygon triangulation: fans for convex faces, ear clipping for concave ones.

Pure numpy (no pxr); lives in stages/ because only extraction needs it.
Ear clipping is written here because the per-face polygons are tiny and the
alternatives (a constrained Delaunay library) would add a dependency for a
dozen lines of code.
"""

from __future__ import annotations

import numpy as np

CONVEX_TOLERANCE = 1e-9
"""Relative slack on the corner test, so collinear corners (quads with a
vertex on an edge) still count as convex."""


def newell_normals(corners: np.ndarray) -> np.ndarray:
    """(F, n, 3) polygon corners -> (F, 3) Newell normals (area-weighted, unnormalized x2)."""
    nxt = np.roll(corners, -1, axis=1)
    return np.cross(corners, nxt).sum(axis=1)


def convex_mask(corners: np.ndarray) -> np.ndarray:
    """(F, n, 3) -> (F,) bool: every corner turns the same way as the polygon normal."""
    normal = newell_normals(corners)
    edge_in = corners - np.roll(corners, 1, axis=1)
    edge_out = np.roll(corners, -1, axis=1) - corners
    turn = np.einsum("fkc,fc->fk", np.cross(edge_in, edge_out), normal)
    scale = (np.linalg.norm(edge_in, axis=2) * np.linalg.norm(edge_out, axis=2)
             * np.linalg.norm(normal, axis=1)[:, None])
    return (turn >= -CONVEX_TOLERANCE * scale).all(axis=1)


def fan(face_indices: np.ndarray) -> np.ndarray:
    """(F, n) vertex indices -> (F * (n - 2), 3) triangles (0, k, k+1), face-major."""
    count, n = face_indices.shape
    k = np.arange(1, n - 1)
    tris = np.stack([np.repeat(face_indices[:, :1], n - 2, axis=1), face_indices[:, k], face_indices[:, k + 1]],
                    axis=2)
    return tris.reshape(-1, 3)


def ear_clip(corners: np.ndarray) -> np.ndarray:
    """Triangulate one simple polygon given as (n, 3) points; returns (n - 2, 3) local corner indices.

    The polygon is projected on the plane of its Newell normal; triangles keep
    the polygon's winding. Degenerate input (all collinear) falls back to a fan.
    """
    n = len(corners)
    normal = newell_normals(corners[None])[0]
    axis = int(np.argmax(np.abs(normal)))
    keep = [(axis + 1) % 3, (axis + 2) % 3]  # cyclic, so (u, v, axis) is right-handed for every axis
    flat = corners[:, keep].astype(np.float64)
    if normal[axis] < 0:  # make the projected polygon counter-clockwise
        flat = flat[:, ::-1]
    remaining = list(range(n))
    triangles = []
    guard = 0
    while len(remaining) > 3 and guard < n * n:
        guard += 1
        m = len(remaining)
        for k in range(m):
            a, b, c = remaining[k - 1], remaining[k], remaining[(k + 1) % m]
            if _cross2(flat[a], flat[b], flat[c]) <= 0:
                continue  # reflex or flat corner: not an ear
            others = [p for p in remaining if p not in (a, b, c)]
            if others and _points_in_triangle(flat[others], flat[a], flat[b], flat[c]).any():
                continue
            triangles.append((a, b, c))
            remaining.pop(k)
            break
        else:
            break  # no ear found (self-intersecting or degenerate): fan the rest
    triangles += [(remaining[0], remaining[k], remaining[k + 1]) for k in range(1, len(remaining) - 1)]
    return np.array(triangles, np.int64).reshape(-1, 3)


def _cross2(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    return float((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))


def _points_in_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    def side(u, v):
        return (v[0] - u[0]) * (p[:, 1] - u[1]) - (v[1] - u[1]) * (p[:, 0] - u[0])

    return (side(a, b) >= 0) & (side(b, c) >= 0) & (side(c, a) >= 0)


def triangulate(points: np.ndarray, counts: np.ndarray, indices: np.ndarray,
                skip_faces: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate a polygon mesh: ((T, 3) int32 point indices, (T,) int32 source face).

    See ``triangulate_corners``; the triangles are ``indices[corners]``.
    """
    corners, tri_face = triangulate_corners(points, counts, indices, skip_faces)
    return np.asarray(indices, np.int64)[corners].astype(np.int32).reshape(-1, 3), tri_face


def triangulate_corners(points: np.ndarray, counts: np.ndarray, indices: np.ndarray,
                        skip_faces: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate a polygon mesh into face-vertex slots.

    Parameters
    ----------
    points : (P, 3) float
    counts : (F,) int faceVertexCounts
    indices : (sum(counts),) int faceVertexIndices
    skip_faces : (F,) bool, optional; faces to leave out (holes, degenerate)

    Returns
    -------
    corners : (T, 3) int32 face-vertex slots (positions in ``indices``) of each triangle's corners,
        winding of the source polygons; faceVarying data of corner k is ``data[corners[:, k]]``
    tri_face : (T,) int32 source face of each triangle
    """
    counts = np.asarray(counts, np.int64)
    indices = np.asarray(indices, np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    keep = counts >= 3
    if skip_faces is not None:
        keep &= ~skip_faces
    tri_parts, face_parts = [], []
    for n in np.unique(counts[keep]):
        faces = np.flatnonzero(keep & (counts == n))
        slots = starts[faces, None] + np.arange(n)
        if n == 3:
            tri_parts.append(slots)
            face_parts.append(faces)
            continue
        convex = convex_mask(points[indices[slots]].astype(np.float64))
        tri_parts.append(fan(slots[convex]))
        face_parts.append(np.repeat(faces[convex], n - 2))
        for face, local in zip(faces[~convex], slots[~convex]):
            tri_parts.append(local[ear_clip(points[indices[local]])])
            face_parts.append(np.full(n - 2, face))
    if not tri_parts:
        return np.zeros((0, 3), np.int32), np.zeros(0, np.int32)
    corners = np.concatenate(tri_parts).astype(np.int32)
    tri_face = np.concatenate(face_parts).astype(np.int32)
    order = np.argsort(tri_face, kind="stable")
    return corners[order], tri_face[order]
