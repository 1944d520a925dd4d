"""Instanced receivers: which prims they are and where their results can go (pure numpy).

USD cannot hold per-vertex data on an instance: an instance proxy (native instancing) is
read-only, and a PointInstancer's prototype is one mesh for all its instances. What it can hold:

- a constant primvar on a native instance's root prim, which the prototype's meshes inherit
  (per instance), and a ``vertex`` primvar on a PointInstancer, one value per instance (a
  per-instance primvar): ``per_instance_means`` computes those, an area-weighted mean of a
  per-vertex result over each instance's triangles;
- per-vertex data on the meshes of a native instance that the bake layer de-instances
  (``instanceable = false`` on its roots): extraction with ``deinstance`` makes them ordinary
  receivers of every processor, and ``stages.refined_mesh.complete_outputs`` de-instances them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.scene import Scene


def instanced_receivers(scene: Scene) -> np.ndarray:
    """Prims that are instances (native proxies or PointInstancer prototypes), not bake:skip, with triangles."""
    has_triangles = np.bincount(scene.tri_prim, minlength=len(scene.prim_paths)) > 0
    return np.flatnonzero(~scene.prim_writable & ~scene.prim_skip & has_triangles)


@dataclass(frozen=True)
class InstanceMeans:
    """Per-instance means of a per-vertex result."""

    native: dict[str, float]
    """Outermost native instance root path -> mean over every mesh under it."""
    instancers: dict[str, np.ndarray]
    """PointInstancer path -> (authored instances,) float32, one per protoIndices row (``fill`` for masked rows)."""


def per_instance_means(scene: Scene, point_values: np.ndarray, prims: np.ndarray, *, fill: float) -> InstanceMeans:
    """Area-weighted means of ``point_values`` (per Scene point) over each instance's triangles.

    A triangle's value is the mean of its corners; degenerate triangles weigh nothing. Native
    instances are keyed by their outermost root, PointInstancer instances by row.
    """
    tris = np.flatnonzero(np.isin(scene.tri_prim, prims))
    values = np.asarray(point_values, np.float64)[scene.tri_vertices[tris]].mean(axis=1)
    weights = scene.tri_areas[tris].astype(np.float64)

    native: dict[str, float] = {}
    roots = np.array([scene.prim_instance_roots[p][0] if scene.prim_instance_roots[p] else ""
                      for p in range(len(scene.prim_paths))], object)
    tri_root = roots[scene.tri_prim[tris]]
    for root in sorted(set(tri_root.tolist()) - {""}):
        mine = tri_root == root
        native[root] = _weighted_mean(values[mine], weights[mine], fill)

    instancers: dict[str, np.ndarray] = {}
    table = scene.instances
    instance = scene.tri_instance[tris]
    if len(table):
        used = instance >= 0
        total = np.bincount(instance[used], weights=values[used] * weights[used], minlength=len(table))
        weight = np.bincount(instance[used], weights=weights[used], minlength=len(table))
        baked = np.bincount(instance[used], minlength=len(table)) > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            means = np.where(weight > 0, total / weight, fill)
        authored_rows = len(table.instance_index) == len(table)  # else: a Scene not read from USD
        for index, path in enumerate(table.instancer_paths):
            rows = np.flatnonzero(table.instance_instancer == index)
            if table.is_native(index) or not baked[rows].any():
                continue  # a native instance is keyed by its root above
            slots = table.instance_index[rows] if authored_rows else np.arange(len(rows))
            count = int(table.instancer_instance_count[index]) if authored_rows else len(rows)
            column = np.full(count, fill, np.float32)
            column[slots] = means[rows]
            instancers[path] = column
    return InstanceMeans(native, instancers)


def _weighted_mean(values: np.ndarray, weights: np.ndarray, fill: float) -> float:
    total = float(weights.sum())
    return float((values * weights).sum() / total) if total > 0 else fill
