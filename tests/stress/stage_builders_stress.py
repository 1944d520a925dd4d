"""Stages for the stress suite: a box on a floor, hostile geometry, lights and a small PointInstancer.

A plain module, imported as ``from stress.stage_builders_stress import ...``
(tests/conftest.py puts tests/ on sys.path; tests/stress is a namespace package).
"""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import numpy as np
from pxr import Gf, Usd, UsdGeom, UsdLux, Vt


def box_on_floor(stage: Usd.Stage, root: str = "/World", offset=(0.0, 0.0, 0.0), scale: float = 1.0) -> None:
    """A 10x10 floor (a 10x10 grid of quads sharing vertices) and a unit box standing on it, Z up."""
    ox, oy, oz = offset
    floor = UsdGeom.Mesh.Define(stage, f"{root}/floor")
    grid = np.stack(np.meshgrid(np.linspace(-5, 5, 11), np.linspace(-5, 5, 11), indexing="xy"), -1).reshape(-1, 2)
    points = [Gf.Vec3f(float((x * scale) + ox), float((y * scale) + oy), float(oz)) for x, y in grid]
    quads = [(r * 11 + c, r * 11 + c + 1, (r + 1) * 11 + c + 1, (r + 1) * 11 + c) for r in range(10) for c in range(10)]
    floor.CreatePointsAttr(points)
    floor.CreateFaceVertexCountsAttr([4] * len(quads))
    floor.CreateFaceVertexIndicesAttr([i for q in quads for i in q])
    cube = UsdGeom.Mesh.Define(stage, f"{root}/box")
    corners = [(x, y, z) for z in (0, 1) for y in (-0.5, 0.5) for x in (-0.5, 0.5)]
    cube.CreatePointsAttr([Gf.Vec3f(float(x * scale + ox), float(y * scale + oy), float(z * scale + oz))
                           for x, y, z in corners])
    faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (1, 3, 7, 5), (3, 2, 6, 7), (2, 0, 4, 6)]
    cube.CreateFaceVertexCountsAttr([4] * 6)
    cube.CreateFaceVertexIndicesAttr([i for f in faces for i in f])


def stage_with(**kwargs) -> Usd.Stage:
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.Xform.Define(stage, "/World")
    box_on_floor(stage, **kwargs)
    return stage


def hostile_stage() -> Usd.Stage:
    """Zero-area and sliver triangles, duplicate vertices, a non-planar and a concave polygon,
    coincident coplanar faces and a huge triangle next to tiny ones."""
    stage = stage_with()

    def mesh(name, points, counts, indices):
        m = UsdGeom.Mesh.Define(stage, f"/World/{name}")
        m.CreatePointsAttr([Gf.Vec3f(*map(float, p)) for p in points])
        m.CreateFaceVertexCountsAttr(counts)
        m.CreateFaceVertexIndicesAttr(indices)

    mesh("zero_area", [(1, 1, 0.5), (1, 1, 0.5), (1, 1, 0.5), (2, 2, 0.5), (3, 3, 0.5)], [3, 3], [0, 1, 2, 0, 3, 4])
    mesh("sliver", [(0, 2, 0.2), (4, 2, 0.2), (2, 2 + 1e-7, 0.2)], [3], [0, 1, 2])
    mesh("duplicates", [(-2, -2, 0.3), (-1, -2, 0.3), (-1, -1, 0.3), (-1, -1, 0.3), (-2, -1, 0.3)], [4, 3],
         [0, 1, 2, 4, 2, 3, 4])
    mesh("non_planar", [(2, -2, 0), (3, -2, 0.5), (3, -1, 0), (2, -1, 0.5)], [4], [0, 1, 2, 3])
    mesh("concave", [(-4, 2, 0.1), (-2, 2, 0.1), (-2, 3, 0.1), (-3, 3, 0.1), (-3, 4, 0.1), (-4, 4, 0.1)], [6],
         list(range(6)))
    mesh("z_fight", [(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)], [4], [0, 1, 2, 3])
    mesh("huge", [(-1e4, -1e4, -1), (1e4, -1e4, -1), (0, 1e4, -1)], [3], [0, 1, 2])
    mesh("tiny", [(0.7, 0.7, 1.0), (0.7 + 1e-6, 0.7, 1.0), (0.7, 0.7 + 1e-6, 1.0)], [3], [0, 1, 2])
    return stage


def add_lights(stage: Usd.Stage, root: str = "/World") -> None:
    """A tilted DistantLight (sun) and an untextured DomeLight (sky): both scale- and translation-free."""
    sun = UsdLux.DistantLight.Define(stage, f"{root}/Sun")
    sun.CreateIntensityAttr(3.0)
    sun.CreateAngleAttr(0.53)
    sun.AddRotateXYZOp().Set(Gf.Vec3f(35.0, 20.0, 0.0))
    sky = UsdLux.DomeLight.Define(stage, f"{root}/Sky")
    sky.CreateIntensityAttr(1.0)
    sky.CreateColorAttr(Gf.Vec3f(0.6, 0.7, 1.0))


def add_instancer(stage: Usd.Stage, root: str = "/World") -> str:
    """A PointInstancer with four instances of a small 0.4-unit cube prototype on the floor; returns the
    prototype's path."""
    instancer = UsdGeom.PointInstancer.Define(stage, f"{root}/Scatter")
    UsdGeom.Scope.Define(stage, f"{root}/Scatter/Prototypes")
    proto = UsdGeom.Mesh.Define(stage, f"{root}/Scatter/Prototypes/Crate")
    s = 0.2
    corners = [(x, y, z) for z in (0, 2 * s) for y in (-s, s) for x in (-s, s)]
    proto.CreatePointsAttr([Gf.Vec3f(*c) for c in corners])
    faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (1, 3, 7, 5), (3, 2, 6, 7), (2, 0, 4, 6)]
    proto.CreateFaceVertexCountsAttr([4] * 6)
    proto.CreateFaceVertexIndicesAttr([i for f in faces for i in f])
    instancer.CreatePrototypesRel().SetTargets([proto.GetPath()])
    positions = [(2.0, 2.0, 0.0), (2.6, 2.1, 0.0), (-2.5, 1.5, 0.0), (1.5, -3.0, 0.0)]
    instancer.CreatePositionsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in positions]))
    instancer.CreateProtoIndicesAttr(Vt.IntArray([0] * len(positions)))
    instancer.CreateOrientationsAttr(Vt.QuathArray([Gf.Quath(1, 0, 0, 0), Gf.Quath(0.9239, 0, 0, 0.3827),
                                                    Gf.Quath(1, 0, 0, 0), Gf.Quath(0.7071, 0, 0, 0.7071)]))
    return str(proto.GetPath())


def hostile_lit_stage() -> Usd.Stage:
    """hostile_stage() plus a DistantLight, a DomeLight and a small PointInstancer."""
    stage = hostile_stage()
    add_lights(stage)
    add_instancer(stage)
    return stage


def small_lit_stage(translate=None, scale: float | None = None) -> Usd.Stage:
    """Box on a floor, lights and instancer under /World, /World moved by double-precision xformOps."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, "Z")
    world = UsdGeom.Xform.Define(stage, "/World")
    if translate is not None:
        world.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*translate))
    if scale is not None:
        world.AddScaleOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(scale, scale, scale))
    box_on_floor(stage)
    add_lights(stage)
    add_instancer(stage)
    return stage


# ---------------------------------------------------------------------------
# The cheapest parameters that still run every kernel of each processor.

FAST_FORM_FACTORS = {"target_patches": 48, "rays": 16}
FAST_SKY = {"patch_count": 16, "samples": 4, "min_area": 0.0, "max_level": 2, "max_triangles": 20000}
"""4 samples (2 x 2): with 1 a pair is never partly visible, so nothing would be refined; min_area 0: the
huge triangle makes the scene diagonal 3e4, and the default relative floor would forbid every split."""
FAST_FIELDS = {"positional_samples": 16, "direction_map_size": 4, "force": "Crate"}
TMY3 = str(Path(importlib.util.find_spec("pvlib").origin).parent / "data" / "723170TYA.CSV")
"""The typical year pvlib ships (Greensboro NC, NREL TMY3, public domain): the weather of annual_daylight."""

FAST_BOUNCES = {"gather_rays": 8, "patches": 64, "bounces": 2}
"""interreflection: few gather rays and patches (every bounce path still runs)."""
FAST_PARAMS: dict[str, dict[str, dict]] = {
    "ambient_occlusion": {"ambient_occlusion": {"samples": 16, "per_face": True}},
    "sky_visibility": {"sky_visibility": FAST_SKY},
    "interreflection": {"sky_visibility": FAST_SKY, "interreflection": FAST_BOUNCES},
    "daylight": {"sky_visibility": FAST_SKY, "interreflection": FAST_BOUNCES, "daylight": {"sun_samples": 2}},
    "displacement_fields": {"displacement_fields": FAST_FIELDS},
    "instance_ao": {"displacement_fields": FAST_FIELDS, "instance_ao": {"samples": 16, "instances": True}},
    "form_factors": {"form_factors": FAST_FORM_FACTORS},
    "radiosity": {"form_factors": FAST_FORM_FACTORS,
                  "radiosity": {"light_samples": 2, "sky_samples": 4, "patch_points": 2, "gather_rays": 4}},
    "light_probes": {"light_probes": {"probes": 64, "iterations": 1, "rays": 16, "placement_rays": 8}},
    "irradiance_grid": {"irradiance_grid": {"vertices": 64, "rays": 16}},
    "progressive_mesh": {},
    "daylight_stream": {"sky_visibility": FAST_SKY, "interreflection": FAST_BOUNCES,
                        "daylight_stream": {"declination_step": 12.0, "hour_step": 15.0, "sun_samples": 2}},
    "annual_daylight": {"sky_visibility": FAST_SKY, "interreflection": FAST_BOUNCES,
                        "annual_daylight": {"weather": TMY3, "sun_bins": 1, "sun_samples": 1}},
}
"""Per processor: the params argument of usdbake.bake / Pipeline.build (dependencies' params included)."""


def fast_params(name: str) -> dict[str, dict]:
    """FAST_PARAMS of a processor; a processor without an entry runs at its defaults (a new processor joins
    every stress and determinism test as it is; give it an entry when its defaults are slow)."""
    return FAST_PARAMS.get(name, {})


def walk_values(value, where: str, *, skip_fields: tuple[str, ...] = (), depth: int = 0):
    """(where, leaf) for every numpy array, bytes value and number reachable from a product or record
    (dataclasses, dicts, lists, tuples), so every kernel output handed downstream is seen, not only what
    gets authored; dataclass fields named in ``skip_fields`` are passed over."""
    if depth > 6:
        return
    if isinstance(value, (np.ndarray, bytes, bytearray)) or \
            (isinstance(value, (float, int, np.number)) and not isinstance(value, bool)):
        yield where, value
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            if f.name not in skip_fields:
                yield from walk_values(getattr(value, f.name), f"{where}.{f.name}", skip_fields=skip_fields,
                                       depth=depth + 1)
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from walk_values(item, f"{where}[{key!r}]", skip_fields=skip_fields, depth=depth + 1)
    elif isinstance(value, (list, tuple)):
        for k, item in enumerate(value):
            yield from walk_values(item, f"{where}[{k}]", skip_fields=skip_fields, depth=depth + 1)
