"""Radiosity on an instanced layout: peak memory, seconds and patches of a bake (issue 27, resources).

The layout of the issue: a 1,280-triangle prototype (an icosphere, level 3, 0.4 m radius) under 4
PointInstancers -- each its own copy of the prototype, two of the four a darker red -- standing in a
square grid on a 60 x 60 m floor, lit by a uniform DomeLight and a DistantLight. ``--plain`` writes the
same spheres as ordinary meshes (receivers) instead. Y-up, metres.

Each bake runs ``usdbake bake STAGE -o OUT -p PROCESSOR --cache FRESH --force --json`` in a subprocess of
its own; its peak resident memory is the child's ``ru_maxrss`` (``os.wait4``), its seconds the wall time
(and each step's from the JSON report), its patch count the length of the RadiosityPatches prim's
``areas`` in the bake layer. ``--accuracy`` instead bakes in process and compares the floor's indirect
irradiance with a path tracer.

Not a ``bench_`` module (minutes per layout)::

    python -m usdbake.benchmarks.instanced_radiosity_memory OUT.json [--instances 250 1000] \
        [--processor form_factors] [--plain] [--timeout 1800] [--accuracy [--paths 8192]]

Results of the issue-27 runs (before and after the change): benchmarks/results/runs/instanced_radiosity_memory.json
(a folder of its own: the report reads only the bench_ results beside it).

Results are written after every bake, so a run stopped by a time limit keeps what it measured.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "samples"))  # samples/ is not a package
from mesh_builder import icosphere  # noqa: E402

INSTANCERS = 4
PROTOTYPE_LEVEL = 3
"""Icosphere subdivision level: 20 * 4^3 = 1,280 triangles, the issue's prototype size."""
RADIUS = 0.4
SPACING = 1.6
"""Grid spacing of the instances (m): 1,000 instances cover ~51 x 51 m."""
FLOOR_HALF = 30.0
COLOURS = ((0.7, 0.7, 0.7), (0.6, 0.2, 0.15), (0.7, 0.7, 0.7), (0.6, 0.2, 0.15))
"""Albedo of each instancer's prototype (two materials among the instances)."""


def _material(stage: Usd.Stage, path: str, colour) -> UsdShade.Material:
    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*colour))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


def _mesh(stage: Usd.Stage, path: str, points: np.ndarray, triangles: np.ndarray, material) -> UsdGeom.Mesh:
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(points, np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(triangles), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(triangles, np.int32).ravel()))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    return mesh


def positions(count: int) -> np.ndarray:
    """(count, 3) float64 instance positions on a square grid centred on the origin, resting on the floor."""
    side = int(np.ceil(np.sqrt(count)))
    k = np.arange(count)
    x = (k % side - (side - 1) / 2) * SPACING
    z = (k // side - (side - 1) / 2) * SPACING
    return np.c_[x, np.full(count, RADIUS), z]


def write_layout(path: Path, instances: int, *, plain: bool = False, floor_cells: int = 16,
                 level: int = PROTOTYPE_LEVEL, lights: bool = True) -> dict:
    """Write the layout to ``path`` (the floor a ``floor_cells`` x ``floor_cells`` grid, the prototype an
    icosphere of ``level``, no lights unless ``lights``); returns its triangle counts (rendered, authored)."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    grey = _material(stage, "/World/Looks/Floor", (0.5, 0.5, 0.5))
    looks = [_material(stage, f"/World/Looks/Proto{i}", c) for i, c in enumerate(COLOURS)]
    cells = floor_cells  # the floor as a grid of quads: vertices for the radiosity output
    ticks = np.linspace(-FLOOR_HALF, FLOOR_HALF, cells + 1)
    x, z = np.meshgrid(ticks, ticks)
    floor_points = np.c_[x.ravel(), np.zeros(x.size), z.ravel()]
    a = (np.arange(cells)[None, :] + (cells + 1) * np.arange(cells)[:, None]).ravel()
    floor_tris = np.r_[np.c_[a, a + cells + 1, a + cells + 2], np.c_[a, a + cells + 2, a + 1]]
    _mesh(stage, "/World/Floor", floor_points, floor_tris, grey)
    sphere, sphere_tris = icosphere(level)
    sphere = sphere * RADIUS
    where = positions(instances)
    groups = np.array_split(np.arange(instances), INSTANCERS)
    for g, rows in enumerate(groups):
        if plain:
            for row in rows:
                _mesh(stage, f"/World/Spheres{g}/Sphere{row}", sphere + where[row], sphere_tris, looks[g])
            continue
        instancer = UsdGeom.PointInstancer.Define(stage, f"/World/Instancer{g}")
        proto = _mesh(stage, f"/World/Instancer{g}/Prototypes/Sphere", sphere, sphere_tris, looks[g])
        instancer.CreatePrototypesRel().SetTargets([proto.GetPath()])
        instancer.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(np.zeros(len(rows), np.int32)))
        instancer.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(where[rows].astype(np.float32)))
    if lights:
        dome = UsdLux.DomeLight.Define(stage, "/World/Lights/Sky")
        dome.CreateIntensityAttr(1.0)
        sun = UsdLux.DistantLight.Define(stage, "/World/Lights/Sun")
        sun.CreateIntensityAttr(3.0)
        sun.CreateAngleAttr(0.53)
        UsdGeom.XformCommonAPI(sun).SetRotate(Gf.Vec3f(-50.0, 30.0, 0.0))
    stage.GetRootLayer().Save()
    return {"rendered_triangles": len(floor_tris) + instances * len(sphere_tris),
            "authored_triangles": len(floor_tris) + (instances if plain else INSTANCERS) * len(sphere_tris)}


def bake(stage: Path, processor: str, folder: Path, timeout: float) -> dict:
    """One ``usdbake bake`` in a fresh process: its peak RSS (MB, ``ru_maxrss`` from ``os.wait4``), wall
    seconds, per-step seconds, patches (read back from the bake layer) and exit code."""
    out = folder / f"{stage.stem}.{processor}.baked.usdc"
    command = [sys.executable, "-m", "usdbake.cli.main", "bake", str(stage), "-o", str(out), "-p", processor,
               "--cache", str(folder / f"cache-{processor}-{stage.stem}"), "--force", "--json"]
    log = folder / f"{stage.stem}.{processor}.log"
    started = time.perf_counter()
    with open(log, "w") as stdout_file, open(log.with_suffix(".err"), "w") as stderr_file:
        child = subprocess.Popen(command, stdout=stdout_file, stderr=stderr_file, start_new_session=True)
        # a bake running past the timeout is stopped: its own process group, started above
        timer = threading.Timer(timeout, os.killpg, (child.pid, signal.SIGKILL))
        timer.start()
        _, status, usage = os.wait4(child.pid, 0)
        timer.cancel()
    seconds = time.perf_counter() - started
    rc = os.waitstatus_to_exitcode(status)
    row = {"processor": processor, "rc": rc, "timed_out": rc == -signal.SIGKILL, "seconds": round(seconds, 1),
           "peak_mb": round(usage.ru_maxrss / 1024.0, 1)}
    try:
        report = json.loads(log.read_text())
        row["steps"] = {s["processor"]: {"action": s.get("action"), "seconds": s.get("seconds")}
                        for s in report.get("steps", [])}
    except (json.JSONDecodeError, OSError, KeyError, TypeError):
        row["stderr_tail"] = log.with_suffix(".err").read_text()[-1500:]
    row["patches"] = None
    layer = Sdf.Layer.FindOrOpen(str(out)) if out.exists() else None
    spec = layer.GetAttributeAtPath("/usdbake/RadiosityPatches.areas") if layer else None
    if spec is not None and spec.default is not None:
        row["patches"] = len(spec.default)
    return row


def accuracy(instances: int, folder: Path, *, paths: int = 8192) -> dict:
    """Indirect irradiance at the floor's vertices (the only receiver) of the instanced layout, in process
    at the defaults, against the path tracer of benchmarks/references.py (k + 1 bounces, as
    bench_radiosity's Cornell figure): relative RMS, and the reference's own noise (two halves of its
    paths, seeds 7 and 8, against each other, / sqrt 2 for their mean)."""
    from usdbake.geometry.mesh import vertex_normals
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.radiosity import form_factors as ff
    from usdbake.processors.radiosity import radiosity as rad
    from usdbake.stages.extract import extract_scene

    from . import harness
    from .references import path_traced_indirect

    stage = folder / f"layout_accuracy_{instances}.usda"
    write_layout(stage, instances, floor_cells=24)
    scene = extract_scene(Usd.Stage.Open(str(stage)))
    tracer = Tracer.from_scene(scene)
    ids = harness.receiver_points(scene)
    floor = np.isin(scene.tri_prim, np.unique(scene.point_prim[ids]))  # the receivers' triangles
    tris, areas = scene.tri_vertices[floor], scene.tri_areas[floor]
    normals = vertex_normals(scene.points, tris, scene.tri_normals[floor], areas)[ids]
    positions = rad.vertex_sample_positions(scene.points, tris, areas)[ids]
    started = time.perf_counter()
    product, _ = ff.precompute(tracer, scene, ff.FormFactors.Params())
    solved = rad.solve(tracer, scene, product, rad.Radiosity.Params(), ids)
    seconds = time.perf_counter() - started
    halves = [path_traced_indirect(tracer, scene, positions, normals, paths=paths // 2, bounces=product.bounces + 1,
                                   seed=seed) for seed in (7, 8)]
    reference = 0.5 * (halves[0] + halves[1])
    return {"layout": f"{instances} instances, accuracy", "patches": product.patches.count,
            "floor_vertices": len(ids), "paths": paths, "seconds": round(seconds, 1),
            "error": round(harness.relative_rms(solved["vertex_indirect"], reference), 4),
            "mean_ratio": round(float(solved["vertex_indirect"].mean() / max(reference.mean(), 1e-30)), 4),
            "reference_noise": round(harness.relative_rms(halves[0], halves[1]) / 2, 4)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="results JSON")
    parser.add_argument("--instances", type=int, nargs="+", default=[250, 1000])
    parser.add_argument("--processor", action="append", help="processors to bake, one bake each "
                        "(default: form_factors and radiosity)")
    parser.add_argument("--plain", action="store_true", help="ordinary meshes instead of PointInstancers")
    parser.add_argument("--timeout", type=float, default=1800.0, help="seconds before a bake is stopped")
    parser.add_argument("--keep", metavar="DIR", help="write the stages and bakes here (default: a temporary folder)")
    parser.add_argument("--accuracy", action="store_true", help="instead of bakes: floor indirect irradiance "
                        "against a path tracer, in process (minutes)")
    parser.add_argument("--paths", type=int, default=8192, help="reference paths per floor vertex (--accuracy)")
    args = parser.parse_args(argv)
    processors = args.processor or ["form_factors", "radiosity"]
    results = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "python": sys.version.split()[0]},
               "prototype_triangles": 20 * 4 ** PROTOTYPE_LEVEL, "instancers": INSTANCERS, "rows": []}
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(args.keep or scratch)
        folder.mkdir(parents=True, exist_ok=True)
        for count in args.instances if args.accuracy else ():
            row = accuracy(count, folder, paths=args.paths)
            results["rows"].append(row)
            print(json.dumps(row), flush=True)
            Path(args.out).write_text(json.dumps(results, indent=1))
        for count in () if args.accuracy else args.instances:
            stage = folder / f"layout_{'plain' if args.plain else 'instanced'}_{count}.usda"
            counts = write_layout(stage, count, plain=args.plain)
            for processor in processors:
                row = {"layout": f"{count} {'plain meshes' if args.plain else 'instances'}", **counts,
                       **bake(stage, processor, folder, args.timeout)}
                results["rows"].append(row)
                print(json.dumps(row), flush=True)
                Path(args.out).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
