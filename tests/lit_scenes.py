"""Scenes built without pxr for the lighting tests (probes, grid, radiosity): boxes, quads and lights.

A plain module (not a conftest): tests import it with ``from lit_scenes import ...``;
tests/conftest.py puts this folder on sys.path.
"""

from __future__ import annotations

import numpy as np
from usdbake.core.scene import Lights, Scene


def quad(corner, u, v, *, flip=False):
    """Two triangles of the parallelogram corner + [0,1]u + [0,1]v, normal u x v (or -)."""
    c, u, v = (np.asarray(a, np.float32) for a in (corner, u, v))
    points = np.array([c, c + u, c + u + v, c + v], np.float32)
    tris = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    return points, tris[:, ::-1] if flip else tris


def cube(lo, hi, *, inward=False):
    """Closed axis-aligned box, faces outward (or inward), 12 triangles."""
    lo, hi = np.asarray(lo, np.float32), np.asarray(hi, np.float32)
    ex, ey, ez = np.diag(hi - lo).astype(np.float32)
    faces = [
        quad(lo, ey, ex), quad(lo + ez, ex, ey),  # -z, +z
        quad(lo, ex, ez), quad(lo + ey, ez, ex),  # -y, +y
        quad(lo, ez, ey), quad(lo + ex, ey, ez),  # -x, +x
    ]
    return merge([(p, t[:, ::-1] if inward else t) for p, t in faces])


def merge(parts):
    """One (points, triangles) from several, indices offset."""
    points, tris, base = [], [], 0
    for p, t in parts:
        points.append(p)
        tris.append(t + base)
        base += len(p)
    return np.concatenate(points), np.concatenate(tris)


def make_scene(points, tris, *, albedo=0.5, emission=None, double_sided=None, lights=None) -> Scene:
    """One writable prim holding every triangle; albedo a scalar, RGB or per triangle."""
    points = np.asarray(points, np.float32)
    tris = np.asarray(tris, np.int32)
    p = points[tris].astype(np.float64)
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(cross, axis=1)
    normals = np.divide(cross, length[:, None], out=np.zeros_like(cross), where=length[:, None] > 0)
    t = len(tris)
    return Scene(
        points=points, tri_vertices=tris, tri_normals=normals.astype(np.float32),
        tri_areas=(0.5 * length).astype(np.float32),
        tri_albedo=np.broadcast_to(np.asarray(albedo, np.float32), (t, 3)).copy(),
        tri_emission=np.zeros((t, 3), np.float32) if emission is None else np.asarray(emission, np.float32),
        tri_prim=np.zeros(t, np.int32), tri_face=np.arange(t, dtype=np.int32), tri_instance=np.full(t, -1, np.int32),
        tri_double_sided=np.zeros(t, bool) if double_sided is None else np.asarray(double_sided, bool),
        point_prim=np.zeros(len(points), np.int32), prim_paths=("/World/Mesh",),
        prim_point_start=np.array([0, len(points)], np.int64), prim_face_count=np.array([t], np.int32),
        prim_writable=np.ones(1, bool), prim_skip=np.zeros(1, bool), prim_surface=("",),
        lights=lights or Lights(),
    )


def make_lights(*rows) -> Lights:
    """rows: (kind, radiance rgb, position, direction, size)."""
    return Lights(
        light_paths=tuple(f"/World/Light{i}" for i in range(len(rows))),
        light_kind=np.array([r[0] for r in rows], np.int32),
        light_radiance=np.array([r[1] for r in rows], np.float32).reshape(-1, 3),
        light_position=np.array([r[2] for r in rows], np.float32).reshape(-1, 3),
        light_direction=np.array([r[3] for r in rows], np.float32).reshape(-1, 3),
        light_size=np.array([r[4] for r in rows], np.float32).reshape(-1, 2),
    )


def lamp_room_file(directory) -> str:
    """A 6 m room (inward faces) holding a 2 m box, lit by a small SphereLight at (1.5, 1.5, 2.5),
    exported to ``directory/room.usda``; returns the path."""
    from pxr import Gf, UsdLux
    from stage_builders import add_mesh, new_stage

    stage = new_stage(up_axis="Z")
    room_p, room_t = cube([-3, -3, 0], [3, 3, 3], inward=True)
    box_p, box_t = cube([-1, -1, 0], [1, 1, 1])
    points, tris = merge([(room_p, room_t), (box_p, box_t)])
    add_mesh(stage, "/World/Room", points.tolist(), [3] * len(tris), tris.ravel().tolist())
    lamp = UsdLux.SphereLight.Define(stage, "/World/Lamp")
    lamp.CreateRadiusAttr(0.1)
    lamp.CreateIntensityAttr(100.0)
    lamp.AddTranslateOp().Set(Gf.Vec3d(1.5, 1.5, 2.5))
    source = f"{directory}/room.usda"
    stage.GetRootLayer().Export(source)
    return source
