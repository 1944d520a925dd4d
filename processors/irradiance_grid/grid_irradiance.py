"""Irradiance from an irradiance-vector grid inside a kernel (Pacanowski et al. 2008, section 3.2).

``grid_irradiance`` is the ``wp.func`` twin of ``processors/irradiance_grid/vector_grid.reconstruct_irradiance``
("paper" reconstruction, no behind-cutoff). ``visible_grid_irradiance`` is the read the grid's own bounce
passes make at a ray hit y (``irradiance_grid`` docstring, **Bounces**): the same formula over the trilinear
corners that y's side of the surface can see, renormalized::

    p      = y + min(o, t_n / 2) n                     (o = BOUNCE_OFFSET cells; t_n: first hit along n)
    V_c    = 1 if (x_c - y) . n >= 0 and the segment p -> x_c is unoccluded, else 0
    E(y)   = max(0, sum_c w_c V_c sum_a n_a^2 (I_{c,a} . n)) / sum_c w_c V_c     (0 when no corner is kept,
                                                                              or p lies off the grid)

with w_c the trilinear weights of p, x_c the corner positions and I_{c,a} corner c's vector of the
hemisphere of axis a chosen by the sign of n_a. Without V_c a hit on a wall reads vertices on the far
side of the wall (a sky-lit lawn beyond a room's single-sided wall, the filled inside of a cabinet),
and a pass adds light the previous pass never carried. The paper's weights (not the ``normalized``
reconstruction) make the read a lower bound of the light the corner vectors hold:
``I_a . n = integral_{w . a > 0} L (w . n) dw <= E(n)`` because the integrand is at most
``L max(0, w . n)``, and ``sum_a n_a^2 = 1``; dividing by ``sum |n_a|^3`` would overshoot collimated light
along a diagonal normal by up to sqrt(3). So each pass adds at most the light that is there, and the
passes converge from below. ``bounce_tail`` is the grid the last pass reads instead when the passes'
geometric tail is extrapolated (``extrapolate``).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ...kernels.direction24 import AXES
from ...kernels.traversal import TraceScene, surface_origin, trace_any, trace_closest

wp.set_module_options({"enable_backward": False, "fuse_fp": False})


@wp.struct
class GridVectors:
    """An irradiance-vector grid on the device: six vectors per vertex, rows = RGB (W/m^2)."""

    vectors: wp.array(dtype=wp.mat33)
    """(V * 6): vertex v, hemisphere h (+x, -x, +y, -y, +z, -z) at v * 6 + h; vertices x fastest."""
    resolution: wp.vec3i
    origin: wp.vec3
    cell: wp.vec3


def grid_vectors(vectors: np.ndarray, resolution, origin, cell, device) -> GridVectors:
    """A GridVectors of (V, 6, 3, 3) float vectors in the scene frame."""
    grid = GridVectors()
    grid.vectors = wp.array(np.ascontiguousarray(np.asarray(vectors, np.float32).reshape(-1, 3, 3)), dtype=wp.mat33,
                            device=device)
    grid.resolution = wp.vec3i(*(int(n) for n in resolution))
    grid.origin = wp.vec3(*(float(x) for x in origin))
    grid.cell = wp.vec3(*(float(x) for x in cell))
    return grid


@wp.func
def grid_coordinates(grid: GridVectors, p: wp.vec3) -> wp.vec3:
    """p in vertex units ((p - origin) / cell), unclamped."""
    return wp.cw_div(p - grid.origin, grid.cell)


@wp.func
def corner_vertex(grid: GridVectors, g: wp.vec3, corner: int) -> wp.vec3i:
    """Vertex (i, j, k) of trilinear corner ``corner`` (bit b: upper along axis b) of the cell holding the
    grid coordinates g (clamped to the grid)."""
    c = wp.vec3i(0, 0, 0)
    for b in range(3):
        top = grid.resolution[b] - 1
        lo = wp.min(int(wp.floor(wp.clamp(g[b], 0.0, float(top)))), wp.max(top - 1, 0))
        c[b] = lo
        if (corner >> b) & 1 == 1:
            c[b] = wp.min(lo + 1, top)
    return c


@wp.func
def corner_weight(grid: GridVectors, g: wp.vec3, corner: int) -> float:
    """Trilinear weight of corner ``corner`` at grid coordinates g (clamped to the grid)."""
    w = float(1.0)
    for b in range(3):
        top = grid.resolution[b] - 1
        x = wp.clamp(g[b], 0.0, float(top))
        lo = wp.min(int(wp.floor(x)), wp.max(top - 1, 0))
        t = float(0.0)
        if top > 0:
            t = x - float(lo)
        if (corner >> b) & 1 == 1:
            w = w * t
        else:
            w = w * (1.0 - t)
    return w


@wp.func
def vertex_irradiance(grid: GridVectors, c: wp.vec3i, n: wp.vec3) -> wp.vec3:
    """sum_a n_a^2 (I_a . n) at vertex c, per channel, unclamped (paper 3.2: linear in the vectors, so the
    trilinear blend of this is the paper's reconstruction)."""
    v = c[0] + grid.resolution[0] * (c[1] + grid.resolution[1] * c[2])
    e = wp.vec3(0.0, 0.0, 0.0)
    for a in range(3):
        h = 2 * a
        if n[a] < 0.0:
            h = h + 1
        e = e + (grid.vectors[v * 6 + h] * n) * (n[a] * n[a])
    return e


@wp.func
def clamp_positive(e: wp.vec3) -> wp.vec3:
    return wp.vec3(wp.max(e[0], 0.0), wp.max(e[1], 0.0), wp.max(e[2], 0.0))


@wp.func
def grid_irradiance(grid: GridVectors, p: wp.vec3, n: wp.vec3) -> wp.vec3:
    """E(p, n) = max(0, I_n . n) per channel with I_n = I_x n_x^2 + I_y n_y^2 + I_z n_z^2 (paper 3.2, eq. 2):
    each I_a trilinear over the 8 vertices around p (clamped to the grid) in the hemisphere of a chosen by
    the sign of n_a. W/m^2; ``n`` unit, ``p`` already moved off the surface by the caller."""
    g = grid_coordinates(grid, p)
    e = wp.vec3(0.0, 0.0, 0.0)
    for corner in range(8):
        e = e + vertex_irradiance(grid, corner_vertex(grid, g, corner), n) * corner_weight(grid, g, corner)
    return clamp_positive(e)


@wp.func
def visible_grid_irradiance(scene: TraceScene, grid: GridVectors, y: wp.vec3, n: wp.vec3, offset: float,
                            epsilon: float) -> wp.vec3:
    """E(y, n) read from the grid over the corners y's side of the surface sees (module docstring): the
    read point p = y + min(offset, t_n / 2) n (stage units), corners behind y's plane or hidden from p
    dropped and the others' weights renormalized; 0 when none is kept or p lies more than half a cell
    outside the grid (the grid knows nothing there). W/m^2; ``n`` unit, facing the side that is read."""
    o = surface_origin(scene, y, n, wp.vec3(0.0, 0.0, 0.0), epsilon)
    reach = offset
    q = trace_closest(scene, o, n, offset)
    if q.result:
        reach = 0.5 * q.t
    p = o + n * reach
    g = grid_coordinates(grid, p)
    inside = True
    for b in range(3):
        if g[b] < -0.5 or g[b] > float(grid.resolution[b] - 1) + 0.5:
            inside = False
    e = wp.vec3(0.0, 0.0, 0.0)
    kept = float(0.0)
    for corner in range(8):
        w = corner_weight(grid, g, corner)
        if inside and w > 0.0:
            c = corner_vertex(grid, g, corner)
            x = grid.origin + wp.cw_mul(wp.vec3(float(c[0]), float(c[1]), float(c[2])), grid.cell)
            if wp.dot(x - y, n) >= 0.0:
                seen = True
                if wp.length(x - p) > epsilon:
                    seen = not trace_any(scene, p, x - p, 1.0)
                if seen:
                    e = e + vertex_irradiance(grid, c, n) * w
                    kept = kept + w
    if kept <= 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    return clamp_positive(e / kept)


@wp.kernel
def visible_irradiance_kernel(start: int, scene: TraceScene, grid: GridVectors, points: wp.array(dtype=wp.vec3),
                              normals: wp.array(dtype=wp.vec3), offset: float, epsilon: float,
                              irradiance: wp.array(dtype=wp.vec3)):
    """Point i: ``visible_grid_irradiance`` at points[i] with unit normal normals[i] (zero normal: 0)."""
    i = start + wp.tid()
    n = normals[i]
    if wp.length(n) < 0.5:
        irradiance[i] = wp.vec3(0.0, 0.0, 0.0)
        return
    irradiance[i] = visible_grid_irradiance(scene, grid, points[i], wp.normalize(n), offset, epsilon)


def compute_visible_irradiance(tracer, layout, vectors: np.ndarray, points: np.ndarray, normals: np.ndarray, *,
                               offset: float = 0.5) -> np.ndarray:
    """(N, 3) float32 irradiance (W/m^2) at surface points (N, 3) with normals (N, 3), read from grid vectors
    (V, 6, 3, 3) on ``layout`` (vector_grid.GridLayout, scene frame) as a bounce pass reads them
    (``visible_grid_irradiance``); ``offset`` in cells."""
    points = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
    normals = np.ascontiguousarray(np.nan_to_num(normals), np.float32).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros((0, 3), np.float32)
    grid = grid_vectors(vectors, layout.resolution, layout.grid_origin, layout.cell_size, tracer.device)
    out = wp.zeros(len(points), dtype=wp.vec3, device=tracer.device)
    tracer.launch(visible_irradiance_kernel, len(points), [
        tracer.scene, grid, tracer.array(points, wp.vec3), tracer.array(normals, wp.vec3),
        float(offset) * float(np.min(layout.cell_size)), tracer.epsilon, out])
    tracer.rays_cast += 9 * len(points)
    return out.numpy().astype(np.float32)


TAIL_RATIO_MAX = 0.95
"""The bounce ratio ``bounce_tail`` extrapolates with is at most this (a tail of 19 more passes' light)."""


def bounce_tail(*passes: np.ndarray) -> np.ndarray:
    """The indirect grid with all bounces from the last passes G_{j-1}, G_j (the first pass's predecessor
    is 0): the bounces beyond j as the geometric tail of the last increment (Neumann series of the
    transport operator T: after a few passes the increment dG_j = G_j - G_{j-1} ~ r dG_{j-1}, r the
    spectral radius of T, as in power iteration), ``G_inf = G_j + dG_j r / (1 - r)``; the "ambient term"
    of progressive radiosity (Cohen, Chen, Wallace & Greenberg, SIGGRAPH 1988, sec. 4) estimated from the
    passes. r is the ratio of the increments' *signed* sums of hemisphere irradiance (``I_delta . delta``
    over vertices, hemispheres and channels): the passes' noise cancels in a sum, where a sum of absolute
    differences would count it as light. Clipped to [0, TAIL_RATIO_MAX]."""
    if len(passes) < 3:
        return passes[-1]
    older, previous, last = (np.einsum("nhcx,hx->", np.asarray(g, np.float64), AXES) for g in passes[-3:])
    step, before = last - previous, previous - older
    ratio = float(np.clip(step / before, 0.0, TAIL_RATIO_MAX)) if before > 0 else 0.0
    return (passes[-1] + (passes[-1] - passes[-2]) * np.float32(ratio / (1.0 - ratio))).astype(np.float32)
