"""Synthetic instanced scenes built without pxr, for the displacement-field and instance AO tests:
an icosphere prototype, ground grids, instance transforms, and a processor runner.

A plain module (not a conftest): tests/conftest.py puts this folder on sys.path.
"""

from __future__ import annotations

import numpy as np
from usdbake import core
from usdbake.core.scene import Instances, Scene


def icosphere(level: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere: (P, 3) float64 points, (T, 3) int32 outward-wound triangles (20 * 4^level)."""
    t = (1 + 5 ** 0.5) / 2
    points = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
              (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
             (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    points = [np.array(p, float) / np.linalg.norm(p) for p in points]
    for _ in range(level):
        cache, new_faces = {}, []

        def middle(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = points[a] + points[b]
                points.append(m / np.linalg.norm(m))
                cache[key] = len(points) - 1
            return cache[key]

        for a, b, c in faces:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            new_faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new_faces
    return np.array(points), np.array(faces, np.int32)


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
