"""Tetrahedra that conform to the geometry: the empty space of a box meshed by fTetWild, probes split per side.

A Delaunay cloud's tetrahedra ignore the walls; the leak rule then has to guess where a wall is
(Sukys 3.2.2). Here the box [lo, hi] is tetrahedralized with the scene's triangles (clipped to the box)
embedded in it (Hu et al., "Fast Tetrahedral Meshing in the Wild", SIGGRAPH 2020, through pytetwild), so
every surface lies on tetrahedron faces. The tetrahedra on the two sides of a wall share the wall's mesh
vertices, so a probe per mesh vertex would still carry light through: each vertex instead gets one probe
per *side*, the corners of its tetrahedra joined across faces that no surface covers (a face is covered
when a ray from either tetrahedron's centroid to the face's centroid meets geometry). A point then blends
only probes captured on its own side of every wall; no interpolation crosses a surface by construction.

Tetrahedra whose centroid lies inside geometry (the 26-ray vote of ``classify_points``) stay in the mesh,
so a walk can cross a wall's thickness, and take the probes of their vertices' open sides.

pytetwild's package ``__init__`` imports pyvista (for an accessor on its meshes), which usdbake does not
install (see pyproject.toml); ``tetwild()`` loads pytetwild's compiled fTetWild wrapper directly.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

ENVELOPE_RELATIVE = 1e-3
"""fTetWild's envelope: the meshed surfaces stay within this fraction of the box diagonal of the input."""

COARSEN = True
"""fTetWild's coarsening: it removes every vertex it can while keeping quality, so the probe count follows the
target edge length (off, the counts overshoot the budget 3-6x at the same error: measured on the furnished room)."""

CAPTURE_OFFSET = 0.05
"""A probe on a surface is captured this fraction of the target edge length off it, towards its side."""

FACE_TOLERANCE = 2.0
"""A face is covered by a surface when a centroid -> face-centroid ray meets geometry within this many
envelopes beyond the face (the meshed surface is the input's within the envelope)."""


class TetWildUnavailable(RuntimeError):
    """pytetwild (a required dependency) is missing or its compiled wrapper does not load."""


_WRAPPER = None


def tetwild():
    """pytetwild's compiled fTetWild wrapper module (loaded once, without pytetwild's pyvista import)."""
    global _WRAPPER
    if _WRAPPER is None and "pytetwild.PyfTetWildWrapper" in sys.modules:  # pytetwild imported (with pyvista)
        _WRAPPER = sys.modules["pytetwild.PyfTetWildWrapper"]
    if _WRAPPER is None:
        spec = importlib.util.find_spec("pytetwild")
        if spec is None or not spec.submodule_search_locations:
            raise TetWildUnavailable("conforming tetrahedra need pytetwild (pip install pytetwild)")
        found = sorted(Path(next(iter(spec.submodule_search_locations))).glob("PyfTetWildWrapper*.so")) + sorted(
            Path(next(iter(spec.submodule_search_locations))).glob("PyfTetWildWrapper*.pyd"))
        if not found:
            raise TetWildUnavailable(f"pytetwild at {spec.origin} has no compiled PyfTetWildWrapper")
        loader = importlib.machinery.ExtensionFileLoader("pytetwild.PyfTetWildWrapper", str(found[0]))
        module = importlib.util.module_from_spec(importlib.util.spec_from_loader(loader.name, loader))
        loader.exec_module(module)
        sys.modules[loader.name] = module  # pytetwild's own import, if it comes later, finds this one
        _WRAPPER = module
    return _WRAPPER


def box_surface(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(8, 3) corners and (12, 3) triangles of the box [lo, hi]."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    quads = ((0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3))
    return corners, np.array([t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))])


def clip_polygon(polygon: list[np.ndarray], axis: int, value: float, keep_below: bool) -> list[np.ndarray]:
    """One Sutherland-Hodgman pass: the part of a convex polygon on one side of the plane x[axis] = value."""
    out = []
    for k, current in enumerate(polygon):
        previous = polygon[k - 1]
        inside_now = current[axis] <= value if keep_below else current[axis] >= value
        inside_before = previous[axis] <= value if keep_below else previous[axis] >= value
        if inside_now != inside_before:
            t = (value - previous[axis]) / (current[axis] - previous[axis])
            out.append(previous + t * (current - previous))
        if inside_now:
            out.append(current)
    return out


def clip_to_box(corners: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(M, 3, 3) triangles: those of ``corners`` (N, 3, 3) inside [lo, hi], the ones crossing it clipped
    (and fanned back into triangles), those outside dropped."""
    corners = np.asarray(corners, np.float64)
    inside = ((corners >= lo) & (corners <= hi)).all(axis=(1, 2))
    outside = ((corners < lo).all(axis=1) | (corners > hi).all(axis=1)).any(axis=1)
    pieces = [corners[inside]]
    for triangle in corners[~inside & ~outside]:
        polygon = list(triangle)
        for axis in range(3):
            polygon = clip_polygon(polygon, axis, lo[axis], keep_below=False) if polygon else polygon
            polygon = clip_polygon(polygon, axis, hi[axis], keep_below=True) if polygon else polygon
        pieces.extend(np.array([[polygon[0], polygon[k], polygon[k + 1]]]) for k in range(1, len(polygon) - 1))
    return np.concatenate(pieces) if pieces else np.zeros((0, 3, 3))


@dataclass(frozen=True)
class ConformingMesh:
    """Probes at the mesh vertices, one per side of every surface, and the tetrahedra over them."""

    positions: np.ndarray
    """(P, 3) float64 the mesh vertex of each probe (the tetrahedra's geometry; split probes coincide)."""
    capture_positions: np.ndarray
    """(P, 3) float64 where each probe captures: its vertex, moved off a surface (or the box) towards its own side."""
    tet_vertices: np.ndarray
    """(T, 4) int64 probe indices, positively oriented."""
    tet_neighbors: np.ndarray
    """(T, 4) int64 the tetrahedron across the face opposite each corner, -1 on the box."""
    mesh_vertices: int
    """fTetWild's vertices (before the split per side)."""
    solid_tets: int
    """Tetrahedra inside geometry."""
    covered_faces: int
    """Shared faces that lie on a surface."""
    seconds: float
    """fTetWild's time."""


def tetrahedralize_box(triangles: np.ndarray, lo: np.ndarray, hi: np.ndarray, edge_length: float,
                       threads: int = 0, sizing: tuple | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """fTetWild's mesh of the box [lo, hi] with ``triangles`` (M, 3, 3) embedded (clipped to the box):
    vertices (V, 3), positively oriented tetrahedra (T, 4) inside the box, seconds. ``sizing``: (points
    (S, 3), tetrahedra (U, 4), edge length at each point (S,)), a background mesh whose interpolated values
    are the target edge length where it covers (``edge_length`` elsewhere)."""
    clipped = clip_to_box(triangles, lo, hi)
    corners, faces = box_surface(lo, hi)
    vertices = np.concatenate([clipped.reshape(-1, 3), corners])
    faces = np.concatenate([np.arange(3 * len(clipped)).reshape(-1, 3), faces + 3 * len(clipped)]).astype(np.uint32)
    background = (np.zeros((0, 3)), np.zeros((0, 4), np.int32), np.zeros(0)) if sizing is None else (
        np.ascontiguousarray(sizing[0], np.float64), np.ascontiguousarray(sizing[1], np.int32),
        np.ascontiguousarray(sizing[2], np.float64))
    started = time.perf_counter()
    mesh_v, mesh_t = tetwild().tetrahedralize_mesh(
        vertices, faces, True, False, 0.0, float(edge_length), ENVELOPE_RELATIVE, 10.0, COARSEN, int(threads), 80, 6,
        True, False, True, *background)
    seconds = time.perf_counter() - started
    mesh_v, mesh_t = np.asarray(mesh_v, np.float64), np.asarray(mesh_t, np.int64)
    centroid = mesh_v[mesh_t].mean(axis=1)
    slack = 1e-6 * float(np.linalg.norm(hi - lo))
    mesh_t = mesh_t[((centroid >= lo - slack) & (centroid <= hi + slack)).all(axis=1)]
    a, b, c, d = (mesh_v[mesh_t[:, k]] for k in range(4))
    negative = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) < 0
    mesh_t[negative] = mesh_t[negative][:, [0, 2, 1, 3]]
    return mesh_v, mesh_t, seconds


def shared_faces(tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Faces shared by two tetrahedra: (F, 2) tetrahedron pairs and (F, 2) the corner each one has
    opposite the face; and the (T, 4) neighbour table across the face opposite each corner (-1 none)."""
    t = len(tets)
    opposite = np.repeat(np.arange(4)[None], t, axis=0).reshape(-1)
    owner = np.repeat(np.arange(t), 4)
    faces = np.sort(np.stack([np.delete(tets, k, axis=1) for k in range(4)], axis=1).reshape(-1, 3), axis=1)
    order = np.lexsort(faces.T[::-1])
    same = (faces[order[1:]] == faces[order[:-1]]).all(axis=1)
    first, second = order[:-1][same], order[1:][same]
    pairs = np.stack([owner[first], owner[second]], axis=1)
    corners = np.stack([opposite[first], opposite[second]], axis=1)
    neighbors = -np.ones((t, 4), np.int64)
    neighbors[pairs[:, 0], corners[:, 0]] = pairs[:, 1]
    neighbors[pairs[:, 1], corners[:, 1]] = pairs[:, 0]
    return np.concatenate([pairs, corners], axis=1), neighbors


def conforming_mesh(tracer, classify, triangles: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                    edge_length: float, threads: int = 0, sizing: tuple | None = None) -> ConformingMesh:
    """The conforming probe mesh of the box [lo, hi] around ``triangles`` (M, 3, 3, the tracer's frame).

    ``classify(points) -> (inside, nearest)`` is ``processors.light_probes.capture.classify_points`` bound to the
    scene; ``tracer`` casts the face-covering rays (module docstring)."""
    mesh_v, tets, seconds = tetrahedralize_box(triangles, lo, hi, edge_length, threads, sizing)
    centroid = mesh_v[tets].mean(axis=1)
    solid, _ = classify(centroid.astype(np.float32))
    pairs_corners, neighbors = shared_faces(tets)
    pairs, opposite = pairs_corners[:, :2], pairs_corners[:, 2:]

    # A face between two tetrahedra is covered when geometry lies on it (rays from both centroids).
    keep_corner = np.arange(4)[None] != opposite[:, :1]
    face_vertices = tets[pairs[:, 0]][keep_corner].reshape(-1, 3)
    face_centre = mesh_v[face_vertices].mean(axis=1)
    tolerance = FACE_TOLERANCE * ENVELOPE_RELATIVE * float(np.linalg.norm(hi - lo))
    covered = np.zeros(len(pairs), bool)
    for side in range(2):
        origin = centroid[pairs[:, side]]
        d = face_centre - origin
        length = np.linalg.norm(d, axis=1)
        unit = d / np.maximum(length, 1e-30)[:, None]
        hit_t = tracer.closest_hit(origin.astype(np.float32), unit.astype(np.float32)).hit_t
        covered |= hit_t < length + tolerance

    # Corners (tet, k) joined across open faces: one probe per connected set (a vertex per side).
    open_faces = np.flatnonzero(~covered & ~solid[pairs[:, 0]] & ~solid[pairs[:, 1]])
    rows, cols = [], []
    for k in range(4):
        joined = open_faces[opposite[open_faces, 0] != k]
        ta, tb = pairs[joined, 0], pairs[joined, 1]
        vertex = tets[ta, k]
        rows.append(4 * ta + k)
        cols.append(4 * tb + np.argmax(tets[tb] == vertex[:, None], axis=1))
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    nodes = 4 * len(tets)
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(nodes, nodes))
    _, label = connected_components(graph, directed=False)
    corner_vertex = tets.reshape(-1)
    corner_solid = np.repeat(solid, 4)

    # Probes of open sides; a solid tetrahedron's corner takes an open side's probe of its vertex, or (a
    # vertex inside geometry only) a probe of its own.
    open_label = np.where(corner_solid, -1, label)
    labels, probe_of_label = np.unique(open_label[open_label >= 0], return_inverse=True)
    probe = -np.ones(nodes, np.int64)
    probe[open_label >= 0] = probe_of_label
    vertex_probe = -np.ones(len(mesh_v), np.int64)
    vertex_probe[corner_vertex[probe >= 0]] = probe[probe >= 0]
    orphan_vertices = np.unique(corner_vertex[(probe < 0) & (vertex_probe[corner_vertex] < 0)])
    vertex_probe[orphan_vertices] = len(labels) + np.arange(len(orphan_vertices))
    probe[probe < 0] = vertex_probe[corner_vertex[probe < 0]]
    count = len(labels) + len(orphan_vertices)

    position_vertex = np.zeros(count, np.int64)
    position_vertex[probe] = corner_vertex
    positions = mesh_v[position_vertex]
    # Capture off the surface: towards the mean centroid of the probe's own tetrahedra, where the vertex
    # has tetrahedra on other sides (split) or inside geometry.
    side_centre = np.zeros((count, 3))
    side_count = np.zeros(count)
    open_corners = ~corner_solid
    np.add.at(side_centre, probe[open_corners], np.repeat(centroid, 4, axis=0)[open_corners])
    np.add.at(side_count, probe[open_corners], 1.0)
    corners_at_vertex = np.bincount(corner_vertex, minlength=len(mesh_v))
    # On a surface: the vertex has tetrahedra on other sides or inside geometry, or it lies on the box
    # (where a scene's outer walls often are).
    slack = 1e-6 * float(np.linalg.norm(hi - lo))
    on_box = ((positions <= lo + slack) | (positions >= hi - slack)).any(axis=1)
    on_surface = (side_count < corners_at_vertex[position_vertex]) | on_box
    towards = side_centre / np.maximum(side_count, 1.0)[:, None] - positions
    distance = np.linalg.norm(towards, axis=1)
    step = np.minimum(CAPTURE_OFFSET * edge_length, 0.3 * distance)
    move = on_surface & (side_count > 0) & (distance > 0)
    capture = positions.copy()
    capture[move] += towards[move] * (step[move] / distance[move])[:, None]
    return ConformingMesh(positions=positions, capture_positions=capture, tet_vertices=probe.reshape(-1, 4),
                          tet_neighbors=neighbors, mesh_vertices=len(mesh_v), solid_tets=int(solid.sum()),
                          covered_faces=int(covered.sum()), seconds=seconds)
