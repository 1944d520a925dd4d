"""Pure-numpy helpers on Scene meshes shared by several processors: normals, receivers, face means."""

from __future__ import annotations

import numpy as np

from ..core.scene import Scene


def vertex_normals(points: np.ndarray, tri_vertices: np.ndarray, tri_normals: np.ndarray,
                   tri_areas: np.ndarray) -> np.ndarray:
    """(P, 3) float32 area-weighted vertex normals; zero where no non-degenerate triangle touches."""
    accum = np.zeros((len(points), 3), np.float64)
    weighted = tri_normals.astype(np.float64) * tri_areas[:, None]
    for corner in range(3):
        np.add.at(accum, tri_vertices[:, corner], weighted)
    length = np.linalg.norm(accum, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        normals = np.where(length > 0, accum / length, 0.0)
    return normals.astype(np.float32)


def receiver_prims(scene: Scene) -> np.ndarray:
    """Indices of prims that receive baked values: writable, not marked bake:skip, with triangles."""
    has_triangles = np.bincount(scene.tri_prim, minlength=len(scene.prim_paths)) > 0
    return np.flatnonzero(scene.prim_writable & ~scene.prim_skip & has_triangles)


def face_means(values: np.ndarray, weights: np.ndarray, face: np.ndarray, face_count: int) -> np.ndarray:
    """Weighted mean of per-triangle values over each authored face (faces without triangles get 1)."""
    total = np.bincount(face, weights=values * weights, minlength=face_count)
    weight = np.bincount(face, weights=weights, minlength=face_count)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(weight > 0, total / weight, 1.0).astype(np.float32)


NO_RECEIVERS = "no writable meshes (all instanced, bake:skip or empty)"
"""Why a processor that writes to receiver meshes does not apply."""


def missing_receivers(scene: Scene) -> str:
    """NO_RECEIVERS when the scene has no receiver prims (``receiver_prims``), else ''.

    Meant for ``Processor.applies``: ``reason = missing_receivers(scene); return not reason, reason``.
    """
    return NO_RECEIVERS if len(receiver_prims(scene)) == 0 else ""
