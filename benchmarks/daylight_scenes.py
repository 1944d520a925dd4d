"""Daylight scenes of issue 29 (interreflections, glazing, photometry) and their Radiance references.

Two stages, Z-up, metres, x east, y north (usdbake's ``enu_to_world('Z')`` with ``north`` 0, Radiance's
frame in ``radiance_reference``), every face's material a UsdPreviewSurface bound to its mesh
(``diffuseColor``; glass: ``inputs:opacity`` = 1 - VLT and a float ``bake:transmittance`` = VLT on the
glass mesh prim, so either reading of ``stages/materials.py`` finds the VLT):

``lm83_office()``
    An IES LM-83-style side-lit office, 6 m wide (x) x 10 m deep (y) x 3 m high, its one glazed facade
    facing **south** (the y = 0 wall, the window's outward normal -y). Window band: sill 0.9 m, head
    2.4 m, 4.8 m wide centred (x 0.6 .. 5.4): window-to-wall ratio 7.2 / 18 = 0.40. Reflectances (grey):
    floor 0.2, walls 0.5, ceiling 0.7; one glass pane of VLT 0.6 fills the opening. Walls, floor and
    ceiling are **single faces facing into the room** (no thickness, no reveals), the box closed by the
    glass; no ground in the stage (gendaymtx and usdbake's ground parameter add one of 0.2 below the
    horizon). Sensors: LM-83 puts them on a work plane 0.76 m high on a 0.6 m grid; usdbake reports per
    face of receiving meshes, so the **floor** is the sensor surface here: a 0.6 m grid (10 x 17 = 170
    points, 0.3 m from the walls, at the centres of the floor's 0.2 m cells), 1 mm above the floor,
    normals up. The floor is tessellated in 0.2 m squares (``floor_cell``), so each sensor lies in a face
    of its own (on the diagonal shared by the two triangles of a square: ``sample_baked`` averages faces
    that contain a point).

``furnished_daylight_room()``
    A furnished living room of our own, 8 x 6 x 2.8 m inside, 0.25 m thick walls and roof (inner and
    outer faces, reveals around the openings: a closed solid, so one- and two-sided surfaces agree), four
    windows (two south, one west, one east; sill 0.9 m, head 2.2 m) each holding a glass pane of VLT 0.7
    in the middle of the wall, furnished with open bookshelves of books, a sofa and an armchair with
    cushions, a dining table and six chairs, a coffee table, a TV cabinet, lamps, plants, a rug (floor
    cells of its own, so nothing covers the floor but feet and pots) and small objects: tessellated boxes
    (every face its own vertices: unwelded creases), cylinders (caps unwelded from the side) and spheres,
    RGB materials, closed solids wound outward, ~129k triangles; on a 200 m x 200 m ground of
    albedo 0.2 (the building's footprint left out, so the ground does not overlap the floor). Lit by a
    uniform sky (``SKY_RADIANCE``; the stage has its own ground, so no ground glow below the horizon).
    Sensors: ``random_surface_points`` (area-uniform on the surfaces inside the room, fixed seed).

Each returns a ``DaylightScene``; its first six fields unpack as (stage, sensor_points, sensor_normals,
triangles, albedo, transmittance). The Radiance side reads the geometry back from the stage with pxr
(``stage_triangles``: world positions, fan-triangulated faces, bound materials), not from the generator,
so both sides see the same triangles. ``sample_baked`` reads usdbake's per-face results of a baked stage
at the sensor points. ``office_reference`` and ``furnished_reference`` compute the Radiance references
(cached in benchmarks/cache by ``harness.cached_reference``).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

from . import harness

sys.path.insert(0, str(harness.SAMPLES))  # the samples' mesh and stage helpers (samples/ is not a package)
from mesh_builder import X, Y, Z, MeshBuilder, faces_except, icosphere, ticks  # noqa: E402
from stage_authoring import make_material, new_stage, write_mesh  # noqa: E402

SCENES_VERSION = 1
"""Bump when a scene's geometry or materials change (part of the reference cache keys)."""
TRANSMITTANCE_ATTR = "bake:transmittance"
SENSOR_OFFSET = 1e-3
"""Metres: sensors and random points are traced from 1 mm off their surface, along the normal."""

# --------------------------------------------------------------------------- the LM-83 office

OFFICE_SIZE = (6.0, 10.0, 3.0)
"""Width (x, along the facade), depth (y, away from it), height (z), metres."""
OFFICE_WINDOW = ((0.6, 5.4), (0.9, 2.4))
"""The window opening in the south wall (y = 0): (x range, z range), metres: 7.2 m^2 of 18 m^2."""
OFFICE_REFLECTANCE = {"Floor": 0.2, "Walls": 0.5, "Ceiling": 0.7}
OFFICE_VLT = 0.6
OFFICE_SENSOR_SPACING = 0.6
"""LM-83's grid spacing (metres); the first row and column 0.3 m from the walls."""
GLASS_REFLECTANCE = 0.1
"""diffuseColor authored on glass: about the hemispherical reflectance of Radiance ``glass`` of VLT 0.6-0.7
(n = 1.52, ~0.06 at normal incidence, rising at grazing angles). Radiance reflects it specularly and ignores
this value; a diffuse reader gets the same energy back."""


@dataclass(frozen=True)
class DaylightScene:
    """A stage, its sensors and its geometry as the Radiance side reads it back (``stage_triangles``).

    Unpacks as (stage, sensor_points, sensor_normals, triangles, albedo, transmittance)."""

    stage: Usd.Stage
    sensor_points: np.ndarray
    """(S, 3) float64 world positions (metres), on (or, for the office floor, 1 mm above) their surface."""
    sensor_normals: np.ndarray
    """(S, 3) float64 unit normals of the sensors' surfaces."""
    triangles: np.ndarray
    """(T, 3, 3) float64 world positions of every triangle of every mesh (fan-triangulated faces)."""
    albedo: np.ndarray
    """(T, 3) float64 RGB diffuse reflectance (the bound UsdPreviewSurface's diffuseColor)."""
    transmittance: np.ndarray
    """(T,) float64 VLT at normal incidence: ``bake:transmittance``, else 1 - opacity; 0 opaque."""
    sensor_prims: tuple = ()
    """(S,) prim path of the mesh each sensor lies on."""
    tri_prim: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """(T,) int64 index into ``prim_paths`` of each triangle's mesh."""
    prim_paths: tuple = ()
    """The mesh prim paths, in ``stage_triangles`` order."""

    def __iter__(self):
        return iter((self.stage, self.sensor_points, self.sensor_normals, self.triangles, self.albedo,
                     self.transmittance))


def _glass_material(stage, name: str, vlt: float):
    """A UsdPreviewSurface glass: opacity = 1 - VLT, ior 1.52, diffuseColor ``GLASS_REFLECTANCE``; the VLT also
    as ``bake:transmittance`` on the Material."""
    material = make_material(stage, name, (GLASS_REFLECTANCE,) * 3, 0.0)
    shader = UsdShade.Shader(stage.GetPrimAtPath(f"/World/Looks/{name}/PreviewSurface"))
    shader.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(float(1.0 - vlt))
    shader.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(1.52)
    material.GetPrim().CreateAttribute(TRANSMITTANCE_ATTR, Sdf.ValueTypeNames.Float).Set(float(vlt))
    return material


def _write_glass(stage, path: str, builder: MeshBuilder, material, vlt: float):
    mesh = write_mesh(stage, path, builder, material)
    mesh.GetPrim().CreateAttribute(TRANSMITTANCE_ATTR, Sdf.ValueTypeNames.Float).Set(float(vlt))
    return mesh


def office_stage(*, floor_cell: float = 0.2, surface_cell: float = 0.5, vlt: float = OFFICE_VLT) -> Usd.Stage:
    """The LM-83-style office (module docstring), in memory; floor in ``floor_cell`` squares, walls and
    ceiling in cells of about ``surface_cell`` metres."""
    w, d, h = OFFICE_SIZE
    (wx0, wx1), (wz0, wz1) = OFFICE_WINDOW
    looks = {name: ((r, r, r), 0.9) for name, r in OFFICE_REFLECTANCE.items()}
    stage, mats = new_stage(UsdGeom.Tokens.z, 1.0, "IES LM-83-style side-lit office (issue 29)", looks,
                            root="/World/Office")
    glass = _glass_material(stage, "Glass", vlt)
    floor, ceiling, walls, pane = MeshBuilder(), MeshBuilder(), MeshBuilder(), MeshBuilder()
    lo, hi = (0.0, 0.0, 0.0), (w, d, h)
    steps = lambda cell: (cell, cell, cell)  # noqa: E731
    floor.box(lo, hi, faces=("-z",), steps=steps(floor_cell), inward=True)
    ceiling.box(lo, hi, faces=("+z",), steps=steps(surface_cell), inward=True)
    walls.box(lo, hi, faces=("+y", "-x", "+x"), steps=steps(surface_cell), inward=True)
    # South wall (y = 0, facing +y into the room): a grid over the window's stops, the opening skipped.
    zs = _ticks([0.0, wz0, wz1, h], surface_cell)
    xs = _ticks([0.0, wx0, wx1, w], surface_cell)
    opening = {(i, j) for i in range(len(zs) - 1) for j in range(len(xs) - 1)
               if wz0 <= zs[i] < wz1 and wx0 <= xs[j] < wx1}
    walls.grid((0.0, 0.0, 0.0), Z, X, zs, xs, skip=opening)
    pane.grid((0.0, 0.0, 0.0), Z, X, [wz0, wz1], [wx0, wx1])  # the glass, facing into the room
    for name, builder in (("Floor", floor), ("Ceiling", ceiling), ("Walls", walls)):
        write_mesh(stage, f"/World/Office/{name}", builder, mats[name])
    _write_glass(stage, "/World/Office/Glazing", pane, glass, vlt)
    return stage


def _ticks(stops, step: float) -> np.ndarray:
    """Values through every stop, at most ``step`` apart."""
    return ticks(stops, step)


def office_sensors(spacing: float = OFFICE_SENSOR_SPACING, height: float = SENSOR_OFFSET
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(S, 3) float64 floor sensors on the LM-83 grid (``height`` above the floor) and their (S, 3) up normals,
    row by row from the window (y) and west to east (x)."""
    w, d, _ = OFFICE_SIZE
    xs = np.arange(spacing / 2, w, spacing)
    ys = np.arange(spacing / 2, d, spacing)
    gy, gx = np.meshgrid(ys, xs, indexing="ij")
    points = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, height)])
    return points, np.tile([0.0, 0.0, 1.0], (len(points), 1))


def lm83_office(*, floor_cell: float = 0.2, surface_cell: float = 0.5, vlt: float = OFFICE_VLT) -> DaylightScene:
    """The office stage, its floor sensors and its triangles read back from the stage."""
    stage = office_stage(floor_cell=floor_cell, surface_cell=surface_cell, vlt=vlt)
    points, normals = office_sensors()
    geometry = stage_triangles(stage)
    return DaylightScene(stage, points, normals, geometry.triangles, geometry.albedo, geometry.transmittance,
                         sensor_prims=("/World/Office/Floor",) * len(points), tri_prim=geometry.tri_prim,
                         prim_paths=geometry.prim_paths)


def window_to_wall_ratio(scene: DaylightScene, wall_normal=(0.0, 1.0, 0.0)) -> float:
    """Glazed area / (glazed + opaque area) of the wall whose inward normal is ``wall_normal``, from the
    triangles (the facade: opaque faces in the plane of the glass with that normal)."""
    tri = scene.triangles
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normal = cross / np.maximum(2.0 * area, 1e-300)[:, None]
    glazed = scene.transmittance > 0
    plane = float(tri[glazed][:, :, 1].mean())  # the facade's y
    facade = (normal @ np.asarray(wall_normal) > 0.99) & (np.abs(tri[:, :, 1] - plane).max(axis=1) < 1e-6)
    return float(area[facade & glazed].sum() / area[facade].sum())


# --------------------------------------------------------------------------- the furnished room

ROOM_LO, ROOM_HI = np.array([-4.0, -3.0, 0.0]), np.array([4.0, 3.0, 2.8])
"""The room's interior box, metres."""
WALL = 0.25
"""Wall and roof thickness, metres."""
ROOM_VLT = 0.7
SKY_RADIANCE = 1000.0 / np.pi
"""Uniform sky radiance, W/(m^2 sr): an unobstructed horizontal surface receives 1000 W/m^2."""
SILL, HEAD = 0.9, 2.2
ROOM_RUG = ((-3.2, -0.4), (-2.2, -0.8))
"""The rug's (x, y) extent: floor cells of their own (coplanar with the floor, covering none of it)."""
ROOM_WINDOWS = {
    # name: (wall, (lo, hi) along the wall's horizontal axis): x for the south wall, y for west / east.
    "SouthWest": ("-y", (-3.0, -1.2)),
    "SouthEast": ("-y", (0.5, 2.5)),
    "West": ("-x", (-1.0, 1.0)),
    "East": ("+x", (0.5, 2.0)),
}
ROOM_MATERIALS = {
    "Plaster": ((0.75, 0.73, 0.70), 0.9),
    "Ceiling": ((0.85, 0.85, 0.85), 0.9),
    "Oak": ((0.50, 0.35, 0.20), 0.6),
    "Walnut": ((0.30, 0.20, 0.12), 0.5),
    "Render": ((0.60, 0.58, 0.55), 0.9),
    "Ground": ((0.20, 0.20, 0.20), 1.0),
    "FabricBlue": ((0.15, 0.25, 0.50), 0.9),
    "FabricRed": ((0.60, 0.12, 0.10), 0.9),
    "FabricMustard": ((0.70, 0.55, 0.15), 0.9),
    "Rug": ((0.45, 0.30, 0.35), 1.0),
    "Leaf": ((0.10, 0.35, 0.10), 0.7),
    "Terracotta": ((0.60, 0.30, 0.18), 0.8),
    "Metal": ((0.55, 0.55, 0.58), 0.4),
    "Shade": ((0.90, 0.85, 0.70), 0.9),
    "White": ((0.80, 0.80, 0.80), 0.5),
    "Black": ((0.05, 0.05, 0.05), 0.5),
    "BookA": ((0.55, 0.10, 0.10), 0.8),
    "BookB": ((0.10, 0.20, 0.45), 0.8),
    "BookC": ((0.15, 0.40, 0.20), 0.8),
    "BookD": ((0.80, 0.70, 0.45), 0.8),
    "BookE": ((0.25, 0.25, 0.25), 0.8),
    "BookF": ((0.70, 0.40, 0.10), 0.8),
}
AXES_Y_TO_Z = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Rows: where a Y-up builder's local x, y, z go in the Z-up stage (a proper rotation: windings kept)."""


def _cylinder(builder: MeshBuilder, center, radius: float, z0: float, z1: float, segments: int = 32,
              rings: int = 1, bottom: bool = True, top: bool = True, profile=None):
    """A Z-up closed cylinder of ``radius`` from height ``z0`` to ``z1`` about the vertical through ``center``
    (its x, y; heights are absolute) or, with ``profile`` [(radius, height), ...] climbing the outside, a
    lathe solid; the caps and the side separate lathes: unwelded rims."""
    local = MeshBuilder()
    side = profile if profile is not None else [(radius, z0 + (z1 - z0) * k / rings) for k in range(rings + 1)]
    side = np.asarray(side, float)
    if bottom and side[0, 0] > 0:
        local.lathe([(0.0, side[0, 1]), tuple(side[0])], segments)
    local.lathe(side, segments)
    if top and side[-1, 0] > 0:
        local.lathe([tuple(side[-1]), (0.0, side[-1, 1])], segments)
    builder.extend(local, AXES_Y_TO_Z, (center[0], center[1], 0.0))


def _sphere(builder: MeshBuilder, center, radii, level: int = 3):
    """An ellipsoid (icosphere of 20 * 4^level triangles, scaled per axis)."""
    points, faces = icosphere(level)
    builder.add(points * np.asarray(radii, float) + np.asarray(center, float), np.full(len(faces), 3), faces)


def _box(builder: MeshBuilder, lo, hi, cell: float | None = None, faces=None):
    """A box with every face its own vertices; no bottom when it stands on the floor (z = 0)."""
    faces = faces if faces is not None else (faces_except("-z") if lo[2] <= 0.0 else faces_except())
    builder.box(lo, hi, faces=faces, steps=(cell, cell, cell))


def _shell(cell: float) -> dict[str, MeshBuilder]:
    """Inner walls, floor, ceiling (facing in), the outer shell (facing out), the reveals and the panes."""
    (x0, y0, z0), (x1, y1, z1) = ROOM_LO, ROOM_HI
    t = WALL
    parts = {name: MeshBuilder() for name in ("Floor", "Ceiling", "Walls", "Exterior", "Reveals", "Glazing")}
    xs, ys = _ticks([x0, *ROOM_RUG[0], x1], cell), _ticks([y0, *ROOM_RUG[1], y1], cell)
    rug = {(i, j) for i in range(len(xs) - 1) for j in range(len(ys) - 1)
           if ROOM_RUG[0][0] <= xs[i] < ROOM_RUG[0][1] and ROOM_RUG[1][0] <= ys[j] < ROOM_RUG[1][1]}
    parts["Floor"].grid((0, 0, z0), X, Y, xs, ys, skip=rug)  # facing up
    parts["Rug"] = MeshBuilder()
    parts["Rug"].grid((0, 0, z0), X, Y, _ticks(ROOM_RUG[0], cell), _ticks(ROOM_RUG[1], cell))
    parts["Ceiling"].box(ROOM_LO, ROOM_HI, faces=("+z",), steps=(cell,) * 3, inward=True)
    outer_lo, outer_hi = ROOM_LO - [t, t, 0.0], ROOM_HI + [t, t, t]
    parts["Exterior"].box(outer_lo, outer_hi, faces=("+z", "+y"), steps=(1.0,) * 3)  # roof, north
    windows = {wall: [span for name, (w, span) in ROOM_WINDOWS.items() if w == wall] for wall in ("-y", "-x", "+x")}

    def wall_grid(builder, origin, axis_u, axis_v, u_stops, v_stops, spans, horizontal_is_u, step):
        """A planar grid through the window stops, the openings skipped (u, v: the grid's axes)."""
        us, vs = _ticks(u_stops, step), _ticks(v_stops, step)
        skip = set()
        for i in range(len(us) - 1):
            for j in range(len(vs) - 1):
                a, b = (us[i], vs[j]) if horizontal_is_u else (vs[j], us[i])  # (horizontal, height)
                if SILL <= b < HEAD and any(lo <= a < hi for lo, hi in spans):
                    skip.add((i, j))
        builder.grid(origin, axis_u, axis_v, us, vs, skip=skip)

    def stops(spans, lo, hi):
        return sorted({lo, hi, *[v for span in spans for v in span]})

    walls, exterior = parts["Walls"], parts["Exterior"]
    walls.box(ROOM_LO, ROOM_HI, faces=("+y",), steps=(cell,) * 3, inward=True)  # north wall: solid
    # South (y = y0): inner faces +y (u = z, v = x), outer faces -y at y0 - t (u = x, v = z).
    wall_grid(walls, (0, y0, 0), Z, X, [z0, SILL, HEAD, z1], stops(windows["-y"], x0, x1), windows["-y"], False, cell)
    wall_grid(exterior, (0, y0 - t, 0), X, Z, stops(windows["-y"], x0 - t, x1 + t), [z0, SILL, HEAD, z1 + t],
              windows["-y"], True, 1.0)
    # West (x = x0): inner faces +x (u = y, v = z), outer -x (u = z, v = y).
    wall_grid(walls, (x0, 0, 0), Y, Z, stops(windows["-x"], y0, y1), [z0, SILL, HEAD, z1], windows["-x"], True, cell)
    wall_grid(exterior, (x0 - t, 0, 0), Z, Y, [z0, SILL, HEAD, z1 + t], stops(windows["-x"], y0 - t, y1 + t),
              windows["-x"], False, 1.0)
    # East (x = x1): inner faces -x (u = z, v = y), outer +x (u = y, v = z).
    wall_grid(walls, (x1, 0, 0), Z, Y, [z0, SILL, HEAD, z1], stops(windows["+x"], y0, y1), windows["+x"], False, cell)
    wall_grid(exterior, (x1 + t, 0, 0), Y, Z, stops(windows["+x"], y0 - t, y1 + t), [z0, SILL, HEAD, z1 + t],
              windows["+x"], True, 1.0)
    # Reveals (sill, head, jambs) facing into each opening, and the panes in the middle of the wall.
    reveals, glazing = parts["Reveals"], parts["Glazing"]
    for wall, (lo, hi) in ROOM_WINDOWS.values():
        if wall == "-y":
            inner, outward = y0, np.array([0.0, -1.0, 0.0])
            a = lambda s, z, depth: (s, inner - depth, z)  # noqa: E731
        else:
            inner = x0 if wall == "-x" else x1
            sign = -1.0 if wall == "-x" else 1.0
            outward = np.array([sign, 0.0, 0.0])
            a = lambda s, z, depth, inner=inner, sign=sign: (inner + sign * depth, s, z)  # noqa: E731
        corners = lambda s0, z0_, s1, z1_, depth0, depth1: [a(s0, z0_, depth0), a(s1, z1_, depth0),  # noqa: E731
                                                             a(s1, z1_, depth1), a(s0, z0_, depth1)]
        centre = np.array(a(0.5 * (lo + hi), 0.5 * (SILL + HEAD), 0.5 * t))
        edges = ((lo, SILL, hi, SILL), (lo, HEAD, hi, HEAD), (lo, SILL, lo, HEAD), (hi, SILL, hi, HEAD))
        for s0, z0_, s1, z1_ in edges:  # sill, head, jambs
            quad = np.array(corners(s0, z0_, s1, z1_, 0.0, t))
            facing = centre - quad.mean(axis=0)
            facing -= outward * (facing @ outward)  # into the opening, in the wall's plane
            reveals.polygon(quad, facing=facing)
        pane = np.array([a(lo, SILL, 0.5 * t), a(hi, SILL, 0.5 * t), a(hi, HEAD, 0.5 * t), a(lo, HEAD, 0.5 * t)])
        glazing.polygon(pane, facing=-outward)  # facing into the room
    return parts


def _furniture() -> dict[str, tuple[MeshBuilder, str]]:
    """The furnishings: {prim name: (builder, material name)}. No two solids overlap: every face sees light."""
    parts: dict[str, tuple[MeshBuilder, str]] = {}

    def add(name: str, look: str) -> MeshBuilder:
        builder = MeshBuilder()
        parts[name] = (builder, look)
        return builder

    rng = np.random.default_rng(29)  # fixed: the same books, heights and leaves on every build
    # Bookshelves on the north wall (y = 3.0), open at the back (the wall is their back, 1 cm behind): two
    # sides, six shelves from 0.1 m (a kick space), books in groups with gaps (about half the shelf length).
    for k, x_lo in enumerate((-3.6, -1.4)):
        frame = add(f"Bookshelf{k}", "Walnut")
        x_hi, y_lo, y_hi, z_hi = x_lo + 2.0, 2.6, 2.99, 2.1
        for side in (x_lo, x_hi - 0.03):
            _box(frame, (side, y_lo, 0.0), (side + 0.03, y_hi, z_hi), cell=0.1)
        shelves = np.linspace(0.1, z_hi - 0.03, 6)
        for z in shelves:
            _box(frame, (x_lo + 0.03, y_lo, z), (x_hi - 0.03, y_hi, z + 0.03), cell=0.1)
        books = [add(f"Books{k}{look}", f"Book{look}") for look in "ABCDEF"]
        for z_lo, z_next in zip(shelves[:-1] + 0.03, shelves[1:]):
            x, group = x_lo + 0.05 + rng.uniform(0.0, 0.2), int(rng.integers(4, 12))
            while True:
                width = rng.uniform(0.02, 0.05)
                if x + width > x_hi - 0.06:
                    break
                height = min(rng.uniform(0.18, 0.30), z_next - z_lo - 0.02)
                depth = rng.uniform(0.14, 0.22)
                b = books[int(rng.integers(6))]
                _box(b, (x, y_hi - depth, z_lo + 0.002), (x + width, y_hi, z_lo + 0.002 + height),
                     faces=faces_except("-z"))
                x += width + rng.uniform(0.004, 0.012)
                group -= 1
                if group == 0:  # a gap, then the next group
                    x, group = x + rng.uniform(0.15, 0.4), int(rng.integers(4, 12))
    # Sofa (south-facing, against nothing) on legs, its cushions, and an armchair.
    sofa = add("Sofa", "FabricBlue")
    _box(sofa, (-3.0, -0.6, 0.12), (-0.6, 0.3, 0.42), cell=0.1)  # seat
    _box(sofa, (-3.0, 0.32, 0.12), (-0.6, 0.55, 0.95), cell=0.1)  # back
    for x in (-3.0, -0.75):
        _box(sofa, (x, -0.6, 0.43), (x + 0.15, 0.3, 0.65), cell=0.1)  # arms
    legs = add("SofaLegs", "Walnut")
    for x, y in ((-2.95, -0.55), (-0.7, -0.55), (-2.95, 0.45), (-0.7, 0.45)):
        _cylinder(legs, (x, y, 0.0), 0.025, 0.0, 0.119, segments=16, bottom=False)
    cushions = add("Cushions", "FabricRed")
    for x in (-2.5, -1.8, -1.1):
        _sphere(cushions, (x, 0.23, 0.70), (0.2, 0.08, 0.18), level=3)
    seat_cushions = add("SeatCushions", "FabricMustard")
    for x in (-2.33, -1.27):
        _sphere(seat_cushions, (x, -0.17, 0.47), (0.47, 0.38, 0.045), level=3)
    chair = add("Armchair", "FabricMustard")
    _box(chair, (1.9, -0.2, 0.12), (2.75, 0.6, 0.42), cell=0.1)
    _box(chair, (2.77, -0.2, 0.12), (2.97, 0.6, 0.95), cell=0.1)
    chair_legs = add("ArmchairLegs", "Walnut")
    for x, y in ((1.95, -0.15), (2.92, -0.15), (1.95, 0.55), (2.92, 0.55)):
        _cylinder(chair_legs, (x, y, 0.0), 0.025, 0.0, 0.119, segments=16, bottom=False)
    _sphere(add("ArmchairCushion", "FabricRed"), (2.62, 0.2, 0.62), (0.08, 0.2, 0.18), level=3)
    # Coffee table on the rug (``ROOM_RUG``: part of the floor, see ``_shell``), with a bowl of fruit.
    table = add("CoffeeTable", "Oak")
    _box(table, (-2.4, -1.9, 0.40), (-1.2, -1.1, 0.44), cell=0.05)
    for x, y in ((-2.35, -1.85), (-1.25, -1.85), (-2.35, -1.15), (-1.25, -1.15)):
        _cylinder(table, (x, y, 0.0), 0.025, 0.0, 0.399, segments=24, bottom=False)
    bowl = add("Bowl", "White")
    _cylinder(bowl, (-1.8, -1.5, 0.441), 0.0, 0.0, 0.0, segments=48,
              profile=[(0.06, 0.441), (0.12, 0.47), (0.15, 0.52)])
    fruit = add("Fruit", "FabricMustard")
    for dx, dy in ((-0.04, 0.0), (0.05, 0.03), (0.0, -0.05)):
        _sphere(fruit, (-1.8 + dx, -1.5 + dy, 0.561), (0.04, 0.04, 0.04), level=3)
    # Dining table with six chairs (east half of the room).
    dining = add("DiningTable", "Oak")
    _box(dining, (0.6, -2.2, 0.72), (2.4, -1.2, 0.76), cell=0.05)
    for x, y in ((0.68, -2.12), (2.32, -2.12), (0.68, -1.28), (2.32, -1.28)):
        _cylinder(dining, (x, y, 0.0), 0.035, 0.0, 0.719, segments=24, rings=4, bottom=False)
    for k, (x, y, back) in enumerate(((0.9, -2.65, -1), (1.5, -2.65, -1), (2.1, -2.65, -1),
                                       (0.9, -0.75, 1), (1.5, -0.75, 1), (2.1, -0.75, 1))):
        c = add(f"Chair{k}", "Walnut")
        _box(c, (x - 0.2, y - 0.2, 0.44), (x + 0.2, y + 0.2, 0.47), cell=0.05)  # seat
        by = y + back * 0.2
        _box(c, (x - 0.2, min(by, by - back * 0.03), 0.48), (x + 0.2, max(by, by - back * 0.03), 0.9), cell=0.05)
        for dx in (-0.17, 0.17):
            for dy in (-0.17, 0.17):
                _cylinder(c, (x + dx, y + dy, 0.0), 0.018, 0.0, 0.439, segments=16, bottom=False)
    # Candle holders and glasses on the dining table.
    tableware = add("Tableware", "White")
    for x in np.linspace(0.9, 2.1, 5):
        _cylinder(tableware, (x, -1.7, 0.761), 0.0, 0.0, 0.0, segments=32,
                  profile=[(0.035, 0.761), (0.03, 0.78), (0.012, 0.80), (0.01, 0.86), (0.04, 0.93)])
    # TV cabinet with a screen (west wall, north of the window) and a floor lamp, table lamps.
    cabinet = add("Cabinet", "Walnut")
    _box(cabinet, (-3.95, 1.3, 0.12), (-3.5, 2.5, 0.55), cell=0.05)  # on legs
    for x, y in ((-3.9, 1.35), (-3.55, 1.35), (-3.9, 2.45), (-3.55, 2.45)):
        _cylinder(cabinet, (x, y, 0.0), 0.02, 0.0, 0.119, segments=16, bottom=False)
    screen = add("Screen", "Black")
    _box(screen, (-3.9, 1.45, 0.6), (-3.85, 2.35, 1.15), cell=0.05)
    _cylinder(screen, (-3.88, 1.9, 0.551), 0.06, 0.551, 0.599, segments=24, bottom=False)
    for k, (x, y) in enumerate(((-0.3, 0.4), (3.4, 1.0), (3.5, -2.5))):
        lamp = add(f"FloorLamp{k}", "Metal")
        _cylinder(lamp, (x, y, 0.0), 0.15, 0.0, 0.03, segments=48, bottom=False)
        _cylinder(lamp, (x, y, 0.031), 0.012, 0.031, 1.449, segments=16, rings=8, bottom=False)
        shade = add(f"LampShade{k}", "Shade")
        _cylinder(shade, (x, y, 0.0), 0.0, 0.0, 0.0, segments=64,
                  profile=[(0.22 - 0.008 * i, 1.45 + 0.03 * i) for i in range(11)])  # a closed cone
    for k, (x, y, z) in enumerate(((-3.72, 2.2, 0.551), (2.3, -1.45, 0.761))):
        lamp = add(f"TableLamp{k}", "Terracotta")
        _cylinder(lamp, (x, y, z), 0.0, 0.0, 0.0, segments=48,
                  profile=[(0.05, z), (0.09, z + 0.05), (0.1, z + 0.12), (0.07, z + 0.2), (0.015, z + 0.24)])
        _sphere(add(f"TableLampShade{k}", "Shade"), (x, y, z + 0.36), (0.12, 0.12, 0.1), level=3)
    # Plants: pots with spherical leaves (room corners and by the windows).
    leaves_builder = add("Leaves", "Leaf")
    for k, (x, y, scale) in enumerate(((3.6, 2.6, 1.0), (-3.65, -2.65, 0.8), (0.1, -2.6, 0.6), (3.65, -1.0, 0.7))):
        pot = add(f"Pot{k}", "Terracotta")
        _cylinder(pot, (x, y, 0.0), 0.0, 0.0, 0.0, segments=48, bottom=False,
                  profile=[(0.12 * scale, 0.0), (0.16 * scale, 0.3 * scale), (0.17 * scale, 0.32 * scale)])
        for _ in range(30):
            r = rng.uniform(0.04, 0.07) * scale
            centre = np.clip((x + rng.normal(0, 0.12 * scale), y + rng.normal(0, 0.12 * scale),
                              0.32 * scale + 0.05 + rng.uniform(0.1, 0.9) * scale),
                             ROOM_LO + 0.1, ROOM_HI - 0.1)  # leaves stay off the walls
            _sphere(leaves_builder, centre, (r, r * 0.6, r * 0.25), level=2)
    # Ornaments on the bookshelves' top and on the cabinet: vases and balls.
    ornaments = add("Ornaments", "White")
    for x in (-3.3, -2.2, -0.9, 0.2):
        _cylinder(ornaments, (x, 2.78, 2.101), 0.0, 0.0, 0.0, segments=48,
                  profile=[(0.05, 2.101), (0.09, 2.2), (0.06, 2.32), (0.03, 2.4), (0.045, 2.45)])
    balls = add("Balls", "FabricBlue")
    for y in (1.45, 1.6, 2.4):
        _sphere(balls, (-3.7, y, 0.601), (0.05, 0.05, 0.05), level=3)
    return parts


def room_stage(*, cell: float = 0.1, vlt: float = ROOM_VLT, dome_light: bool = False) -> Usd.Stage:
    """The furnished room (module docstring), in memory: inner surfaces in ``cell``-metre squares.

    ``dome_light``: also author a white UsdLux.DomeLight of ``SKY_RADIANCE`` (for processors that read the sky
    from the stage; the daylight processors take it from their parameters: sky 'uniform',
    uniform_radiance ``SKY_RADIANCE``)."""
    stage, looks = new_stage(UsdGeom.Tokens.z, 1.0, "furnished daylight room (issue 29)", ROOM_MATERIALS,
                             root="/World/Room")
    glass = _glass_material(stage, "Glass", vlt)
    shell = _shell(cell)
    shell_looks = {"Floor": "Oak", "Rug": "Rug", "Ceiling": "Ceiling", "Walls": "Plaster", "Exterior": "Render",
                   "Reveals": "Plaster"}
    for name, look in shell_looks.items():
        write_mesh(stage, f"/World/Room/{name}", shell[name], looks[look])
    _write_glass(stage, "/World/Room/Glazing", shell["Glazing"], glass, vlt)
    UsdGeom.Xform.Define(stage, "/World/Room/Furniture")
    for name, (builder, look) in _furniture().items():
        if builder.arrays()[0].size:
            write_mesh(stage, f"/World/Room/Furniture/{name}", builder, looks[look])
    lo, hi = ROOM_LO - [WALL, WALL, 0.0], ROOM_HI + [WALL, WALL, 0.0]
    ground = MeshBuilder()  # 200 x 200 m, the building's footprint left out
    ground.grid((0, 0, 0), X, Y, [-100, lo[0], hi[0], 100], [-100, lo[1], hi[1], 100], skip={(1, 1)})
    write_mesh(stage, "/World/Ground", ground, looks["Ground"])
    if dome_light:
        sky = UsdLux.DomeLight.Define(stage, "/World/Lights/Sky")
        sky.CreateIntensityAttr(float(SKY_RADIANCE))
        sky.CreateColorAttr(Gf.Vec3f(1.0, 1.0, 1.0))
    return stage


def inside_room(points: np.ndarray, margin: float = 1e-3) -> np.ndarray:
    """(N,) bool: points within the room's interior box (its surfaces included)."""
    return np.all((points >= ROOM_LO - margin) & (points <= ROOM_HI + margin), axis=1)


def furnished_daylight_room(*, points: int = 150, seed: int = 29, cell: float = 0.1, vlt: float = ROOM_VLT,
                            dome_light: bool = False) -> DaylightScene:
    """The furnished room stage, ``points`` random surface points inside it (``random_surface_points``) and
    its triangles read back from the stage."""
    stage = room_stage(cell=cell, vlt=vlt, dome_light=dome_light)
    geometry = stage_triangles(stage)
    p, n, prims = random_surface_points(geometry, points, seed=seed)
    return DaylightScene(stage, p, n, geometry.triangles, geometry.albedo, geometry.transmittance,
                         sensor_prims=prims, tri_prim=geometry.tri_prim, prim_paths=geometry.prim_paths)


def random_surface_points(geometry: "StageTriangles | DaylightScene", count: int, *, seed: int = 29
                          ) -> tuple[np.ndarray, np.ndarray, tuple]:
    """(count, 3) float64 area-uniform random points on the opaque triangles whose centroid lies inside the
    room's interior box (floor, inner walls, ceiling, furniture: not the glass, reveals, exterior or
    ground), their (count, 3) unit face normals and the (count,) prim paths they lie on. ``seed`` fixed by
    the caller: the same points on every run."""
    tri = geometry.triangles
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    chosen = np.flatnonzero(inside_room(tri.mean(axis=1)) & (geometry.transmittance == 0) & (area > 1e-12))
    rng = np.random.default_rng(seed)
    pick = rng.choice(chosen, count, p=area[chosen] / area[chosen].sum())
    r1, r2 = np.sqrt(rng.random(count)), rng.random(count)
    a, b, c = tri[pick, 0], tri[pick, 1], tri[pick, 2]
    points = (1 - r1)[:, None] * a + (r1 * (1 - r2))[:, None] * b + (r1 * r2)[:, None] * c
    normals = cross[pick] / (2.0 * area[pick])[:, None]
    prims = tuple(geometry.prim_paths[i] for i in geometry.tri_prim[pick])
    return points, normals, prims


# --------------------------------------------------------------------------- reading stages back (pxr only)


@dataclass(frozen=True)
class StageTriangles:
    """Every mesh of a stage as world-space triangles, with the materials the Radiance side needs."""

    triangles: np.ndarray
    """(T, 3, 3) float64 world positions (metres x metersPerUnit not applied: stages here are in metres)."""
    albedo: np.ndarray
    """(T, 3) float64 diffuseColor of the bound UsdPreviewSurface (0.5 grey when none)."""
    transmittance: np.ndarray
    """(T,) float64: ``bake:transmittance`` of the prim, else of its material, else 1 - opacity; 0 opaque."""
    tri_prim: np.ndarray
    """(T,) int64 index into ``prim_paths``."""
    tri_face: np.ndarray
    """(T,) int64 the authored face each triangle comes from (fan triangulation)."""
    prim_paths: tuple


def _surface_shader(prim: Usd.Prim) -> tuple[UsdShade.Material | None, UsdShade.Shader | None]:
    material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
    if not material:
        return None, None
    source = material.ComputeSurfaceSource()
    shader = source[0] if source and source[0] else None
    return material, shader


def _input(shader: UsdShade.Shader | None, name: str, default):
    if shader is None:
        return default
    value = shader.GetInput(name)
    got = value.Get() if value else None
    return default if got is None else got


def _fan(counts: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fan triangulation of polygons: (T, 3) point ids, (T,) face ids and (T, 3) face-vertex (corner) ids."""
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    per_face = np.maximum(counts - 2, 0)
    faces = np.repeat(np.arange(len(counts)), per_face)
    k = np.arange(len(faces)) - np.repeat(np.cumsum(per_face) - per_face, per_face)
    s = starts[faces]
    corners = np.stack([s, s + k + 1, s + k + 2], axis=1)
    return indices[corners], faces, corners


def _mesh_triangles(mesh: UsdGeom.Mesh, cache: UsdGeom.XformCache, time=Usd.TimeCode.Default()):
    """(T, 3, 3) world triangles, (T,) face ids, (T, 3) point ids and (T, 3) corner ids of a mesh."""
    points = np.asarray(mesh.GetPointsAttr().Get(time), np.float64).reshape(-1, 3)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(time), np.int64)
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(time), np.int64)
    matrix = np.asarray(cache.GetLocalToWorldTransform(mesh.GetPrim()), np.float64)  # row vectors: p' = p M
    world = points @ matrix[:3, :3] + matrix[3, :3]
    tri, face, corners = _fan(counts, indices)
    return world[tri], face, tri, corners


def stage_triangles(stage: Usd.Stage, time=Usd.TimeCode.Default()) -> StageTriangles:
    """Every visible UsdGeom.Mesh of ``stage`` as world triangles with its bound material's diffuseColor and
    glazing VLT (read with pxr only, independently of usdbake's stages/)."""
    cache = UsdGeom.XformCache(time)
    tris, albedo, trans, prim_ids, faces, paths = [], [], [], [], [], []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        if UsdGeom.Imageable(prim).ComputeVisibility(time) == UsdGeom.Tokens.invisible:
            continue
        mesh = UsdGeom.Mesh(prim)
        world, face, _, _ = _mesh_triangles(mesh, cache, time)
        material, shader = _surface_shader(prim)
        color = np.asarray(_input(shader, "diffuseColor", Gf.Vec3f(0.5, 0.5, 0.5)), np.float64)
        tau = 1.0 - float(_input(shader, "opacity", 1.0))
        for holder in (material.GetPrim() if material else None, prim):
            attr = holder.GetAttribute(TRANSMITTANCE_ATTR) if holder is not None else None
            if attr and attr.HasAuthoredValue():
                tau = float(attr.Get())
        paths.append(str(prim.GetPath()))
        tris.append(world)
        faces.append(face)
        albedo.append(np.tile(color, (len(world), 1)))
        trans.append(np.full(len(world), tau))
        prim_ids.append(np.full(len(world), len(paths) - 1))
    return StageTriangles(np.concatenate(tris), np.concatenate(albedo), np.concatenate(trans),
                          np.concatenate(prim_ids).astype(np.int64), np.concatenate(faces).astype(np.int64),
                          tuple(paths))


# --------------------------------------------------------------------------- usdbake's results at the sensors


def sample_baked(stage: "Usd.Stage | str | Path", primvar: str, points: np.ndarray, normals: np.ndarray, *,
                 prims=None, time=Usd.TimeCode.Default(), max_distance: float = 0.02,
                 min_facing: float = 0.5) -> np.ndarray:
    """(N, C) float64 values of a baked primvar at sensor points: the faces that contain each point.

    ``stage``: the baked stage (or its path); ``primvar``: e.g. 'bake:daylightIrradiance' (the
    'primvars:' prefix optional); ``points`` (N, 3), ``normals`` (N, 3) world. Each point is projected onto
    the plane of every triangle of the meshes carrying the primvar (of ``prims[i]``, its prim path, when
    given) that faces its way (n_tri . n >= ``min_facing``) and lies within ``max_distance`` metres along the
    normal; the triangles whose closed interior holds the projection at the smallest distance (ties: the
    faces sharing an edge or corner the point lies on) give their values' mean. ``uniform`` primvars give
    the face's value; ``vertex`` / ``varying`` / ``faceVarying`` ones barycentric interpolation; ``constant``
    the value. NaN where no face is found.
    """
    stage = Usd.Stage.Open(str(stage)) if not isinstance(stage, Usd.Stage) else stage
    name = primvar if primvar.startswith("primvars:") else f"primvars:{primvar}"
    points = np.asarray(points, np.float64).reshape(-1, 3)
    normals = np.asarray(normals, np.float64).reshape(-1, 3)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    cache = UsdGeom.XformCache(time)
    meshes = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh) or not prim.HasAttribute(name):
            continue
        pv = UsdGeom.Primvar(prim.GetAttribute(name))
        values = pv.ComputeFlattened(time)
        if values is None:
            continue
        values = np.asarray(values, np.float64)
        values = values.reshape(len(values), -1) if values.ndim else values.reshape(1, 1)
        world, face, tri, corners = _mesh_triangles(UsdGeom.Mesh(prim), cache, time)
        cross = np.cross(world[:, 1] - world[:, 0], world[:, 2] - world[:, 0])
        norm = np.linalg.norm(cross, axis=1)
        unit = cross / np.maximum(norm, 1e-300)[:, None]
        meshes.append((str(prim.GetPath()), world, unit, norm > 0, face, tri, corners, pv.GetInterpolation(), values))
    if not meshes:
        raise ValueError(f"no mesh of the stage carries {name}")
    channels = meshes[0][-1].shape[1]
    out = np.full((len(points), channels), np.nan)
    for i, (p, n) in enumerate(zip(points, normals)):
        best, hits = np.inf, []
        for path, world, tn, valid, face, tri, corners, interpolation, values in meshes:
            if prims is not None and prims[i] != path:
                continue
            a, b, c = world[:, 0], world[:, 1], world[:, 2]
            dist = np.einsum("ij,ij->i", p - a, tn)  # signed distance of p above each plane
            near = np.flatnonzero((tn @ n >= min_facing) & (np.abs(dist) <= max_distance) & valid)
            if not len(near):
                continue
            q = p - dist[near, None] * tn[near]
            w = _barycentric(q, a[near], b[near], c[near])
            tol = 1e-6
            inside = np.all(w >= -tol, axis=1)
            for k in np.flatnonzero(inside):
                d = abs(dist[near[k]])
                if d < best - 1e-6:
                    best, hits = d, []
                if d <= best + 1e-6:
                    hits.append(_value_at(interpolation, values, face[near[k]], tri[near[k]], corners[near[k]],
                                          w[k]))
        if hits:
            out[i] = np.mean(hits, axis=0)
    return out


def _barycentric(q: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(K, 3) barycentric weights of points q (K, 3) in triangles (a, b, c) (K, 3 each)."""
    e0, e1, e2 = b - a, c - a, q - a
    d00, d01, d11 = (e0 * e0).sum(1), (e0 * e1).sum(1), (e1 * e1).sum(1)
    d20, d21 = (e2 * e0).sum(1), (e2 * e1).sum(1)
    det = d00 * d11 - d01 * d01
    det = np.where(np.abs(det) > 0, det, 1.0)
    w1, w2 = (d11 * d20 - d01 * d21) / det, (d00 * d21 - d01 * d20) / det
    return np.stack([1.0 - w1 - w2, w1, w2], axis=1)


def _value_at(interpolation: str, values: np.ndarray, face: int, tri_points: np.ndarray, tri_corners: np.ndarray,
              w: np.ndarray) -> np.ndarray:
    """The primvar's value at barycentric weights ``w`` of one triangle of a face."""
    w = np.clip(w, 0.0, None)
    w = w / w.sum()
    if interpolation == UsdGeom.Tokens.uniform:
        return values[face]
    if interpolation in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        return w @ values[tri_points]
    if interpolation == UsdGeom.Tokens.faceVarying:
        return w @ values[tri_corners]
    return values[0]


# --------------------------------------------------------------------------- Radiance references (cached)

OFFICE_AMBIENT_DIVISIONS = 65536
"""rcontrib -ad of the office reference (-ab 6, -aa 0, -lw 0.2 / -ad = 3.05e-6, MF:4). Noise judged by two seeds
(``radiance_reference._dummy_rays``), per run = |a - b| / mean / sqrt 2 over the 170 sensors, Greensboro TMY3,
occupied 8-18 h: mean occupied illuminance median 0.45% (p90 1.4%, max 3.0%), daylight factor (CIE overcast)
median 0.28% (p90 1.2%), sDA 0.694 in both. At MF:1 the same measure gave 4.6% / 1.9% / 0.8% (median) at
-ad 1024 / 4096 / 16384. Cost: ~160 CPU-s of rcontrib (2 processes; 156-165 s wall on the shared 2-core dev
machine, ~80 s if idle) + 38 s for the direct-only coefficients + 3 s gendaymtx."""
ROOM_AMBIENT_DIVISIONS = 65536
"""rtrace -ad of the furnished room's uniform-sky reference (-ab 6, -aa 0, -as 0, -lw 0.2 / -ad = 3.05e-6). Noise
by two seeds, per run, luminance-weighted irradiance at the 150 points: median 0.42%, p90 1.5% (-ad 16384: 0.9%,
3.0%; no bias between them: mean ratio 0.999). 6 of the 150 points lie in crevices (between books, sofa seat
and back) below 1% of the median. Cost: ~390-440 CPU-s of rtrace (2 processes; 416-439 s wall on the shared
2-core dev machine) + ~45 s for the direct-only run (-ab 1, 4 x -ad)."""


def scene_fingerprint(scene: DaylightScene) -> str:
    """sha256 (16 hex) of the arrays the Radiance side reads: triangles, albedo, transmittance, sensors
    (dtype, shape and bytes)."""
    import hashlib

    digest = hashlib.sha256()
    for array in (scene.triangles, scene.albedo, scene.transmittance, scene.sensor_points, scene.sensor_normals):
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype}{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()[:16]


def office_reference(scene: DaylightScene | None = None, *, mf: int = 4, ambient_bounces: int = 5,
                     ambient_divisions: int = OFFICE_AMBIENT_DIVISIONS, limit_weight: float | None = None,
                     seed: int = 1, weather_path: str | None = None, processes: int | None = None) -> dict:
    """The office's annual Radiance reference, computed once per settings and cached (``harness.cached_reference``,
    benchmarks/cache/daylight_office-<key>.npz).

    Two-phase (``radiance_reference``): rcontrib daylight coefficients at the floor sensors, glass as Radiance
    ``glass`` of the pane's VLT, ``-ab ambient_bounces + 1 -ad ambient_divisions -aa 0 -lw 0.2/-ad``, Reinhart
    MF:``mf`` + ground row; and the same with ``ambient_bounces`` 0 (the sky and ground seen directly, through
    the glass: for ASE and the direct / interreflected split), -ad 4 x ``ambient_divisions``. Times gendaymtx -O0
    (visible, Perez luminous efficacy, ground 0.2, sun in the patches) of ``weather_path`` (default the
    Greensboro TMY3 file pvlib ships) x 179 lm/W.

    Returns arrays: ``sensor_points`` (S, 3), ``sensor_normals`` (S, 3); ``dc`` and ``dc_direct`` (S, P, 3)
    float32 (sr); ``times`` (H,) datetime64[m] mid-hour local standard time; ``illuminance`` (H, S) float32 lux
    from ``dc``; ``rcontrib_seconds``, ``rcontrib_direct_seconds``, ``gendaymtx_seconds`` (0-d wall times
    when first computed), ``rcontrib_cpu_seconds``, ``rcontrib_direct_cpu_seconds`` (CPU time of all
    Radiance processes: robust to other load), ``processes``; ``command`` (0-d str).
    """
    from . import radiance_reference as rr

    scene = scene if scene is not None else lm83_office()
    weather_path = str(weather_path or rr._tmy3_example())
    settings = {"scene": "lm83_office", "version": SCENES_VERSION, "fingerprint": scene_fingerprint(scene),
                "mf": mf, "ambient_bounces": ambient_bounces, "ambient_divisions": ambient_divisions,
                "limit_weight": limit_weight, "seed": seed, "weather": Path(weather_path).name,
                "output": "visible", "ground_reflectance": 0.2}

    def compute() -> dict:
        common = dict(transmittance=scene.transmittance, mf=mf, limit_weight=limit_weight, seed=seed,
                      processes=processes)
        total, direct = {}, {}
        dc = rr.daylight_coefficients(scene.triangles, scene.albedo, scene.sensor_points, scene.sensor_normals,
                                      ambient_bounces=ambient_bounces, ambient_divisions=ambient_divisions,
                                      timings=total, **common)
        dc_direct = rr.daylight_coefficients(scene.triangles, scene.albedo, scene.sensor_points,
                                             scene.sensor_normals, ambient_bounces=0,
                                             ambient_divisions=4 * ambient_divisions, timings=direct, **common)
        started = time.perf_counter()
        times, sky = rr.annual_sky_matrix(weather_path, mf=mf, output="visible", ground_reflectance=0.2)
        sky_seconds = time.perf_counter() - started
        return {"sensor_points": scene.sensor_points, "sensor_normals": scene.sensor_normals,
                "dc": dc.astype(np.float32), "dc_direct": dc_direct.astype(np.float32), "times": times,
                "illuminance": rr.illuminance_from(dc, sky).astype(np.float32),
                "rcontrib_seconds": np.float64(total["radiance_seconds"]),
                "rcontrib_cpu_seconds": np.float64(total["radiance_cpu_seconds"]),
                "rcontrib_direct_seconds": np.float64(direct["radiance_seconds"]),
                "rcontrib_direct_cpu_seconds": np.float64(direct["radiance_cpu_seconds"]),
                "gendaymtx_seconds": np.float64(sky_seconds), "processes": np.int64(total["processes"]),
                "command": np.str_(total["command"])}

    return harness.cached_reference("daylight_office", settings, compute)


def furnished_reference(scene: DaylightScene | None = None, *, ambient_bounces: int = 5,
                        ambient_divisions: int = ROOM_AMBIENT_DIVISIONS, limit_weight: float | None = None,
                        seed: int = 1, radiance: float = SKY_RADIANCE, processes: int | None = None) -> dict:
    """The furnished room's single-uniform-sky Radiance reference at its random surface points, cached
    (benchmarks/cache/daylight_furnished-<key>.npz).

    ``rtrace -I`` (``radiance_reference.uniform_sky_irradiance``) 1 mm off each surface along its normal: sky
    of ``radiance`` W/(m^2 sr) above the horizon (1000 W/m^2 on an open horizontal), the stage's own 200 m
    ground and nothing below the horizon beyond it (no ground glow), glass of VLT 0.7, plastic RGB
    materials; ``-ab ambient_bounces + 1 -ad ambient_divisions -aa 0 -lw 0.2/-ad``, and ``ambient_bounces`` 0
    (the sky seen directly) at 4 x the divisions, for the interreflected share.

    Returns arrays: ``points`` (N, 3), ``normals`` (N, 3), ``prims`` (N,) str; ``irradiance`` and
    ``irradiance_direct`` (N, 3) float64 RGB W/m^2; ``rtrace_seconds``, ``rtrace_direct_seconds`` (wall),
    ``rtrace_cpu_seconds``, ``rtrace_direct_cpu_seconds`` (CPU, all processes), ``processes``,
    ``sky_radiance`` (0-d); ``command`` (0-d str).
    """
    from . import radiance_reference as rr

    scene = scene if scene is not None else furnished_daylight_room()
    settings = {"scene": "furnished_daylight_room", "version": SCENES_VERSION,
                "fingerprint": scene_fingerprint(scene), "ambient_bounces": ambient_bounces,
                "ambient_divisions": ambient_divisions, "limit_weight": limit_weight, "seed": seed,
                "radiance": radiance, "offset": SENSOR_OFFSET}

    def compute() -> dict:
        common = dict(transmittance=scene.transmittance, radiance=radiance, ground=False,
                      limit_weight=limit_weight, offset=SENSOR_OFFSET, seed=seed, processes=processes)
        total, direct = {}, {}
        e = rr.uniform_sky_irradiance(scene.triangles, scene.albedo, scene.sensor_points, scene.sensor_normals,
                                      ambient_bounces=ambient_bounces, ambient_divisions=ambient_divisions,
                                      timings=total, **common)
        e_direct = rr.uniform_sky_irradiance(scene.triangles, scene.albedo, scene.sensor_points,
                                             scene.sensor_normals, ambient_bounces=0,
                                             ambient_divisions=4 * ambient_divisions, timings=direct, **common)
        return {"points": scene.sensor_points, "normals": scene.sensor_normals,
                "prims": np.array(scene.sensor_prims, dtype=str), "irradiance": e, "irradiance_direct": e_direct,
                "rtrace_seconds": np.float64(total["radiance_seconds"]),
                "rtrace_cpu_seconds": np.float64(total["radiance_cpu_seconds"]),
                "rtrace_direct_seconds": np.float64(direct["radiance_seconds"]),
                "rtrace_direct_cpu_seconds": np.float64(direct["radiance_cpu_seconds"]),
                "processes": np.int64(total["processes"]), "sky_radiance": np.float64(radiance),
                "command": np.str_(total["command"])}

    return harness.cached_reference("daylight_furnished", settings, compute)
