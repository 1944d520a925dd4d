"""building.usda: an L-shaped two-storey building (~700 triangles).

Y-up, metersPerUnit 1: gridded façades with recessed windows, hexagonal balconies, a roof slab
with a 0.5 m overhang (concave L-shaped ngon caps), a water tank, ground, sun and sky.
"""

import numpy as np
from pxr import UsdGeom

from mesh_builder import X, Y, Z, MeshBuilder, faces_except, unit
from stage_authoring import add_daylight, new_stage, write_mesh

FILE = "building.usda"
TRIANGLES = (600, 800)  # triangle budget checked after writing

MATERIALS = {
    "Plaster": ((0.8, 0.76, 0.7), 0.85),
    "Glass": ((0.1, 0.14, 0.18), 0.05),
    "Concrete": ((0.55, 0.55, 0.53), 0.8),
    "Metal": ((0.6, 0.62, 0.65), 0.35, {"metallic": 0.8}),
    "Grass": ((0.25, 0.4, 0.15), 1.0),
}
"""UsdPreviewSurface looks: {name: (diffuse color, roughness, extra inputs)}."""

BAY = 4.0                  # façade module along a wall (m)
STOREY = 3.2               # floor-to-floor height (m)
STOREYS = 2
WINDOW_SPAN = (1.2, 2.8)   # window inside a bay
WINDOW_SILL_HEAD = (0.9, 2.3)  # window inside a storey
RECESS = 0.25              # window recess depth (m)
ROOF = (6.4, 6.8)          # roof slab bottom and top
# L-shaped footprint (x, z), counter-clockwise seen from above; True: the wall after the corner has windows.
FOOTPRINT = [(-10, 10), (-2, 10), (-2, 2), (10, 2), (10, -6), (-10, -6)]
WINDOWED = [False, False, False, True, True, True]
ROOF_OUTLINE = [(-10.5, 10.5), (-1.5, 10.5), (-1.5, 2.5), (10.5, 2.5), (10.5, -6.5), (-10.5, -6.5)]
# Balcony: hexagon in façade coordinates (along the wall, out of the wall).
BALCONY = [(-1.6, -0.1), (1.6, -0.1), (1.6, 1.0), (1.2, 1.4), (-1.2, 1.4), (-1.6, 1.0)]


def opening_ticks(length, module, opening, count):
    """0, a0, b0, a1, b1, ..., length where (a_k, b_k) is the opening inside module k."""
    return [0.0, *(k * module + edge for k in range(count) for edge in opening), length]


def add_window_recess(walls, glass, corner, width, height):
    """Four reveals into the wall and a recessed pane for the opening at corner + width x height."""
    depth = -RECESS * unit(np.cross(width, height))
    front = [corner, corner + width, corner + width + height, corner + height]
    back = [p + depth for p in front]
    glass.polygon(back)
    for k in range(4):  # edge x depth points into the opening for a counter-clockwise outline
        walls.polygon([front[k], front[(k + 1) % 4], back[(k + 1) % 4], back[k]])


def add_facade(walls, glass, start, end, windowed):
    """Wall between two footprint corners as a quad grid, windowed walls with recessed windows."""
    start = np.array([start[0], 0.0, start[1]])
    end = np.array([end[0], 0.0, end[1]])
    length = np.linalg.norm(end - start)
    along = (end - start) / length  # along x Y is the outward normal
    bays = int(round(length / BAY))
    if not windowed:
        walls.grid(start, along, Y, np.linspace(0, length, bays + 1), np.arange(STOREYS + 1) * STOREY)
        return
    u_ticks = opening_ticks(length, BAY, WINDOW_SPAN, bays)
    v_ticks = opening_ticks(STOREYS * STOREY, STOREY, WINDOW_SILL_HEAD, STOREYS)
    openings = sorted((2 * i + 1, 2 * j + 1) for i in range(bays) for j in range(STOREYS))
    walls.grid(start, along, Y, u_ticks, v_ticks, skip=openings)
    for i, j in openings:
        corner = start + along * u_ticks[i] + Y * v_ticks[j]
        add_window_recess(walls, glass, corner, along * (u_ticks[i + 1] - u_ticks[i]),
                          Y * (v_ticks[j + 1] - v_ticks[j]))


def add_balcony(slabs, rails, center_xz, along_xz, out_xz, floor_y):
    """Hexagonal slab sticking out of a wall at floor_y with a front parapet."""
    center, along, out = (np.asarray(v, dtype=float) for v in (center_xz, along_xz, out_xz))
    outline = [center + a * along + b * out for a, b in BALCONY]
    slabs.prism(outline, floor_y - 0.2, floor_y)
    corners = np.array([center + a * along + b * out for a, b in ((-1.2, 1.3), (1.2, 1.4))])
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    rails.box((lo[0], floor_y, lo[1]), (hi[0], floor_y + 1.0, hi[1]), faces=faces_except("-y"))


def build():
    """L-shaped building: gridded façades, window recesses, balconies, roof slab, tank, ground."""
    stage, looks = new_stage(UsdGeom.Tokens.y, 1.0, "L-shaped building", MATERIALS, root="/World/Building")
    walls, glass = MeshBuilder(), MeshBuilder()
    for k, windowed in enumerate(WINDOWED):
        add_facade(walls, glass, FOOTPRINT[k], FOOTPRINT[(k + 1) % len(FOOTPRINT)], windowed)

    roof = MeshBuilder()
    roof.prism(ROOF_OUTLINE, *ROOF)  # concave L-shaped caps, 0.5 m overhang
    roof.box((-11.5, 2.6, -1.5), (-10.0, 2.8, 1.5), faces=faces_except("+x"))  # entrance canopy against the wall
    slabs, metal = MeshBuilder(), MeshBuilder()
    for x in (4.0, -4.0):  # upper-storey balconies on the south façade (z = -6)
        add_balcony(slabs, metal, (x, -6.0), (-1, 0), (0, -1), STOREY)
    octagon = [(-6 + 1.2 * np.cos(a), 6 + 1.2 * np.sin(a)) for a in np.arange(8) * np.pi / 4]
    metal.prism(octagon, ROOF[1], ROOF[1] + 1.6, bottom=False)  # water tank
    ground = MeshBuilder()
    ground.grid((0, 0, 0), Z, X, np.linspace(-30, 30, 9), np.linspace(-30, 30, 9))

    for name, builder, look in (("Walls", walls, "Plaster"), ("Windows", glass, "Glass"), ("Roof", roof, "Concrete"),
                                ("Balconies", slabs, "Concrete"), ("Metalwork", metal, "Metal")):
        write_mesh(stage, f"/World/Building/{name}", builder, looks[look])
    write_mesh(stage, "/World/Ground", ground, looks["Grass"])
    add_daylight(stage, (-50.0, 35.0, 0.0))  # 50 degrees up
    return stage
