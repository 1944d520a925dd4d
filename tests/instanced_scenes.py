"""Synthetic instanced scenes built without pxr, for the displacement-field and instance AO tests:
an icosphere prototype (samples/mesh_builder.py), ground grids, instance transforms, and a processor runner.

A plain module (not a conftest): tests/conftest.py puts this folder on sys.path.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from usdbake import core
from usdbake.core.scene import Instances, Scene

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "samples"))  # samples/ is not a package
from mesh_builder import icosphere  # noqa: E402,F401  (re-exported: the instancing tests import it from here)


def grid(half: float, cells: int, height: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A (cells x cells) ground grid at y = height facing +Y (points (P, 3), triangles (T, 3))."""
    ticks = np.linspace(-half, half, cells + 1)
    x, z = np.meshgrid(ticks, ticks)
    points = np.c_[x.ravel(), np.full(x.size, height), z.ravel()]
    k = np.arange(cells)
    i, j = np.meshgrid(k, k)
    a = (j * (cells + 1) + i).ravel()
    quads = np.c_[a, a + cells + 1, a + cells + 2, a + 1]
    return points, np.r_[quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]].astype(np.int32)


def translate(x, y, z, scale=(1.0, 1.0, 1.0), rotate_y=0.0) -> np.ndarray:
    """(4, 4) row-vector matrix: scale, then rotate about +Y, then translate."""
    c, s = np.cos(rotate_y), np.sin(rotate_y)
    m = np.diag([*scale, 1.0]) @ np.array([[c, 0, -s, 0], [0, 1, 0, 0], [s, 0, c, 0], [0, 0, 0, 1]])
    m[3, :3] = (x, y, z)
    return m


def build_scene(receivers, prototypes, instances, *, times=None, transforms_at_times=None) -> Scene:
    """A Scene as extraction flattens it.

    receivers : [(path, points, triangles)] writable meshes
    prototypes : [(path, points, triangles)] prototype-space meshes
    instances : [(prototype index, (4, 4) row-vector prototype-to-world matrix)]
    """
    parts = [(path, np.asarray(p, np.float64), t, True, -1) for path, p, t in receivers]
    for j, (proto, matrix) in enumerate(instances):
        path, p, t = prototypes[proto]
        parts.append((path, (np.c_[p, np.ones(len(p))] @ matrix)[:, :3], t, False, j))
    start = np.cumsum([0] + [len(p) for _, p, _, _, _ in parts])
    points = np.concatenate([p for _, p, _, _, _ in parts]).astype(np.float32)
    tris = np.concatenate([t + start[m] for m, (_, _, t, _, _) in enumerate(parts)]).astype(np.int32)
    tri_prim = np.concatenate([np.full(len(t), m, np.int32) for m, (_, _, t, _, _) in enumerate(parts)])
    corners = points[tris].astype(np.float64)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(cross, axis=1)
    normals = np.where(length[:, None] > 0, cross / np.maximum(length, 1e-300)[:, None], 0).astype(np.float32)
    count = len(tris)
    inst = Instances(
        instancer_paths=("/World/Scatter",) if instances else (),
        prototype_paths=tuple(path for path, _, _ in prototypes) if instances else (),
        instance_instancer=np.zeros(len(instances), np.int32),
        instance_prototype=np.array([p for p, _ in instances], np.int32),
        instance_transforms=np.array([m for _, m in instances], np.float64).reshape(-1, 4, 4),
        instance_times=np.zeros(0) if times is None else np.asarray(times, np.float64),
        instance_transforms_at_times=(np.zeros((0, len(instances), 4, 4)) if transforms_at_times is None
                                      else np.asarray(transforms_at_times, np.float64)),
    )
    return Scene(
        points=points, tri_vertices=tris, tri_normals=normals, tri_areas=(length / 2).astype(np.float32),
        tri_albedo=np.full((count, 3), 0.5, np.float32), tri_emission=np.zeros((count, 3), np.float32),
        tri_prim=tri_prim, tri_face=np.arange(count, dtype=np.int32), tri_instance=np.array(
            [parts[m][4] for m in tri_prim], np.int32), tri_double_sided=np.zeros(count, bool),
        point_prim=np.repeat(np.arange(len(parts), dtype=np.int32), np.diff(start)),
        prim_paths=tuple(path for path, _, _, _, _ in parts), prim_point_start=start.astype(np.int64),
        prim_face_count=np.array([len(t) for _, _, t, _, _ in parts], np.int32),
        prim_writable=np.array([w for _, _, _, w, _ in parts], bool), prim_skip=np.zeros(len(parts), bool),
        prim_surface=("",) * len(parts), instances=inst,
    )


def run_processor(cls, scene, params=None, products=None):
    processor = cls()
    return processor.run(core.Context(scene=scene, params=cls.Params.from_dict(params or {}), tracer=None,
                                      products=products or {}))
