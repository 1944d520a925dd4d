"""Point location in a light-probe cloud on the device: a grid of start tetrahedra, then the barycentric walk.

The interpolation of Cupisz ("Light probe interpolation using tetrahedral tessellations", GDC 2012) as
Sukys describes it (Chalmers 2014, section 3.2.1): a point's probe weights are its barycentric
coordinates in the tetrahedron that contains it,

    (b1, b2, b3) = M_t (p - v0),   b0 = 1 - b1 - b2 - b3,

with M_t the inverse of the 3 x 3 matrix of the tetrahedron's edge vectors (the "3x3 barycentric
matrices" a game engine stores). The walk starts in a tetrahedron near the point and, while a
coordinate is negative, steps into the neighbour across the face opposite the most negative one. The
start comes from a uniform grid over the cloud whose cells hold the tetrahedron whose centroid is
nearest the cell centre, so walks are a few steps long; the same walk from the last tetrahedron a
moving object was in is ``locate_from`` (what an engine caches per object).

``processors.light_probes.tetrahedra`` holds the float64 numpy walk this one follows step for step; this is its
float32 twin for kernels (``locate``, ``locate_from``: ``wp.func``s other kernels call) and for batches
(``ProbeLookup.locate``).
"""

from __future__ import annotations

import numpy as np
import warp as wp
from scipy.spatial import cKDTree

from ...kernels.tracer import launch_chunked

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

BARY_TOLERANCE = 1e-6
"""A float32 barycentric above -tolerance counts as inside (points on a shared face)."""
MAX_GRID_SIDE = 64
"""Start-grid cells per axis at most (64^3 ints = 1 MB)."""
CELLS_PER_TET = 1.0
"""Start-grid cells per tetrahedron: about one, so a start is within a tetrahedron or two of the point."""


@wp.struct
class TetMesh:
    """A tetrahedralized probe cloud as kernels read it."""

    tet_vertices: wp.array(dtype=wp.vec4i)
    tet_neighbors: wp.array(dtype=wp.vec4i)
    """Neighbour across the face opposite vertex k, -1 on the hull."""
    tet_matrix: wp.array(dtype=wp.mat33)
    """M_t: (p - tet_origin) -> (b1, b2, b3)."""
    tet_origin: wp.array(dtype=wp.vec3)
    """v0 (plus the joggle offset of a tetrahedron flat in the exact positions)."""
    grid_start: wp.array(dtype=int)
    """Start tetrahedron per grid cell, x fastest."""
    grid_lower: wp.vec3
    grid_inverse_cell: float
    grid_side: wp.vec3i
    max_steps: int


@wp.struct
class TetHit:
    tet: int
    bary: wp.vec4
    inside: wp.bool
    """False outside the hull (the walk stopped at the boundary) or when the walk ran out of steps."""


@wp.func
def tet_barycentric(mesh: TetMesh, tet: int, p: wp.vec3) -> wp.vec4:
    """(b0, b1, b2, b3) of p in tetrahedron tet."""
    b = mesh.tet_matrix[tet] * (p - mesh.tet_origin[tet])
    return wp.vec4(1.0 - b[0] - b[1] - b[2], b[0], b[1], b[2])


@wp.func
def start_tet(mesh: TetMesh, p: wp.vec3) -> int:
    """The grid's start tetrahedron for p (cells clamped to the grid)."""
    c = (p - mesh.grid_lower) * mesh.grid_inverse_cell
    x = wp.clamp(int(wp.floor(c[0])), 0, mesh.grid_side[0] - 1)
    y = wp.clamp(int(wp.floor(c[1])), 0, mesh.grid_side[1] - 1)
    z = wp.clamp(int(wp.floor(c[2])), 0, mesh.grid_side[2] - 1)
    return mesh.grid_start[x + mesh.grid_side[0] * (y + mesh.grid_side[1] * z)]


@wp.func
def locate_from(mesh: TetMesh, p: wp.vec3, start: int) -> TetHit:
    """Barycentric walk from tetrahedron ``start`` to the one containing p (see module doc)."""
    hit = TetHit()
    tet = start
    previous = int(-1)
    hit.inside = False
    for _step in range(mesh.max_steps):
        b = tet_barycentric(mesh, tet, p)
        worst = int(0)
        for k in range(1, 4):
            if b[k] < b[worst]:
                worst = k
        hit.tet = tet
        hit.bary = b
        if b[worst] >= -BARY_TOLERANCE:
            hit.inside = True
            return hit
        nxt = mesh.tet_neighbors[tet][worst]
        if nxt < 0:
            return hit  # outside the hull: the boundary tetrahedron
        if nxt == previous:
            hit.inside = True  # the point lies on the face between the two (float rounding): either holds it
            return hit
        previous = tet
        tet = nxt
    return hit


@wp.func
def locate(mesh: TetMesh, p: wp.vec3) -> TetHit:
    """The tetrahedron containing p and p's barycentrics in it, walking from the grid's start."""
    return locate_from(mesh, p, start_tet(mesh, p))


@wp.kernel
def locate_kernel(start: int, mesh: TetMesh, points: wp.array(dtype=wp.vec3), tets: wp.array(dtype=int),
                  bary: wp.array(dtype=wp.vec4), inside: wp.array(dtype=wp.int8)):
    """Batch ``locate``: tetrahedron, barycentrics and inside flag of point i."""
    i = start + wp.tid()
    hit = locate(mesh, points[i])
    tets[i] = hit.tet
    bary[i] = hit.bary
    inside[i] = wp.int8(wp.where(hit.inside, 1, 0))


class ProbeLookup:
    """A Tetrahedralization (``processors.light_probes.tetrahedra``) on the device, with its start grid."""

    def __init__(self, tetra, *, device: str = "cpu", threads: int | None = None):
        from ...kernels.tracer import default_threads

        self.device = wp.get_device(device)
        self.threads = threads or default_threads()
        self.tetra = tetra
        points = np.asarray(tetra.points, np.float64)
        tets = np.asarray(tetra.tet_vertices, np.int64)
        offset = tetra.tet_offset if tetra.tet_offset is not None else np.zeros((len(tets), 3))
        origin = points[tets[:, 0]] + offset
        used = points[np.unique(tets)]
        lower, upper = used.min(axis=0), used.max(axis=0)
        extent = np.maximum(upper - lower, 1e-30)
        cell = float(np.cbrt(np.prod(extent) / max(len(tets) * CELLS_PER_TET, 1.0)))
        cell = max(cell, float(extent.max()) / MAX_GRID_SIDE)
        side = np.clip(np.ceil(extent / cell).astype(np.int64), 1, MAX_GRID_SIDE)
        centres = lower + (np.stack(np.meshgrid(*[np.arange(s) for s in side], indexing="ij"), -1)
                           .transpose(2, 1, 0, 3).reshape(-1, 3) + 0.5) * cell
        centroids = points[tets].mean(axis=1)
        proper = np.flatnonzero(~tetra.tet_flat) if tetra.tet_flat is not None else np.arange(len(tets))
        starts = proper[cKDTree(centroids[proper]).query(centres)[1]]
        mesh = TetMesh()
        mesh.tet_vertices = wp.array(tets.astype(np.int32), dtype=wp.vec4i, device=self.device)
        mesh.tet_neighbors = wp.array(np.asarray(tetra.tet_neighbors, np.int32), dtype=wp.vec4i, device=self.device)
        mesh.tet_matrix = wp.array(np.asarray(tetra.tet_inverse, np.float32), dtype=wp.mat33, device=self.device)
        mesh.tet_origin = wp.array(origin.astype(np.float32), dtype=wp.vec3, device=self.device)
        mesh.grid_start = wp.array(starts.astype(np.int32), dtype=int, device=self.device)
        mesh.grid_lower = wp.vec3(*lower.astype(np.float32))
        mesh.grid_inverse_cell = float(1.0 / cell)
        mesh.grid_side = wp.vec3i(*side.astype(np.int32).tolist())
        mesh.max_steps = int(len(tets) + 1)
        self.mesh = mesh

    def locate(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N,) tetrahedra, (N, 4) float32 barycentrics and (N,) inside flags of points (N, 3)."""
        points = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
        n = len(points)
        tets = wp.empty(n, dtype=int, device=self.device)
        bary = wp.empty(n, dtype=wp.vec4, device=self.device)
        inside = wp.empty(n, dtype=wp.int8, device=self.device)
        launch_chunked(locate_kernel, n, [self.mesh, wp.array(points, dtype=wp.vec3, device=self.device), tets, bary,
                                          inside], device=self.device, threads=self.threads)
        return tets.numpy(), bary.numpy(), inside.numpy().astype(bool)
