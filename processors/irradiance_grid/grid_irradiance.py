"""Irradiance from an irradiance-vector grid inside a kernel (Pacanowski et al. 2008, section 3.2).

The ``wp.func`` twin of ``processors/irradiance_grid/vector_grid.reconstruct_irradiance`` ("paper" reconstruction,
no behind-cutoff): kernels that need the grid's light at a point call it, such as the grid's own capture
when it bounces light a second time.
"""

from __future__ import annotations

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})


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
def grid_irradiance(grid: GridVectors, p: wp.vec3, n: wp.vec3) -> wp.vec3:
    """E(p, n) = max(0, I_n . n) per channel with I_n = I_x n_x^2 + I_y n_y^2 + I_z n_z^2 (paper 3.2, eq. 2):
    each I_a trilinear over the 8 vertices around p (clamped to the grid) in the hemisphere of a chosen by
    the sign of n_a. W/m^2; ``n`` unit, ``p`` already moved off the surface by the caller."""
    t = wp.vec3(0.0, 0.0, 0.0)
    i0 = wp.vec3i(0, 0, 0)
    i1 = wp.vec3i(0, 0, 0)
    for a in range(3):
        top = grid.resolution[a] - 1
        g = wp.clamp((p[a] - grid.origin[a]) / grid.cell[a], 0.0, float(top))
        lo = wp.min(int(wp.floor(g)), wp.max(top - 1, 0))
        i0[a] = lo
        i1[a] = wp.min(lo + 1, top)
        if top > 0:
            t[a] = g - float(lo)
    e = wp.vec3(0.0, 0.0, 0.0)
    for a in range(3):
        h = 2 * a
        if n[a] < 0.0:
            h = h + 1
        interp = wp.mat33(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        for corner in range(8):
            w = float(1.0)
            c = wp.vec3i(0, 0, 0)
            for b in range(3):
                if (corner >> b) & 1 == 1:
                    c[b] = i1[b]
                    w = w * t[b]
                else:
                    c[b] = i0[b]
                    w = w * (1.0 - t[b])
            v = c[0] + grid.resolution[0] * (c[1] + grid.resolution[1] * c[2])
            interp = interp + grid.vectors[v * 6 + h] * w
        e = e + (interp * n) * (n[a] * n[a])
    return wp.vec3(wp.max(e[0], 0.0), wp.max(e[1], 0.0), wp.max(e[2], 0.0))
