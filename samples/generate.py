"""Generate the usdbake sample stages (.usda) that live next to this script.

    python samples/generate.py [--out DIR]

All geometry is polygonal UsdGeom.Mesh (quads where natural, a few ngons and a
concave polygon in building.usda) wound counter-clockwise seen from the side
the surface faces (USD's default rightHanded orientation). Smooth surfaces
share vertices; hard (90 degree) edges get their own vertices. Every mesh has
a UsdPreviewSurface material bound through MaterialBindingAPI, every stage has
UsdLux lights, explicit upAxis / metersPerUnit and /World as defaultPrim.
Output is deterministic: the only randomness uses fixed seeds.

Stages:
  cornell_box.usda      Y-up, metersPerUnit 0.01: the classic Cornell box data kept
                        verbatim (~556 x 549 x 559 units, so ~5.5 m), front open
                        towards -Z, a RectLight plus an emissive quad under the ceiling.
  window_room.usda      Z-up, metersPerUnit 1: 4 x 5 x 3 m room with one window,
                        ground plane outside, sun + sky.
  building.usda         Y-up, metersPerUnit 1: L-shaped two-storey building with
                        recessed windows, balconies, roof overhang (~700 triangles).
  city_block.usda       Z-up, metersPerUnit 1: 3 x 3 city blocks, streets, sidewalks
                        (~9,000 triangles).
  atrium.usda           Y-up, metersPerUnit 1: Sponza-like two-storey courtyard with
                        colonnades, arches, balustrade and hanging cloths (~50k triangles).
  instanced_props.usda  Y-up, metersPerUnit 1: a time-sampled PointInstancer (vase and
                        crate prototypes) and instanceable references to a class bench.

After writing, verify.verify() re-opens every stage, prints a summary table and
checks the triangle budgets.

Layout (plain modules beside this script, imported from its folder):
  generate.py           this entry point: the list of stages and main()
  mesh_builder.py       pure numpy geometry and MeshBuilder (no USD)
  stage_authoring.py    stage skeleton, UsdPreviewSurface materials, meshes, lights
  <stage>.py            one module per stage above: FILE, TRIANGLES (budget), build()
  verify.py             re-open, summarise and check the written stages
"""

import argparse
from pathlib import Path

import atrium
import building
import city_block
import cornell_box
import instanced_props
import window_room
from stage_authoring import save
from verify import verify

SAMPLES = (cornell_box, window_room, building, city_block, atrium, instanced_props)
"""Stage modules, in the order they are written and listed."""


def main():
    """Write every stage to --out (default: this script's folder), then verify them."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent)
    out = parser.parse_args().out
    out.mkdir(parents=True, exist_ok=True)
    for sample in SAMPLES:
        save(sample.build(), out / sample.FILE)
    verify(out, {sample.FILE: sample.TRIANGLES for sample in SAMPLES})


if __name__ == "__main__":
    main()
