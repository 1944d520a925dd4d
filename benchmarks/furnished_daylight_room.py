"""The furnished daylight room of issue 29: a living room lit by a uniform sky through four glazed windows.

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

Z-up, metres, x east, y north, materials and glass as ``daylight_scenes`` describes (its ``DaylightScene``,
glass material and ``SENSOR_OFFSET`` are shared); the triangles are read back from the stage
(``stage_readback.stage_triangles``). Its Radiance reference: ``daylight_references.furnished_reference``.
"""

from __future__ import annotations

import sys

import numpy as np
from pxr import Gf, Usd, UsdGeom, UsdLux

from . import harness
from .daylight_scenes import DaylightScene, _glass_material, _ticks, _write_glass
from .stage_readback import StageTriangles, stage_triangles

sys.path.insert(0, str(harness.SAMPLES))  # the samples' mesh and stage helpers (samples/ is not a package)
from mesh_builder import X, Y, Z, MeshBuilder, faces_except, icosphere  # noqa: E402
from stage_authoring import new_stage, write_mesh  # noqa: E402

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


def room_stage(*, cell: float = 0.1, vlt: float = ROOM_VLT, dome_light: bool = False,
               glazed: bool = True) -> Usd.Stage:
    """The furnished room (module docstring), in memory: inner surfaces in ``cell``-metre squares.

    ``glazed=False`` leaves the panes out (open windows): the variant for processors that do not model
    glass transmission (radiosity, irradiance_grid, light_probes read a pane as an opaque surface).

    ``dome_light``: also author a white UsdLux.DomeLight of ``SKY_RADIANCE`` (for processors that read the sky
    from the stage; the daylight processors take it from their parameters: sky 'uniform',
    uniform_radiance ``SKY_RADIANCE``)."""
    stage, looks = new_stage(UsdGeom.Tokens.z, 1.0, "furnished daylight room (issue 29)", ROOM_MATERIALS,
                             root="/World/Room")
    shell = _shell(cell)
    shell_looks = {"Floor": "Oak", "Rug": "Rug", "Ceiling": "Ceiling", "Walls": "Plaster", "Exterior": "Render",
                   "Reveals": "Plaster"}
    for name, look in shell_looks.items():
        write_mesh(stage, f"/World/Room/{name}", shell[name], looks[look])
    if glazed:
        _write_glass(stage, "/World/Room/Glazing", shell["Glazing"], _glass_material(stage, "Glass", vlt), vlt)
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

