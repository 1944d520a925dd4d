"""The irradiance vector grid's layout over the scene and the irradiance read back from it (numpy).

Pacanowski et al. 2008, sections 3.1 and 3.2; the layout rule and the reconstruction formulas are in
the ``irradiance_grid`` module docstring (**Grid**, **Reconstruction**). ``grid_irradiance`` holds the
reconstruction's ``wp.func`` twin, for kernels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...core.scene import Scene
from ...formats import streaming
from ...geometry.mesh import receiver_detail_box

MAX_GRID_VERTICES = 50_000_000
"""Refuse grids larger than this (a tiny cell_size on a large scene): about 10 GB of float vectors."""


@dataclass(frozen=True)
class GridLayout:
    grid_origin: np.ndarray
    """(3,) float64 position of vertex (0, 0, 0) in the scene frame."""
    cell_size: np.ndarray
    """(3,) float64."""
    resolution: tuple[int, int, int]

    @property
    def count(self) -> int:
        return int(np.prod(self.resolution))

    def positions(self) -> np.ndarray:
        """(V, 3) float32 vertex positions in the scene frame, x fastest."""
        return (self.grid_origin + streaming.grid_coords(self.resolution) * self.cell_size).astype(np.float32)


def _axis_counts(extent: np.ndarray, h: float) -> np.ndarray:
    return np.maximum(2, np.ceil(extent / h + 0.5).astype(np.int64) + 1)


RECEIVER_MARGIN = 0.1
"""Without probe volumes, the grid spans the non-backdrop receivers' bounds grown by this share of their
diagonal on every side (the rule light_probes places its probes by), clipped to the scene's bounds."""


def grid_bounds(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Where the grid goes: the union of the stage's probe volumes (prims with ProbeVolumeAPI); with none, the
    bounds of the receivers that are not backdrops (``geometry.mesh.backdrop_prims``: a 200 m ground under a
    6 m room) grown by RECEIVER_MARGIN of their diagonal and clipped to the scene's bounds; the scene's bounds
    when no receiver is a backdrop."""
    if len(scene.probe_volumes):
        return scene.probe_volumes[:, 0].min(axis=0), scene.probe_volumes[:, 1].max(axis=0)
    lo, hi = (np.asarray(b, np.float64) for b in scene.bounds)
    detail = receiver_detail_box(scene)
    if detail is None:
        return lo, hi
    inner_lo, inner_hi = detail
    margin = RECEIVER_MARGIN * float(np.linalg.norm(inner_hi - inner_lo))
    return np.maximum(inner_lo - margin, lo), np.minimum(inner_hi + margin, hi)


def grid_layout(lo: np.ndarray, hi: np.ndarray, *, cell_size: float = 0.0, vertices: int = 20000) -> GridLayout:
    """Cubic cells over the box [lo, hi] (``irradiance_grid`` docstring, **Grid**); ``cell_size`` 0 = the
    largest grid with at most ``vertices`` vertices (bisection on h)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    extent = np.maximum(hi - lo, 0.0)
    if cell_size > 0:
        h = float(cell_size)
    else:
        scale = max(float(extent.max()), 1e-30)
        small, large = scale * 1e-6, scale * 4.0  # large: 2 vertices per axis; small: far too many
        for _ in range(80):
            mid = math.sqrt(small * large)
            if np.prod(_axis_counts(extent, mid).astype(np.float64)) > vertices:
                small = mid
            else:
                large = mid
        h = large
    counts = _axis_counts(extent, h)
    if np.prod(counts.astype(np.float64)) > MAX_GRID_VERTICES:
        raise ValueError(f"irradiance_grid: cell_size={h:g} gives {int(np.prod(counts.astype(np.float64)))} "
                         f"vertices (more than {MAX_GRID_VERTICES}); choose a larger cell_size")
    centre = 0.5 * (lo + hi)
    cell = np.full(3, h)
    origin = centre - 0.5 * (counts - 1) * h
    return GridLayout(origin, cell, tuple(int(c) for c in counts))


def trilinear(layout: GridLayout, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Corner vertex indices (N, 8) int64 and weights (N, 8) float64 of points (N, 3) (clamped to the grid)."""
    points = np.nan_to_num(np.asarray(points, np.float64).reshape(-1, 3))
    res = np.asarray(layout.resolution, np.int64)
    g = (points - layout.grid_origin) / layout.cell_size
    g = np.clip(g, 0.0, res - 1)
    i0 = np.minimum(np.floor(g).astype(np.int64), np.maximum(res - 2, 0))
    t = np.where(res > 1, g - i0, 0.0)
    i1 = np.minimum(i0 + 1, res - 1)
    index = np.empty((len(points), 8), np.int64)
    weight = np.empty((len(points), 8), np.float64)
    for corner in range(8):
        bits = [(corner >> a) & 1 for a in range(3)]
        c = np.stack([i1[:, a] if bits[a] else i0[:, a] for a in range(3)], axis=1)
        index[:, corner] = c[:, 0] + res[0] * (c[:, 1] + res[1] * c[:, 2])
        weight[:, corner] = np.prod([t[:, a] if bits[a] else 1.0 - t[:, a] for a in range(3)], axis=0)
    return index, weight


RECONSTRUCTIONS = ("paper", "normalized")


def reconstruct_irradiance(layout: GridLayout, vectors: np.ndarray, points: np.ndarray, normals: np.ndarray, *,
                           normal_offset: float = 0.5, reconstruction: str = "paper",
                           behind_cutoff: bool = False) -> np.ndarray:
    """Irradiance E(p, n) (N, 3) float32 (W/m^2) from grid vectors (V, 6, 3, 3) (paper 3.2,
    ``irradiance_grid`` docstring, **Reconstruction**).

    reconstruction : "paper" (E = I_n . n) or "normalized" (E = I_n . n / sum |n_a|^3: exact for a
        uniform sky as well as along the axes). Points with a zero normal get 0.
    behind_cutoff : drop the trilinear corners that lie behind the surface's plane at p
        ((corner - p) . n < 0) and renormalize the others (plain trilinear when all are behind).
    """
    if reconstruction not in RECONSTRUCTIONS:
        raise ValueError(f"reconstruction={reconstruction!r} is not one of {list(RECONSTRUCTIONS)}")
    points = np.asarray(points, np.float64).reshape(-1, 3)
    normals = np.nan_to_num(np.asarray(normals, np.float64).reshape(-1, 3))
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    ok = length[:, 0] > 0.5
    n = np.where(ok[:, None], normals / np.where(length > 0, length, 1.0), 0.0)
    query = points + n * (normal_offset * float(np.min(layout.cell_size)))
    index, weight = trilinear(layout, query)
    if behind_cutoff:
        corners = layout.grid_origin + streaming.grid_coords(layout.resolution)[index] * layout.cell_size
        front = np.einsum("nki,ni->nk", corners - points[:, None, :], n) >= 0.0
        kept = (weight * front).sum(axis=1, keepdims=True)
        weight = np.where(kept > 0, weight * front / np.where(kept > 0, kept, 1.0), weight)
    vectors = np.asarray(vectors, np.float32).reshape(-1, 6, 3, 3)
    result = np.zeros((len(points), 3))
    for axis in range(3):
        hemisphere = 2 * axis + (n[:, axis] < 0)
        interp = np.zeros((len(points), 3, 3))
        for corner in range(8):
            interp += weight[:, corner, None, None] * vectors[index[:, corner], hemisphere]
        result += (n[:, axis] ** 2)[:, None] * np.einsum("nci,ni->nc", interp, n)
    if reconstruction == "normalized":
        result /= np.maximum((np.abs(n) ** 3).sum(axis=1), 1.0 / 3.0 ** 0.5)[:, None]
    result = np.where(ok[:, None], np.maximum(result, 0.0), 0.0)
    return result.astype(np.float32)
