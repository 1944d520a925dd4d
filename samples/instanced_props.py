"""instanced_props.usda: a time-sampled PointInstancer and instanceable references.

Y-up, metersPerUnit 1, frames 1-3 at 24 fps: a floor, a PointInstancer /World/Scatter of vase and
crate prototypes (positions and orientations at the default time and on every frame) and four
instanceable prims referencing the class /World/Library/Bench.
"""

import numpy as np
from pxr import Gf, Usd, UsdGeom, Vt

from mesh_builder import X, Z, MeshBuilder, faces_except
from stage_authoring import DECIMALS, add_daylight, new_stage, write_mesh

FILE = "instanced_props.usda"
TRIANGLES = (5000, 20000)  # triangle budget checked after writing (PointInstancer prototypes counted once)

MATERIALS = {
    "Floor": ((0.6, 0.6, 0.58), 0.8),
    "Terracotta": ((0.62, 0.3, 0.18), 0.7),
    "Wood": ((0.55, 0.38, 0.2), 0.75),
    "Iron": ((0.15, 0.15, 0.16), 0.5, {"metallic": 0.9}),
}
"""UsdPreviewSurface looks: {name: (diffuse color, roughness, extra inputs)}."""

VASES, CRATES = 60, 20
FRAMES = (1, 2, 3)
BENCH_X = (-9.0, -3.0, 3.0, 9.0)


def vase():
    """Ribbed vase (closed lathe surface with a hollow neck), ~6k triangles."""
    t = np.linspace(0.02, 1.0, 38)
    height = 0.85 * t
    radius = (0.09 + 0.16 * np.exp(-((t - 0.35) / 0.25) ** 2) + 0.02 * t
              + 0.03 * np.exp(-((t - 1.0) / 0.06) ** 2))
    outer = list(zip(radius, height))
    lip = radius[-1]
    profile = [(0.0, 0.0), (0.1, 0.0), *outer, (lip - 0.005, 0.86), (lip - 0.03, 0.855),
               (0.085, 0.8), (0.075, 0.75), (0.0, 0.73)]
    segments = 72
    ribs = np.zeros(len(profile))
    ribs[2:2 + len(outer)] = np.sin(np.pi * t)  # ribs fade out at the foot and the lip
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)[:, None]
    builder = MeshBuilder()
    builder.lathe(profile, segments, radial_scale=1 + 0.035 * np.cos(18 * phi) * ribs)
    return builder


def crate():
    """0.7 m crate resting on y = 0 (no hidden bottom face)."""
    builder = MeshBuilder()
    builder.box((-0.35, 0, -0.35), (0.35, 0.7, 0.35), faces=faces_except("-y"))
    return builder


def bench_parts():
    """Bench (along X, facing -Z) as (slats, frame) builders."""
    slats, frame = MeshBuilder(), MeshBuilder()
    for z0, z1 in ((-0.25, -0.1), (-0.075, 0.075), (0.1, 0.25)):
        slats.box((-0.9, 0.42, z0), (0.9, 0.46, z1))
    for y0, y1 in ((0.6, 0.72), (0.8, 0.92)):
        slats.box((-0.9, y0, 0.26), (0.9, y1, 0.3))
    for x0 in (-0.8, 0.74):
        frame.box((x0, 0, -0.22), (x0 + 0.06, 0.42, 0.22), faces=faces_except("-y"))
        frame.box((x0, 0.42, 0.3), (x0 + 0.06, 0.95, 0.34))
    return slats, frame


def quat_y(angle):
    """Gf.Quath rotating `angle` radians about +Y."""
    return Gf.Quath(float(np.cos(angle / 2)), 0.0, float(np.sin(angle / 2)), 0.0)


def add_scatter(stage, looks):
    """PointInstancer with vase + crate prototypes, at the default time and time-sampled frames."""
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    UsdGeom.Scope.Define(stage, "/World/Scatter/Prototypes")
    vase_mesh = write_mesh(stage, "/World/Scatter/Prototypes/Vase", vase(), looks["Terracotta"])
    crate_mesh = write_mesh(stage, "/World/Scatter/Prototypes/Crate", crate(), looks["Wood"])
    instancer.CreatePrototypesRel().SetTargets([vase_mesh.GetPath(), crate_mesh.GetPath()])

    rng = np.random.default_rng(7)  # fixed seed: identical output on every run
    gx, gz = np.meshgrid(np.linspace(-13.5, 13.5, 10), np.linspace(-13.5, 9.0, 8))
    base = np.column_stack([gx.ravel(), np.zeros(gx.size), gz.ravel()])
    base[:, [0, 2]] += rng.uniform(-0.6, 0.6, (len(base), 2))
    proto = rng.permutation(np.repeat([0, 1], [VASES, CRATES]))
    angle = rng.uniform(0, 2 * np.pi, len(base))
    scale = rng.uniform(0.8, 1.3, len(base))
    slide = rng.normal(size=(len(base), 3)) * [1, 0, 1]
    slide *= 0.15 / np.linalg.norm(slide, axis=1, keepdims=True)  # 15 cm per frame

    instancer.CreateProtoIndicesAttr(Vt.IntArray(proto.tolist()))
    instancer.CreateScalesAttr(Vt.Vec3fArray([Gf.Vec3f(float(s), float(s), float(s)) for s in scale]))
    positions = instancer.CreatePositionsAttr()
    orientations = instancer.CreateOrientationsAttr()
    for time, offset in [(Usd.TimeCode.Default(), 0)] + [(Usd.TimeCode(f), f - FRAMES[0]) for f in FRAMES]:
        points = np.round(base + offset * slide, DECIMALS).astype(np.float32)
        positions.Set(Vt.Vec3fArray.FromNumpy(points), time)
        orientations.Set(Vt.QuathArray([quat_y(a + offset * np.radians(4)) for a in angle]), time)


def add_benches(stage, looks):
    """Bench defined once as a class, referenced by four instanceable prims."""
    UsdGeom.Scope.Define(stage, "/World/Library")
    bench = stage.CreateClassPrim("/World/Library/Bench")
    bench.SetTypeName("Xform")
    slats, frame = bench_parts()
    write_mesh(stage, "/World/Library/Bench/Slats", slats, looks["Wood"])
    write_mesh(stage, "/World/Library/Bench/Frame", frame, looks["Iron"])
    UsdGeom.Xform.Define(stage, "/World/Benches")
    for k, x in enumerate(BENCH_X):
        instance = UsdGeom.Xform.Define(stage, f"/World/Benches/Bench_{k}")
        instance.GetPrim().GetReferences().AddInternalReference(bench.GetPath())
        instance.GetPrim().SetInstanceable(True)
        instance.AddTranslateOp().Set(Gf.Vec3d(x, 0, 12.5))


def build():
    """Floor, PointInstancer scatter (static + time-sampled) and instanceable benches."""
    stage, looks = new_stage(UsdGeom.Tokens.y, 1.0, "instancing", MATERIALS)
    stage.SetStartTimeCode(FRAMES[0])
    stage.SetEndTimeCode(FRAMES[-1])
    stage.SetTimeCodesPerSecond(24)
    floor = MeshBuilder()
    floor.grid((0, 0, 0), Z, X, np.linspace(-15, 15, 16), np.linspace(-15, 15, 16))
    write_mesh(stage, "/World/Floor", floor, looks["Floor"])
    add_scatter(stage, looks)
    add_benches(stage, looks)
    add_daylight(stage, (-50.0, 35.0, 0.0))
    return stage
