"""window_room.usda: a closed 4 x 5 x 3 m room with one window, ground plane outside, sun + sky.

Z-up, metersPerUnit 1. Walls, floor and ceiling face into the room.
"""

from pxr import UsdGeom

from mesh_builder import X, Y, Z, MeshBuilder, faces_except
from stage_authoring import add_daylight, new_stage, write_mesh

FILE = "window_room.usda"
TRIANGLES = (60, 140)  # triangle budget checked after writing

MATERIALS = {
    "Wall": ((0.8, 0.78, 0.74), 0.9),
    "Ceiling": ((0.9, 0.9, 0.9), 0.9),
    "WoodFloor": ((0.45, 0.3, 0.18), 0.6),
    "Cabinet": ((0.3, 0.4, 0.6), 0.5),
    "Ground": ((0.3, 0.35, 0.2), 1.0),
}
"""UsdPreviewSurface looks: {name: (diffuse color, roughness, extra inputs)}."""

ROOM_LO, ROOM_HI = (-2.0, -2.5, 0.0), (2.0, 2.5, 3.0)  # 4 x 5 x 3 m, Z-up
WINDOW_X, WINDOW_Z = (-0.8, 0.8), (0.9, 2.2)          # opening in the south wall (y = -2.5)


def build():
    """Closed room of inward-facing quads, one window in the south wall, ground, sun and sky."""
    stage, looks = new_stage(UsdGeom.Tokens.z, 1.0, "room with one window", MATERIALS, root="/World/Room")
    (x0, y0, z0), (x1, y1, z1) = ROOM_LO, ROOM_HI
    floor, ceiling, walls = MeshBuilder(), MeshBuilder(), MeshBuilder()
    floor.box(ROOM_LO, ROOM_HI, faces=("-z",), steps=(1, 1, None), inward=True)
    ceiling.box(ROOM_LO, ROOM_HI, faces=("+z",), steps=(2, 2.5, None), inward=True)
    walls.box(ROOM_LO, ROOM_HI, faces=("+x", "-x", "+y"), inward=True)
    # South wall facing +Y (into the room): 3 x 3 quads around the window, the middle cell left out.
    walls.grid((x0, y0, z0), Z, X, [0, WINDOW_Z[0], WINDOW_Z[1], z1 - z0],
               [0, WINDOW_X[0] - x0, WINDOW_X[1] - x0, x1 - x0], skip={(1, 1)})
    cabinet = MeshBuilder()
    cabinet.box((0.6, 1.4, 0.0), (1.8, 2.3, 0.9), faces=faces_except("-z"))
    ground = MeshBuilder()  # 20 x 20 m around the room, the room's footprint left out
    ground.grid((0, 0, 0), X, Y, [-10, x0, x1, 10], [-10, y0, y1, 10], skip={(1, 1)})

    for name, builder, look in (("Floor", floor, "WoodFloor"), ("Ceiling", ceiling, "Ceiling"),
                                ("Walls", walls, "Wall"), ("Cabinet", cabinet, "Cabinet")):
        write_mesh(stage, f"/World/Room/{name}", builder, looks[look])
    write_mesh(stage, "/World/Ground", ground, looks["Ground"])
    add_daylight(stage, (55.0, 0.0, 20.0))  # 35 degrees above the horizon, shining north through the window
    return stage
