"""city_block.usda: 3 x 3 city blocks of towers, streets and sidewalks (~9,000 triangles).

Z-up, metersPerUnit 1. Tower heights, setbacks, rooftop units and façade materials come from a
fixed-seed generator.
"""

import numpy as np
from pxr import Gf, UsdGeom

from mesh_builder import X, Y, MeshBuilder, faces_except, ticks
from stage_authoring import add_daylight, new_stage, write_mesh

FILE = "city_block.usda"
TRIANGLES = (8000, 10000)  # triangle budget checked after writing

MATERIALS = {
    "Concrete": ((0.62, 0.6, 0.56), 0.8),
    "Brick": ((0.55, 0.3, 0.22), 0.85),
    "Sandstone": ((0.76, 0.68, 0.52), 0.8),
    "BlueGlass": ((0.35, 0.42, 0.5), 0.2),
    "RoofUnits": ((0.5, 0.52, 0.55), 0.4, {"metallic": 0.6}),
    "Sidewalk": ((0.7, 0.69, 0.66), 0.9),
    "Asphalt": ((0.12, 0.12, 0.13), 0.95),
}
"""UsdPreviewSurface looks: {name: (diffuse color, roughness, extra inputs)}."""

BLOCK_GRID = 3          # blocks per side
BLOCK_SIZE = 40.0       # sidewalk slab per block (m)
BLOCK_PITCH = 52.0      # block size + 12 m street
CURB = 0.15             # sidewalk height
LOTS = ((-17.0, -2.0), (2.0, 17.0))  # 2 x 2 building lots per block (block-local x or y range)
FACADE_STEPS = (5.0, 5.0, 3.5)        # façade quads: ~5 m bays, 3.5 m floors
FACADE_LOOKS = ("Concrete", "Brick", "Sandstone", "BlueGlass")
ABOVE_GROUND = faces_except("-z")     # boxes standing on the ground have no bottom face


def block_centers():
    """Block centre coordinate along one axis."""
    return (np.arange(BLOCK_GRID) - (BLOCK_GRID - 1) / 2) * BLOCK_PITCH


def add_tower(building, units, rng, lo_xy, hi_xy):
    """Box building on a lot (optionally with a setback tier) and 1-2 rooftop units."""
    lo, hi = np.array([*lo_xy, CURB]), np.array([*hi_xy, CURB + rng.uniform(8, 40)])
    building.box(lo, hi, faces=ABOVE_GROUND, steps=FACADE_STEPS)
    if rng.random() < 0.4:  # setback tier
        inset = rng.uniform(2.0, 3.5)
        lo, hi = lo + [inset, inset, 0], hi + [-inset, -inset, 0]
        lo[2], hi[2] = hi[2], hi[2] + rng.uniform(5, 12)
        building.box(lo, hi, faces=ABOVE_GROUND, steps=FACADE_STEPS)
    for _ in range(rng.integers(1, 3)):
        size = rng.uniform(1.5, 3.5, 2)
        corner = rng.uniform(lo[:2] + 0.5, hi[:2] - 0.5 - size)
        units.box([*corner, hi[2]], [*(corner + size), hi[2] + rng.uniform(1.2, 3.0)], faces=ABOVE_GROUND)


def build():
    """3 x 3 blocks of towers on raised sidewalks, tessellated streets, sun and sky."""
    stage, looks = new_stage(UsdGeom.Tokens.z, 1.0, "city blocks", MATERIALS, root="/World/City")
    rng = np.random.default_rng(2024)  # fixed seed: identical output on every run
    centers = block_centers()
    for r, cy in enumerate(centers):
        for c, cx in enumerate(centers):
            block = UsdGeom.Xform.Define(stage, f"/World/City/Block_{r}_{c}")
            block.AddTranslateOp().Set(Gf.Vec3d(cx, cy, 0))
            path = block.GetPath().pathString
            sidewalk = MeshBuilder()
            half = BLOCK_SIZE / 2
            sidewalk.box((-half, -half, 0), (half, half, CURB), faces=ABOVE_GROUND, steps=(8.0, 8.0, None))
            write_mesh(stage, f"{path}/Sidewalk", sidewalk, looks["Sidewalk"])
            units = MeshBuilder()
            lots = [(xs, ys) for ys in LOTS for xs in LOTS]
            for k, (xs, ys) in enumerate(lots):
                building = MeshBuilder()
                inset = rng.uniform(0, 1.5, 2)
                add_tower(building, units, rng, (xs[0] + inset[0], ys[0] + inset[1]),
                          (xs[1] - inset[0], ys[1] - inset[1]))
                write_mesh(stage, f"{path}/Building_{k}", building, looks[FACADE_LOOKS[rng.integers(4)]])
            write_mesh(stage, f"{path}/RoofUnits", units, looks["RoofUnits"])

    edges = np.sort(np.concatenate([centers - BLOCK_SIZE / 2, centers + BLOCK_SIZE / 2]))
    extent = edges[-1] + (BLOCK_PITCH - BLOCK_SIZE)
    road_ticks = ticks([-extent, *edges, extent], 8.0)
    mids = (road_ticks[:-1] + road_ticks[1:]) / 2
    in_block = np.abs(mids[:, None] - centers[None, :]).min(axis=1) < BLOCK_SIZE / 2
    streets = MeshBuilder()
    streets.grid((0, 0, 0), X, Y, road_ticks, road_ticks,
                 skip=[(i, j) for i in np.flatnonzero(in_block) for j in np.flatnonzero(in_block)])
    write_mesh(stage, "/World/City/Streets", streets, looks["Asphalt"])
    add_daylight(stage, (40.0, 0.0, 30.0))  # 50 degrees up
    return stage
