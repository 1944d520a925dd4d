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


INWARD_MIN_RELATIVE = 1e-3
"""A vertex whose ring centroid lies closer than this fraction of the ring's size (in the tangent plane)
is inside a flat or smooth region: it gets no inward direction."""


def vertex_inward(points: np.ndarray, tri_vertices: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(P, 3) float32 unit tangents pointing from each vertex into its own surface: towards the
    area-weighted mean centroid of the triangles that use it, projected on the tangent plane of its
    normal. At an unwelded crease (a flat-shaded box: faces share positions, not vertices) it points
    into the vertex's own face, off the crease line; zero for isolated points and where the ring is
    balanced around the vertex (INWARD_MIN_RELATIVE)."""
    points = np.asarray(points, np.float64)
    corners = points[tri_vertices]
    centroids = corners.mean(axis=1)
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    size = np.sqrt(areas)
    weight = np.zeros(len(points))
    toward = np.zeros((len(points), 3))
    scale = np.zeros(len(points))
    for corner in range(3):
        np.add.at(weight, tri_vertices[:, corner], areas)
        np.add.at(toward, tri_vertices[:, corner], centroids * areas[:, None])
        np.maximum.at(scale, tri_vertices[:, corner], size)
    with np.errstate(invalid="ignore", divide="ignore"):
        offset = np.where(weight[:, None] > 0, toward / weight[:, None] - points, 0.0)
    n = np.asarray(normals, np.float64)
    offset -= n * (offset * n).sum(axis=1, keepdims=True)
    length = np.linalg.norm(offset, axis=1)
    keep = (length > INWARD_MIN_RELATIVE * scale) & (length > 0)
    inward = np.zeros_like(offset)
    inward[keep] = offset[keep] / length[keep, None]
    return inward.astype(np.float32)


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


NO_RECEIVERS = ("no writable meshes (all instanced, bake:skip or empty); bake natively instanced meshes per "
                "vertex with --deinstance (hook: deinstance=True)")
"""Why a processor that writes to receiver meshes does not apply."""


def missing_receivers(scene: Scene) -> str:
    """NO_RECEIVERS when the scene has no receiver prims (``receiver_prims``), else ''.

    Meant for ``Processor.applies``: ``reason = missing_receivers(scene); return not reason, reason``.
    """
    return NO_RECEIVERS if len(receiver_prims(scene)) == 0 else ""


BACKDROP_FACTOR = 4.0
"""A receiver wider than all the others together by this factor on two axes is a backdrop (``backdrop_prims``)."""


def prim_boxes(scene: Scene, prims: np.ndarray) -> np.ndarray:
    """(K, 2, 3) float64 (min, max) of each prim's points."""
    boxes = np.zeros((len(prims), 2, 3))
    for row, prim in enumerate(prims):
        points = scene.points[scene.prim_points(int(prim))].astype(np.float64)
        boxes[row] = points.min(axis=0), points.max(axis=0)
    return boxes


def backdrop_prims(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(backdrops, the other receivers): a receiver is a backdrop (a ground plane, a sky dome mesh) when its
    bounds exceed those of all other receivers together by BACKDROP_FACTOR on at least two axes. Probes
    over a 200 m lawn around a 4 m room would leave the room without one."""
    receivers = receiver_prims(scene)
    if len(receivers) < 2:
        return np.zeros(0, np.int64), receivers
    boxes = prim_boxes(scene, receivers)
    extent = boxes[:, 1] - boxes[:, 0]
    # The union of all boxes but one, for every one at once: prefix and suffix minima / maxima.
    inf = np.full((1, 3), np.inf)
    low_before = np.concatenate([inf, np.minimum.accumulate(boxes[:, 0])[:-1]])
    low_after = np.concatenate([np.minimum.accumulate(boxes[::-1, 0])[::-1][1:], inf])
    high_before = np.concatenate([-inf, np.maximum.accumulate(boxes[:, 1])[:-1]])
    high_after = np.concatenate([np.maximum.accumulate(boxes[::-1, 1])[::-1][1:], -inf])
    rest_extent = np.maximum(high_before, high_after) - np.minimum(low_before, low_after)
    backdrop = (extent > BACKDROP_FACTOR * np.maximum(rest_extent, 1e-30)).sum(axis=1) >= 2
    return receivers[backdrop], receivers[~backdrop]


def receiver_detail_box(scene: Scene) -> tuple[np.ndarray, np.ndarray] | None:
    """(lo, hi) float64 bounds of the receivers that are not backdrops (``backdrop_prims``), in the Scene's
    frame, or None when no receiver is a backdrop (or all are): where a bake's detail is."""
    backdrops, others = backdrop_prims(scene)
    if not (len(backdrops) and len(others)):
        return None
    boxes = prim_boxes(scene, others)
    return boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)


def detail_diagonal(scene: Scene) -> float:
    """The diagonal of ``receiver_detail_box`` (the scene's without backdrops): the length that relative
    sizes (smallest refined face, largest face) should scale with, not a ground plane's."""
    box = receiver_detail_box(scene)
    return scene.diagonal if box is None else float(np.linalg.norm(box[1] - box[0]))
