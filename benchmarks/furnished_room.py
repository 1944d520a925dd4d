"""A furnished room lit only by a uniform sky through four windows, on a 200 m ground plane.

The scene of issue 17's vertex-accuracy figure, built like a production interior: the floor and
the ceiling are one quad each (two triangles across 6 x 5 m, so a vertex-only transfer cannot follow
the light across them), the walls are quads around the window openings, the furniture closed boxes
standing on the floor (unwelded from it), the ground a few huge quads with the room's footprint left
out. Z-up, metres; walls, floor and ceiling face into the room (one-sided, as the form factors and
the path tracer treat every face).
"""

from __future__ import annotations

import sys

import numpy as np
from pxr import Gf, Usd, UsdGeom, UsdLux

from . import harness

sys.path.insert(0, str(harness.SAMPLES))  # the samples' mesh and stage helpers (samples/ is not a package)
from mesh_builder import X, Y, Z, MeshBuilder, faces_except  # noqa: E402
from stage_authoring import new_stage, write_mesh  # noqa: E402

ROOM_LO, ROOM_HI = np.array([-3.0, -2.5, 0.0]), np.array([3.0, 2.5, 2.8])
SKY_RADIANCE = 10.0
"""Uniform DomeLight radiance (W/m^2/sr): an unobstructed horizontal surface receives pi times this."""

MATERIALS = {
    "Plaster": ((0.75, 0.73, 0.7), 0.9),
    "Ceiling": ((0.85, 0.85, 0.85), 0.9),
    "Oak": ((0.5, 0.35, 0.2), 0.6),
    "Fabric": ((0.25, 0.3, 0.45), 0.9),
    "Walnut": ((0.3, 0.2, 0.12), 0.5),
    "Grass": ((0.25, 0.3, 0.15), 1.0),
}

FURNITURE = {
    # name: (lo, hi, look): closed boxes, bottoms left open where they stand on the floor
    "TableTop": ((-0.8, -0.45, 0.72), (0.8, 0.45, 0.76), "Walnut"),
    "TableLegA": ((-0.75, -0.4, 0.0), (-0.69, -0.34, 0.72), "Walnut"),
    "TableLegB": ((0.69, -0.4, 0.0), (0.75, -0.34, 0.72), "Walnut"),
    "TableLegC": ((-0.75, 0.34, 0.0), (-0.69, 0.4, 0.72), "Walnut"),
    "TableLegD": ((0.69, 0.34, 0.0), (0.75, 0.4, 0.72), "Walnut"),
    "SofaSeat": ((-2.0, 1.4, 0.0), (0.2, 2.3, 0.45), "Fabric"),
    "SofaBack": ((-2.0, 2.1, 0.45), (0.2, 2.35, 0.9), "Fabric"),
    "Bookshelf": ((1.2, 2.1, 0.0), (2.4, 2.45, 2.0), "Walnut"),
    "Cabinet": ((2.5, -1.5, 0.0), (2.95, -0.3, 0.9), "Walnut"),
    "Bed": ((-2.95, -2.3, 0.0), (-1.3, -0.3, 0.5), "Fabric"),
}


def build() -> Usd.Stage:
    """The furnished room stage, in memory."""
    stage, looks = new_stage(UsdGeom.Tokens.z, 1.0, "furnished room lit by a uniform sky", MATERIALS,
                             root="/World/Room")
    (x0, y0, z0), (x1, y1, z1) = ROOM_LO, ROOM_HI
    floor, ceiling, walls = MeshBuilder(), MeshBuilder(), MeshBuilder()
    floor.box(ROOM_LO, ROOM_HI, faces=("-z",), inward=True)
    ceiling.box(ROOM_LO, ROOM_HI, faces=("+z",), inward=True)
    walls.box(ROOM_LO, ROOM_HI, faces=("+y",), inward=True)  # north wall: solid
    sill, head = 0.9, 2.2
    # Walls as grids over the window stops, the window cells (i, j) skipped. South (y = y0, facing +Y): two.
    walls.grid((x0, y0, z0), Z, X, [0, sill, head, z1 - z0],
               [0, 1.0, 2.4, 3.6, 5.0, x1 - x0], skip={(1, 1), (1, 3)})
    # West wall (x = x0, facing +X) and east wall (x = x1, facing -X): one window each.
    walls.grid((x0, y0, z0), Y, Z, [0, 1.5, 3.2, y1 - y0], [0, sill, head, z1 - z0],
               skip={(1, 1)})
    walls.grid((x1, y0, z0), Z, Y, [0, sill, head, z1 - z0], [0, 2.0, 3.5, y1 - y0],
               skip={(1, 1)})
    for name, builder, look in (("Floor", floor, "Oak"), ("Ceiling", ceiling, "Ceiling"),
                                ("Walls", walls, "Plaster")):
        write_mesh(stage, f"/World/Room/{name}", builder, looks[look])
    for name, (lo, hi, look) in FURNITURE.items():
        box = MeshBuilder()
        box.box(lo, hi, faces=faces_except("-z") if lo[2] == 0.0 else faces_except())
        write_mesh(stage, f"/World/Room/{name}", box, looks[look])
    ground = MeshBuilder()  # 200 x 200 m, the room's footprint left out
    ground.grid((0, 0, 0), X, Y, [-100, x0, x1, 100], [-100, y0, y1, 100], skip={(1, 1)})
    write_mesh(stage, "/World/Ground", ground, looks["Grass"])
    sky = UsdLux.DomeLight.Define(stage, "/World/Lights/Sky")
    sky.CreateIntensityAttr(SKY_RADIANCE)
    sky.CreateColorAttr(Gf.Vec3f(1.0, 1.0, 1.0))
    return stage


def inside_room(points: np.ndarray, margin: float = 1e-3) -> np.ndarray:
    """(N,) bool: points within the room's box (its surfaces included)."""
    return np.all((points >= ROOM_LO - margin) & (points <= ROOM_HI + margin), axis=1)


def room_points(scene, count: int, *, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(count, 3) float32 area-uniform random points on the room's surfaces (faces whose centre lies in
    the room's box), in the Scene's frame, and their (count, 3) face normals."""
    centres = scene.points[scene.tri_vertices].mean(axis=1) + scene.origin
    return harness.surface_points(scene, count, seed=seed, triangles=inside_room(centres))


def interpolate_at(tracer, scene, vertex_values: np.ndarray, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(N, C) per-vertex values of ``scene`` linearly interpolated at surface points (Scene frame): each point
    is found on the mesh by a short ray back along its normal, then barycentric weights of that face."""
    hits = tracer.closest_hit(points + 1e-3 * normals, -normals, 0.01)
    face = np.maximum(hits.hit_triangle, 0)
    tri = scene.tri_vertices[face]
    a, b, c = (scene.points[tri[:, k]].astype(np.float64) for k in range(3))
    e0, e1, e2 = b - a, c - a, points - a
    d00, d01, d11 = (e0 * e0).sum(1), (e0 * e1).sum(1), (e1 * e1).sum(1)
    d20, d21 = (e2 * e0).sum(1), (e2 * e1).sum(1)
    det = np.where(np.abs(d00 * d11 - d01 * d01) > 0, d00 * d11 - d01 * d01, 1.0)
    w1, w2 = (d11 * d20 - d01 * d21) / det, (d00 * d21 - d01 * d20) / det
    w = np.clip(np.stack([1 - w1 - w2, w1, w2], axis=1), 0, 1)
    values = np.einsum("nk,nkc->nc", w / w.sum(axis=1, keepdims=True), vertex_values[tri].astype(np.float64))
    return np.where((hits.hit_triangle >= 0)[:, None], values, np.nan)
