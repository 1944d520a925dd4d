"""Scenes of several prims built without pxr, for the form-factor and radiosity tests: grid quads
and closed boxes, one prim per part.

A plain module (not a conftest): tests/conftest.py puts this folder on sys.path.
"""

from __future__ import annotations

import numpy as np
from usdbake.core.scene import Lights, Scene


def quad(origin, u, v, grid=1):
    """grid x grid quads spanning origin + s u + t v (s, t in [0, 1]), normal along u x v."""
    origin, u, v = (np.asarray(x, np.float64) for x in (origin, u, v))
    s = np.linspace(0, 1, grid + 1)
    points = (origin + s[:, None, None] * u + s[None, :, None] * v).reshape(-1, 3)
    idx = np.arange((grid + 1) ** 2).reshape(grid + 1, grid + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return points, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def box_parts(size=1.0, grid=1):
    """Closed cube [0, size]^3, six faces with inward normals."""
    s = size
    faces = [quad([0, 0, 0], [s, 0, 0], [0, s, 0], grid), quad([0, 0, s], [0, s, 0], [s, 0, 0], grid),
             quad([0, 0, 0], [0, s, 0], [0, 0, s], grid), quad([s, 0, 0], [0, 0, s], [0, s, 0], grid),
             quad([0, 0, 0], [0, 0, s], [s, 0, 0], grid), quad([0, s, 0], [s, 0, 0], [0, 0, s], grid)]
    return faces


def make_scene(parts, *, albedo=(0.5, 0.5, 0.5), emission=None, lights=None, writable=None) -> Scene:
    """A Scene from (points, triangles) parts, one prim per part; per-part albedo rows allowed."""
    points, tris, prim, start = [], [], [], [0]
    for k, (p, t) in enumerate(parts):
        tris.append(np.asarray(t) + start[-1])
        points.append(p)
        prim.append(np.full(len(t), k))
        start.append(start[-1] + len(p))
    points = np.concatenate(points).astype(np.float32)
    tris = np.concatenate(tris).astype(np.int32)
    prim = np.concatenate(prim).astype(np.int32)
    corner = points[tris].astype(np.float64)
    cross = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normals = np.where(area[:, None] > 0, cross / np.maximum(2 * area[:, None], 1e-30), 0.0)
    count, parts_n = len(tris), len(parts)
    albedo = np.asarray(albedo, np.float32)
    tri_albedo = albedo[prim] if albedo.ndim == 2 else np.broadcast_to(albedo, (count, 3)).copy()
    tri_emission = np.zeros((count, 3), np.float32) if emission is None else np.asarray(emission, np.float32)[prim]
    return Scene(
        points=points, tri_vertices=tris, tri_normals=normals.astype(np.float32), tri_areas=area.astype(np.float32),
        tri_albedo=tri_albedo, tri_emission=tri_emission, tri_prim=prim, tri_face=np.arange(count, dtype=np.int32),
        tri_instance=np.full(count, -1, np.int32), tri_double_sided=np.zeros(count, bool),
        point_prim=np.repeat(np.arange(parts_n), np.diff(start)).astype(np.int32),
        prim_paths=tuple(f"/World/part{k}" for k in range(parts_n)), prim_point_start=np.array(start, np.int64),
        prim_face_count=np.bincount(prim, minlength=parts_n).astype(np.int32),
        prim_writable=np.ones(parts_n, bool) if writable is None else np.asarray(writable, bool),
        prim_skip=np.zeros(parts_n, bool), prim_surface=("",) * parts_n, lights=lights or Lights())
