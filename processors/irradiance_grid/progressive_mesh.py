"""Progressive meshes by half-edge collapse (vertex order + collapse table per mesh).

Pacanowski et al., "Efficient streaming of 3D scenes with complex geometry
and complex lighting", Web3D 2008 (doi:10.1145/1394209.1394214), Section 4.2:
instead of collapsing an edge onto a new vertex (Hoppe 1996), collapse it onto
one of its end vertices, so the whole multiresolution mesh is the original
mesh plus a *vertex lookup table* (the vertex each vertex collapses onto; the
paper's reference for it is Melax 1998) and a vertex order: streaming the
vertices in that order, a client rebuilds every level of detail by mapping
each face corner through the table until it reaches a received vertex and
dropping the faces that became degenerate.

**Collapse order, in two passes.** Section 4.2 leaves the energy open ("some
energy function", citing Garland & Heckbert 1997).

1. *Bulk, by quadric error* (Garland & Heckbert): the edge collapses of
   fast-simplification (Fast-Quadric-Mesh-Simplification, C++) with the mesh
   borders kept, down to about ``BASE_POINTS`` vertices, replayed as half-edge
   collapses onto the vertex the library keeps (its moved position is not
   used: received vertices keep their authored positions). A well-kept
   library: a 200k-vertex height field in under 2 s, where a Python heap took
   minutes. When more than ``BASE_POINTS`` vertices remain (meshes with long
   borders, unwelded triangle soups), a second quadric pass collapses borders
   too, down to about that many.
2. *The coarsest ~BASE_POINTS vertices*, by Melax's half-edge cost ("A simple, fast, and effective
   polygon reduction algorithm", Game Developer, November 1998), in stage
   units (a length times a dimensionless curvature)::

       cost(u -> v) = |u - v| * max_{f in faces(u)} min_{g in faces(u) & faces(v)} (1 - n_f . n_g) / 2

   plus, for a vertex on a mesh border, ``|u - v| * (1 - cos(turn)) / 2`` with
   ``turn`` the border's turning angle at u (straight borders collapse freely,
   corners stay), and border vertices only collapse along border edges (the
   outline never shrinks inward). A collapse that would flip a remaining face
   (its normal turning by more than 90 degrees) costs ``FLIP_PENALTY`` more.
   Each step collapses the vertex with the cheapest collapse (lazy heap; ties
   by vertex index, so the result is deterministic). This pass orders the
   coarsest levels, where the outline and the corners matter most.

**Order.** ``rank[u]``: the position of u in the stream, 0 = the coarsest
mesh's first vertex; a vertex collapses onto one of lower rank
(``collapse_to[u]``, -1 for the last vertex of each connected piece and
for isolated points). The level of detail with the first k vertices is
``lod_faces(tri_vertices, rank, collapse_to, k)``.

Works on the triangulated faces; the table and the order are per authored
point, so they apply to the authored polygons as well (map the corners,
drop polygons with fewer than 3 distinct corners).

USD written (bake layer), on every writable mesh:

============================ ====== ============= =====================================
property                     type   interpolation value
============================ ====== ============= =====================================
primvars:bake:pmRank         int[]  vertex        stream position of each point
primvars:bake:pmCollapseTo   int[]  vertex        point it collapses onto, -1 for none
bake:pmStreamFile            asset                ``usdbake_mesh_<hash>.bin``: the mesh as a
                                                  progressive stream (formats/mesh_stream.py;
                                                  world-space positions)
============================ ====== ============= =====================================

Parameters: ``usdbake list progressive_mesh`` or docs/irradiance_grid.md, both generated from ``Params`` below.
"""

from __future__ import annotations

import hashlib
import heapq
from dataclasses import dataclass

import fast_simplification
import numpy as np

from ...core import Attribute, Context, File, Params, Primvar, Processor, Result, param
from .products import ProgressiveMeshProduct
from ...formats.mesh_stream import encode_mesh_stream
from ...geometry.mesh import missing_receivers, receiver_prims

FLIP_PENALTY = 10.0
"""Added to the curvature term of a collapse that flips a face: such collapses come last."""

EAGER_FACES = 32
"""Melax pass: vertices of at most this many faces are re-priced as soon as a neighbour collapses."""

BASE_POINTS = 2000
"""Vertices left to the Melax pass (pure Python, ~1-2 ms a vertex); the quadric passes take the rest."""


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _dot(a, b) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _normal(p, face) -> tuple[float, float, float]:
    """Unit normal of a face (plain floats: this runs per collapse candidate); zero if degenerate."""
    u, v = _sub(p[face[1]], p[face[0]]), _sub(p[face[2]], p[face[0]])
    n = (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])
    length = _dot(n, n) ** 0.5
    if not length > 0.0 or length == float("inf"):
        return (0.0, 0.0, 0.0)
    return (n[0] / length, n[1] / length, n[2] / length)


def progressive_order(points: np.ndarray, tri_vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Half-edge collapse order of a triangle mesh (Pacanowski et al. 2008, Section 4.2; the two passes of
    the module docstring).

    The reversed collapse sequence is the stream order, which puts "the most significant vertices (that
    are present in the coarser meshes)" first (Section 4.2), and ``collapse_to`` is the paper's vertex
    lookup table.

    Parameters
    ----------
    points : (P, 3) float
    tri_vertices : (T, 3) int indices into points

    Returns
    -------
    rank : (P,) int32 permutation, stream position of each point
    collapse_to : (P,) int32 point each point collapses onto (lower rank), -1 for none
    """
    p = np.nan_to_num(np.asarray(points, np.float64).reshape(-1, 3), posinf=0.0, neginf=0.0)
    tris = _proper(np.asarray(tri_vertices, np.int64).reshape(-1, 3))
    collapse_to = np.full(len(p), -1, np.int64)
    final = np.arange(len(p))  # the surviving vertex each vertex maps to
    sequence = []
    for keep_border in (True, False):
        target = min(2 * BASE_POINTS, len(tris) - 1)  # triangles; the library wants fewer than it has
        if len(np.unique(tris)) <= BASE_POINTS or target < 1:
            break
        _, _, collapses = fast_simplification.simplify(p, tris.astype(np.int32), target_count=target,
                                                       preserve_border=keep_border, return_collapses=True)
        collapses = np.asarray(collapses, np.int64).reshape(-1, 2)
        collapse_to[collapses[:, 1]] = collapses[:, 0]
        sequence.append(collapses[:, 1])
        for kept, gone in collapses[::-1].tolist():  # later collapses first: chains resolve to the survivor
            final[gone] = final[kept]
        tris = _proper(final[tris])
    collapsed = np.concatenate(sequence) if sequence else np.zeros(0, np.int64)
    base = np.setdiff1d(np.arange(len(p)), collapsed)
    compact = np.full(len(p), -1, np.int64)
    compact[base] = np.arange(len(base))
    base_rank, base_collapse = _melax_order(p[base], compact[tris])
    collapse_to[base] = np.where(base_collapse >= 0, base[np.maximum(base_collapse, 0)], -1)
    rank = np.empty(len(p), np.int32)
    rank[base] = base_rank
    rank[collapsed[::-1]] = len(base) + np.arange(len(collapsed), dtype=np.int32)
    return rank, collapse_to.astype(np.int32)


def _melax_order(points: np.ndarray, tri_vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``progressive_order``'s (rank, collapse_to) by Melax's cost alone, for the coarsest vertices (pass 2
    of the module docstring): collapses the cheapest vertex onto a neighbour until none is left."""
    p = [tuple(row) for row in np.nan_to_num(np.asarray(points, np.float64).reshape(-1, 3)).tolist()]
    tris = np.asarray(tri_vertices, np.int64).reshape(-1, 3)
    count = len(p)
    faces: dict[int, list[int]] = {}
    vertex_faces: list[set[int]] = [set() for _ in range(count)]
    neighbours: list[set[int]] = [set() for _ in range(count)]
    for f, (a, b, c) in enumerate(tris.tolist()):
        if a == b or b == c or a == c:
            continue  # a face with repeated corners holds no surface
        faces[f] = [a, b, c]
        for x in (a, b, c):
            vertex_faces[x].add(f)
        neighbours[a] |= {b, c}
        neighbours[b] |= {a, c}
        neighbours[c] |= {a, b}
    normals = {f: _normal(p, face) for f, face in faces.items()}

    def cost(u: int) -> tuple[float, int]:
        best, target = float("inf"), -1
        border = [w for w in neighbours[u] if len(vertex_faces[u] & vertex_faces[w]) == 1]
        turn = 0.0
        if len(border) == 2:
            d1, d2 = _sub(p[u], p[border[0]]), _sub(p[border[1]], p[u])
            l1, l2 = _dot(d1, d1) ** 0.5, _dot(d2, d2) ** 0.5
            if l1 > 0 and l2 > 0:
                turn = (1.0 - _dot(d1, d2) / (l1 * l2)) / 2.0
        elif border:
            turn = 1.0  # several borders meet here: keep it late
        for v in sorted(neighbours[u]):
            if border and v not in border:
                continue
            shared = vertex_faces[u] & vertex_faces[v]
            curvature = 0.0
            for f in vertex_faces[u]:
                nf = normals[f]
                curvature = max(curvature, min(((1.0 - _dot(nf, normals[g])) / 2.0 for g in shared), default=0.0))
            penalty = 0.0
            for f in vertex_faces[u] - shared:
                if _dot(_normal(p, [v if x == u else x for x in faces[f]]), normals[f]) < 0.0:
                    penalty = FLIP_PENALTY
                    break
            d = _sub(p[u], p[v])
            value = _dot(d, d) ** 0.5 * (curvature + turn + penalty)
            if value < best:
                best, target = value, v
        return best, target

    heap = [((cost(u)[0] if neighbours[u] else -1.0), u) for u in range(count)]  # isolated points first
    heapq.heapify(heap)
    alive = [True] * count
    collapse_to = np.full(count, -1, np.int64)
    sequence = []
    while heap:
        c, u = heapq.heappop(heap)
        if not alive[u]:
            continue
        if not neighbours[u]:
            alive[u] = False
            sequence.append(u)
            continue
        current, v = cost(u)
        if heap and current > heap[0][0] + 1e-12 * max(1.0, abs(current)):
            heapq.heappush(heap, (current, u))  # stale key (lazy update): requeue at its real cost
            continue
        if v < 0:  # only border-breaking moves left: take the nearest-index neighbour
            v = min(neighbours[u])
        alive[u] = False
        sequence.append(u)
        collapse_to[u] = v
        for f in list(vertex_faces[u]):
            face = faces[f]
            if v in face:
                for x in face:
                    vertex_faces[x].discard(f)
                del faces[f]
                del normals[f]
            else:
                faces[f] = [v if x == u else x for x in face]
                vertex_faces[v].add(f)
                moved = _normal(p, faces[f])
                if moved != (0.0, 0.0, 0.0):  # a face that became a sliver keeps its last normal
                    normals[f] = moved
        vertex_faces[u] = set()
        for w in neighbours[u]:
            neighbours[w].discard(u)
            if w != v:
                neighbours[w].add(v)
                neighbours[v].add(w)
        neighbours[v].discard(v)
        touched = neighbours[u] | {v}
        neighbours[u] = set()
        for w in list(neighbours[v]):  # neighbours lost with their last shared face
            if not (vertex_faces[v] & vertex_faces[w]):
                neighbours[v].discard(w)
                neighbours[w].discard(v)
        for w in touched:
            # A vertex of many faces (a fan's hub) costs O(faces^2) to price and is touched by every
            # neighbour's collapse: its heap entry stays, and the check at its pop re-prices it.
            if alive[w] and len(vertex_faces[w]) <= EAGER_FACES:
                heapq.heappush(heap, ((cost(w)[0] if neighbours[w] else -1.0), w))
    rank = np.empty(count, np.int32)
    rank[np.asarray(sequence[::-1], np.int64)] = np.arange(count, dtype=np.int32)
    return rank, collapse_to.astype(np.int32)


def lod_faces(tri_vertices: np.ndarray, rank: np.ndarray, collapse_to: np.ndarray, k: int) -> np.ndarray:
    """(F, 3) faces of the level of detail made of the points of rank < k (Section 4.2 of Pacanowski et al.
    2008: each corner is mapped through the vertex lookup table until it reaches a received vertex, and the
    faces left degenerate are dropped, so only valid faces remain)."""
    rank = np.asarray(rank, np.int64)
    collapse_to = np.asarray(collapse_to, np.int64)
    target = np.arange(len(rank))
    for u in np.argsort(rank)[k:]:  # increasing rank: a vertex's target is resolved before it
        t = collapse_to[u]
        target[u] = -1 if t < 0 else target[t]
    mapped = target[np.asarray(tri_vertices, np.int64).reshape(-1, 3)]
    return _proper(mapped[(mapped >= 0).all(axis=1)])


def _proper(faces: np.ndarray) -> np.ndarray:
    """The faces with three distinct corners (the others hold no surface)."""
    return faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]


class ProgressiveMesh(Processor):
    name = "progressive_mesh"
    version = "2"
    summary = "Progressive meshes by half-edge collapse: stream order and vertex lookup table per mesh."
    facets = ("geometry",)
    follows_refinement = True
    writes = ("primvars:bake:pmRank", "primvars:bake:pmCollapseTo", "bake:pmStreamFile")
    provides = (ProgressiveMeshProduct,)

    @dataclass(frozen=True)
    class Params(Params):
        max_points: int = param(5_000_000, "meshes with more points are skipped", low=1)
        packet_vertices: int = param(4096, "vertices per packet of the mesh stream file", low=1, high=1 << 24)

    def applies(self, ctx: Context) -> tuple[bool, str]:
        reason = missing_receivers(ctx.scene)
        return not reason, reason

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        receivers = receiver_prims(scene)
        result = Result(products={ProgressiveMeshProduct: ProgressiveMeshProduct({})})
        skipped = []
        for done, prim in enumerate(receivers):
            sl = scene.prim_points(prim)
            start = sl.start
            points = scene.points[sl]
            if len(points) > p.max_points:
                skipped.append(scene.prim_paths[prim])
                continue
            mine = (scene.tri_prim == prim) & (scene.tri_instance < 0)
            tris = scene.tri_vertices[mine] - start
            rank, collapse_to = progressive_order(points, tris)
            path = scene.prim_paths[prim]
            result.products[ProgressiveMeshProduct].orders[path] = (rank, collapse_to)
            result.outputs.append(Primvar(path, "bake:pmRank", rank, "int", "vertex"))
            result.outputs.append(Primvar(path, "bake:pmCollapseTo", collapse_to, "int", "vertex"))
            data = encode_mesh_stream(points.astype(np.float64) + scene.origin, tris, rank, collapse_to,
                                      packet_vertices=p.packet_vertices)
            stream_file = f"usdbake_mesh_{hashlib.sha256(data).hexdigest()[:10]}.bin"
            result.outputs += [Attribute(path, "bake:pmStreamFile", stream_file, "asset"), File(stream_file, data)]
            ctx.progress((done + 1) / len(receivers))
        if skipped:
            result.messages.append(f"{len(skipped)} meshes over max_points={p.max_points} were skipped: "
                                   + ", ".join(skipped[:5]))
        return result
