"""cornell_box.usda: the classic Cornell box data kept verbatim.

Y-up, metersPerUnit 0.01 (~556 x 549 x 559 units, so ~5.5 m), front open towards -Z:
5 walls (2 x 2 quads each), two rotated blocks, a RectLight plus an emissive quad under the ceiling.
"""

import numpy as np
from pxr import Gf, UsdGeom, UsdLux

from mesh_builder import Y, MeshBuilder, bilinear_patch
from stage_authoring import new_stage, set_emission, write_mesh

FILE = "cornell_box.usda"
TRIANGLES = (40, 120)  # triangle budget checked after writing

# Classic Cornell box data (Cornell Program of Computer Graphics), Y-up, open towards -Z.
CORNELL_WALLS = {
    "Floor": ("White", [(552.8, 0, 0), (0, 0, 0), (0, 0, 559.2), (549.6, 0, 559.2)]),
    "Ceiling": ("White", [(556, 548.8, 0), (556, 548.8, 559.2), (0, 548.8, 559.2), (0, 548.8, 0)]),
    "BackWall": ("White", [(549.6, 0, 559.2), (0, 0, 559.2), (0, 548.8, 559.2), (556, 548.8, 559.2)]),
    "RightWall": ("Green", [(0, 0, 559.2), (0, 0, 0), (0, 548.8, 0), (0, 548.8, 559.2)]),
    "LeftWall": ("Red", [(552.8, 0, 0), (549.6, 0, 559.2), (556, 548.8, 559.2), (556, 548.8, 0)]),
}
# Blocks: (x, z) outline of the top and height; the classic sides are its vertical extrusion.
CORNELL_BLOCKS = {
    "ShortBlock": ([(130, 65), (82, 225), (240, 272), (290, 114)], 165),
    "TallBlock": ([(423, 247), (265, 296), (314, 456), (472, 406)], 330),
}
CORNELL_LIGHT = (213, 343, 227, 332)  # x0, x1, z0, z1 of the 130 x 105 light
CORNELL_EMISSION = (17.0, 12.0, 4.0)

MATERIALS = {
    "White": ((0.725, 0.71, 0.68), 0.9),
    "Red": ((0.63, 0.065, 0.05), 0.9),
    "Green": ((0.14, 0.45, 0.091), 0.9),
    "Light": ((0.78, 0.78, 0.78), 0.9, {"emissive": CORNELL_EMISSION}),
}
"""UsdPreviewSurface looks: {name: (diffuse color, roughness, extra inputs)}."""


def build():
    """Cornell box: 5 walls (2x2 quads each), two rotated blocks, RectLight + emissive quad."""
    stage, looks = new_stage(UsdGeom.Tokens.y, 0.01, "Cornell box, classic data in centimetres", MATERIALS,
                             root="/World/CornellBox")
    for name, (look, corners) in CORNELL_WALLS.items():
        wall = MeshBuilder()
        wall.lattice(bilinear_patch(corners, 2, 2))  # corners wind so the walls face into the box
        write_mesh(stage, f"/World/CornellBox/{name}", wall, looks[look])
    for name, (outline, height) in CORNELL_BLOCKS.items():
        block = MeshBuilder()
        block.prism(outline, 0, height, bottom=False)  # resting on the floor, as in the classic data
        write_mesh(stage, f"/World/CornellBox/{name}", block, looks["White"])

    x0, x1, z0, z1 = CORNELL_LIGHT
    emitter = MeshBuilder()
    emitter.polygon([(x0, 548.6, z0), (x1, 548.6, z0), (x1, 548.6, z1), (x0, 548.6, z1)], facing=-Y)
    write_mesh(stage, "/World/CornellBox/LightQuad", emitter, looks["Light"])

    light = UsdLux.RectLight.Define(stage, "/World/Lights/CeilingLight")
    light.CreateWidthAttr(x1 - x0)
    light.CreateHeightAttr(z1 - z0)
    # Same radiance as the emissive quad: the brightest channel as intensity, the rest as color.
    set_emission(light, max(CORNELL_EMISSION), np.divide(CORNELL_EMISSION, max(CORNELL_EMISSION)))
    light.AddTranslateOp().Set(Gf.Vec3d((x0 + x1) / 2, 548.5, (z0 + z1) / 2))
    light.AddRotateXOp().Set(-90.0)  # local -Z (emission) -> world -Y; height runs along world Z
    return stage
