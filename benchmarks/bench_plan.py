"""`usdbake plan` on a production-like 270k-triangle stage, and `usdbake --help`: wall time and where it goes."""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

NAME = "plan"
DESCRIPTION = (
    "`usdbake plan STAGE` with every processor (the default of `plan`, fresh result cache) on a generated "
    "production-like city stage (`.usdc`, Y-up, metersPerUnit 0.01): a few hundred unwelded flat-shaded "
    "quad meshes (buildings, ground tiles) with authored faceVarying normals and st, UsdPreviewSurface "
    "materials, native instancing (instanceable internal references to /Library prototypes) and two "
    "PointInstancers with their prototypes under the instancer; a sun and a dome light. Triangles are counted "
    "after flattening (instances included). Seconds: median wall time of the whole command as a subprocess, "
    "after one warm-up run (Warp kernels cached); `usdbake --help` and `usdbake plan --help` likewise. The "
    "breakdown is the same work done step by step in a fresh interpreter (median of 3), as cmd_plan and "
    "Pipeline.plan do it: import the CLI, Warp init, build the pipeline (imports the processors), open the "
    "stage, extract_scene, the steps' cache keys (code and scene fingerprints), each processor's applies() "
    "(the first one that needs the tracer pays the BVH build, also reported alone). The issue's figures: plan "
    "on 270k triangles < 5 s, --help < 1 s.")
TARGET_TRIANGLES = 270_000
QUICK_TRIANGLES = 30_000
STAGE_VERSION = 1
"""Bump when the generated stage changes (it is cached under benchmarks/cache by triangles and version)."""

CM = 100.0  # stage units per metre (metersPerUnit 0.01)

# ---------------------------------------------------------------------------
# Geometry: quads (Q, 4, 3), counter-clockwise seen from outside (USD's rightHanded default)


def grid_quads(origin, u, v, nu: int, nv: int) -> np.ndarray:
    """nu x nv quads tiling the parallelogram origin + [0,1] u + [0,1] v; their normal is u x v."""
    a = np.linspace(0.0, 1.0, nu + 1)
    b = np.linspace(0.0, 1.0, nv + 1)
    grid = np.asarray(origin, np.float64) + a[:, None, None] * np.asarray(u) + b[None, :, None] * np.asarray(v)
    return np.stack([grid[:-1, :-1], grid[1:, :-1], grid[1:, 1:], grid[:-1, 1:]], axis=2).reshape(-1, 4, 3)


def box_quads(lo, hi, n=(1, 1, 1), bottom: bool = False) -> np.ndarray:
    """The faces of the box [lo, hi], face i split in n (x, y, z) segments along its sides; no bottom face
    unless ``bottom`` (props stand on the ground)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    sx, sy, sz = hi - lo
    nx, ny, nz = n
    faces = [
        grid_quads((hi[0], lo[1], hi[2]), (0, 0, -sz), (0, sy, 0), nz, ny),   # +x
        grid_quads((lo[0], lo[1], lo[2]), (0, 0, sz), (0, sy, 0), nz, ny),    # -x
        grid_quads((lo[0], lo[1], hi[2]), (sx, 0, 0), (0, sy, 0), nx, ny),    # +z
        grid_quads((hi[0], lo[1], lo[2]), (-sx, 0, 0), (0, sy, 0), nx, ny),   # -z
        grid_quads((lo[0], hi[1], hi[2]), (sx, 0, 0), (0, 0, -sz), nx, nz),   # +y
    ]
    if bottom:
        faces.append(grid_quads((lo[0], lo[1], lo[2]), (sx, 0, 0), (0, 0, sz), nx, nz))  # -y
    return np.concatenate(faces)


def blob_quads(n: int, radius, center, rng, jitter: float = 0.0) -> np.ndarray:
    """A cube-sphere (n x n quads per cube face) of per-axis ``radius`` around ``center``; the corners
    pushed radially by up to ``jitter`` (a rock, a tree crown). Unwelded: every quad its own corners."""
    quads = box_quads((-1, -1, -1), (1, 1, 1), (n, n, n), bottom=True)
    directions = quads / np.linalg.norm(quads, axis=2, keepdims=True)
    if jitter:  # one radius per distinct corner position, so the unwelded quads still meet
        keys = np.round(directions.reshape(-1, 3), 6)
        _, inverse = np.unique(keys, axis=0, return_inverse=True)
        bumps = 1.0 + jitter * (rng.random(inverse.max() + 1) - 0.5)
        directions = directions * bumps[inverse.reshape(-1)].reshape(directions.shape[:2])[..., None]
    return directions * np.asarray(radius, np.float64) + np.asarray(center, np.float64)


def building_quads(width: float, depth: float, floors: int, columns_x: int, columns_z: int) -> np.ndarray:
    """A building: facades of one quad per window bay and floor (3.5 m floors), a roof of 2 x 2 quads."""
    height = floors * 3.5 * CM
    return box_quads((-width / 2, 0, -depth / 2), (width / 2, height, depth / 2), (columns_x, floors, columns_z))


def building_triangles(floors: int, columns_x: int, columns_z: int) -> int:
    return 2 * (2 * floors * (columns_x + columns_z) + columns_x * columns_z)


# ---------------------------------------------------------------------------
# The stage


def _materials(stage, root: str, specs: dict) -> dict:
    from pxr import Gf, Sdf, UsdGeom, UsdShade

    UsdGeom.Scope.Define(stage, root)
    looks = {}
    for name, (color, roughness) in specs.items():
        material = UsdShade.Material.Define(stage, f"{root}/{name}")
        shader = UsdShade.Shader.Define(stage, f"{root}/{name}/PreviewSurface")
        shader.CreateIdAttr("UsdPreviewSurface")
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
        shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
        material.CreateSurfaceOutput().ConnectToSource(shader.CreateOutput("surface", Sdf.ValueTypeNames.Token))
        looks[name] = material
    return looks


def _write_quads(stage, path: str, quads: np.ndarray, material, translate=None, rotate_y: float = 0.0):
    """An unwelded flat-shaded quad mesh as a DCC exports it: 4 points per face, faceVarying normals and
    st (1 m texture tiles), extent, no subdivision, a bound material."""
    from pxr import Gf, Sdf, UsdGeom, UsdShade, Vt

    quads = np.asarray(quads, np.float64)
    count = len(quads)
    normal = np.cross(quads[:, 1] - quads[:, 0], quads[:, 3] - quads[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    points = quads.reshape(-1, 3).astype(np.float32)
    # st: the quad's corners in its own plane, in metres
    u_axis = quads[:, 1] - quads[:, 0]
    u_axis /= np.maximum(np.linalg.norm(u_axis, axis=1, keepdims=True), 1e-12)
    v_axis = np.cross(normal, u_axis)
    local = quads - quads[:, :1]
    st = np.stack([(local * u_axis[:, None]).sum(2), (local * v_axis[:, None]).sum(2)], axis=2) / CM
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(count, 4, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.arange(4 * count, dtype=np.int32)))
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([points.min(0), points.max(0)])))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.repeat(normal, 4, axis=0).astype(np.float32)))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
                                            ).Set(Vt.Vec2fArray.FromNumpy(st.reshape(-1, 2).astype(np.float32)))
    if translate is not None:
        mesh.AddTranslateOp().Set(Gf.Vec3d(*map(float, translate)))
    if rotate_y:
        mesh.AddRotateYOp().Set(float(rotate_y))
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    return mesh


def _prop_parts(rng) -> dict[str, list[tuple[str, np.ndarray, str]]]:
    """The native-instancing prototypes: {name: [(mesh name, quads, material name)]}, in cm."""
    slats = np.concatenate([box_quads((-90, 42, z0), (90, 46, z0 + 15), (6, 1, 1)) for z0 in (-25, -7.5, 10)]
                           + [box_quads((-90, y0, 26), (90, y0 + 12, 30), (6, 1, 1)) for y0 in (60, 80)])
    frame = np.concatenate([box_quads((x0, 0, -22), (x0 + 6, 42, 22), (1, 3, 2)) for x0 in (-80, 74)]
                           + [box_quads((x0, 42, 30), (x0 + 6, 95, 34), (1, 3, 1)) for x0 in (-80, 74)])
    pole = box_quads((-6, 0, -6), (6, 450, 6), (2, 12, 2))
    head = blob_quads(3, (35, 15, 35), (0, 465, 0), rng)
    bin_body = box_quads((-30, 0, -30), (30, 95, 30), (3, 4, 3))
    return {"Bench": [("Slats", slats, "Wood"), ("Frame", frame, "Iron")],
            "Lamp": [("Pole", pole, "Iron"), ("Head", head, "Glass")],
            "Kiosk": [("Body", bin_body, "Paint"), ("Roof", blob_quads(2, (45, 12, 45), (0, 100, 0), rng),
                                                     "Iron")]}


def _tree_parts(rng, crown_n: int, trunk_segments: int) -> list[tuple[str, np.ndarray, str]]:
    trunk = box_quads((-15, 0, -15), (15, 400, 15), (1, trunk_segments, 1))
    crown = blob_quads(crown_n, (260, 320, 260), (0, 650, 0), rng, jitter=0.25)
    return [("Trunk", trunk, "Bark"), ("Crown", crown, "Leaves")]


def _triangles(parts) -> int:
    return 2 * sum(len(quads) for _, quads, _ in parts)


def build_stage(path: Path, triangles: int, seed: int = 0) -> dict:
    """Write the city stage of about ``triangles`` triangles (after flattening instances) to ``path``;
    the count of each kind of content."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, Vt

    rng = np.random.default_rng(seed)  # fixed: the same stage on every machine
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    looks = _materials(stage, "/World/Looks", {
        "Asphalt": ((0.18, 0.18, 0.19), 0.9), "Concrete": ((0.55, 0.54, 0.5), 0.8),
        "Brick": ((0.55, 0.3, 0.22), 0.85), "Plaster": ((0.8, 0.76, 0.68), 0.7),
        "Bark": ((0.3, 0.22, 0.15), 0.9), "Leaves": ((0.2, 0.4, 0.15), 0.8), "Rock": ((0.45, 0.44, 0.42), 0.9)})
    side = 40000.0 * np.sqrt(triangles / TARGET_TRIANGLES)  # the city's side in cm: same density at any size
    counts = {}

    # ground: tiles of 20 x 20 quads (~5% of the triangles)
    tiles = max(1, int(round(np.sqrt(0.05 * triangles / 800))))
    UsdGeom.Xform.Define(stage, "/World/Ground")
    step = side / tiles
    for i in range(tiles):
        for j in range(tiles):
            origin = (-side / 2 + i * step, 0.0, -side / 2 + (j + 1) * step)
            _write_quads(stage, f"/World/Ground/Tile_{i}_{j}", grid_quads(origin, (step, 0, 0), (0, 0, -step), 20, 20),
                         looks["Asphalt"])
    counts["ground_triangles"] = tiles * tiles * 800

    # native instancing: prototypes under the class /Library, instanceable internal references (~15%)
    stage.CreateClassPrim("/Library")
    props = _prop_parts(rng)
    prop_triangles = {}
    for name, parts in props.items():
        UsdGeom.Xform.Define(stage, f"/Library/{name}")
        prop_looks = _materials(stage, f"/Library/{name}/Looks", {
            "Wood": ((0.5, 0.34, 0.2), 0.75), "Iron": ((0.15, 0.15, 0.16), 0.5),
            "Glass": ((0.9, 0.9, 0.85), 0.1), "Paint": ((0.1, 0.35, 0.2), 0.6)})
        for mesh_name, quads, look in parts:
            _write_quads(stage, f"/Library/{name}/{mesh_name}", quads, prop_looks[look])
        prop_triangles[name] = _triangles(parts)
    mean_prop = float(np.mean(list(prop_triangles.values())))
    native = max(3, int(round(0.15 * triangles / mean_prop)))
    UsdGeom.Xform.Define(stage, "/World/Props")
    kinds = list(props)
    native_triangles = 0
    for k in range(native):
        name = kinds[k % len(kinds)]
        prim = UsdGeom.Xform.Define(stage, f"/World/Props/{name}_{k:04d}")
        x, z = rng.uniform(-side / 2, side / 2, 2)
        prim.AddTranslateOp().Set(Gf.Vec3d(float(x), 0.0, float(z)))
        prim.AddRotateYOp().Set(float(rng.uniform(0, 360)))
        prim.GetPrim().GetReferences().AddInternalReference(Sdf.Path(f"/Library/{name}"))
        prim.GetPrim().SetInstanceable(True)
        native_triangles += prop_triangles[name]
    counts["native_instances"] = native
    counts["native_instance_triangles"] = native_triangles

    # PointInstancers with their prototypes under the instancer: trees (~18%) and rocks (~5%)
    instanced_triangles, point_instances = 0, 0
    for instancer_name, share, prototypes in (
            ("Trees", 0.18, {"TreeA": _tree_parts(rng, 6, 6), "TreeB": _tree_parts(rng, 5, 4)}),
            ("Rocks", 0.05, {f"Rock{r}": [("Rock", blob_quads(3, tuple(rng.uniform(40, 120, 3)), (0, 20, 0), rng,
                                                              jitter=0.4), "Rock")] for r in range(3)})):
        base = f"/World/{instancer_name}"
        instancer = UsdGeom.PointInstancer.Define(stage, base)
        UsdGeom.Scope.Define(stage, f"{base}/Prototypes")
        targets, proto_triangles = [], []
        for proto, parts in prototypes.items():
            root = UsdGeom.Xform.Define(stage, f"{base}/Prototypes/{proto}")
            for mesh_name, quads, look in parts:
                _write_quads(stage, f"{base}/Prototypes/{proto}/{mesh_name}", quads, looks[look])
            targets.append(root.GetPath())
            proto_triangles.append(_triangles(parts))
        n = max(2, int(round(share * triangles / np.mean(proto_triangles))))
        indices = rng.integers(0, len(targets), n).astype(np.int32)
        positions = np.c_[rng.uniform(-side / 2, side / 2, n), np.zeros(n), rng.uniform(-side / 2, side / 2, n)]
        angles = rng.uniform(0, np.pi, n)  # half-angles of a rotation about +Y
        orientations = np.c_[np.cos(angles), np.zeros(n), np.sin(angles), np.zeros(n)]
        instancer.CreatePrototypesRel().SetTargets(targets)
        instancer.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(indices))
        instancer.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(positions.astype(np.float32)))
        instancer.CreateOrientationsAttr(Vt.QuathArray([Gf.Quath(*map(float, q)) for q in orientations]))
        instancer.CreateScalesAttr(Vt.Vec3fArray.FromNumpy(np.repeat(rng.uniform(0.7, 1.3, (n, 1)), 3, axis=1)
                                                          .astype(np.float32)))
        instanced_triangles += int(np.asarray(proto_triangles)[indices].sum())
        point_instances += n
    counts["point_instances"] = point_instances
    counts["point_instance_triangles"] = instanced_triangles

    # buildings fill the rest of the budget, on a jittered grid of lots
    budget = triangles - counts["ground_triangles"] - native_triangles - instanced_triangles
    UsdGeom.Xform.Define(stage, "/World/Buildings")
    building_total, b = 0, 0
    while building_total < budget:
        width, depth = rng.uniform(8, 30, 2) * CM
        floors = int(rng.integers(3, 16))
        cx, cz = max(1, int(width / (3 * CM))), max(1, int(depth / (3 * CM)))
        tris = building_triangles(floors, cx, cz)
        _write_quads(stage, f"/World/Buildings/Building_{b:04d}", building_quads(width, depth, floors, cx, cz),
                     looks[("Concrete", "Brick", "Plaster")[b % 3]],
                     translate=(rng.uniform(-side / 2, side / 2), 0.0, rng.uniform(-side / 2, side / 2)),
                     rotate_y=float(rng.choice([0.0, 90.0, rng.uniform(0, 360)])))
        building_total += tris
        b += 1
    counts["buildings"] = b
    counts["building_triangles"] = building_total

    UsdGeom.Scope.Define(stage, "/World/Lights")
    sun = UsdLux.DistantLight.Define(stage, "/World/Lights/Sun")
    sun.CreateIntensityAttr(50000.0)
    sun.CreateAngleAttr(0.53)
    sun.AddRotateXYZOp().Set(Gf.Vec3f(-50.0, 30.0, 0.0))
    UsdLux.DomeLight.Define(stage, "/World/Lights/Sky").CreateIntensityAttr(0.3)
    stage.GetRootLayer().Save()
    counts["triangles"] = (counts["ground_triangles"] + native_triangles + instanced_triangles + building_total)
    counts["mesh_prims_authored"] = sum(1 for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)) + sum(
        len(parts) for parts in props.values())
    return counts


def cached_stage(triangles: int) -> Path:
    """The generated stage of ``triangles``, built once under benchmarks/cache."""
    from . import harness

    path = harness.CACHE / f"plan_city_{triangles}_v{STAGE_VERSION}.usdc"
    if not path.exists():
        harness.CACHE.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f"{path.stem}.{os.getpid()}.partial.usdc")
        try:
            build_stage(partial, triangles)
            os.replace(partial, path)
        finally:
            if partial.exists():
                partial.unlink()
    return path


# ---------------------------------------------------------------------------
# Timing


def _usdbake_command() -> list[str]:
    """The installed `usdbake` script next to this Python, else `python -m usdbake.cli.main`."""
    script = Path(sys.executable).with_name("usdbake")
    return [str(script)] if script.exists() else [sys.executable, "-m", "usdbake.cli.main"]


def _wall(command: list[str], repeats: int) -> list[float]:
    seconds = []
    for _ in range(repeats):
        started = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True, env={**os.environ, "COLUMNS": "120"})
        seconds.append(time.perf_counter() - started)
    return seconds


BREAKDOWN = """
import json, sys, time
started = time.perf_counter()
import usdbake.cli.main
imported = time.perf_counter() - started
from usdbake.benchmarks.bench_plan import breakdown
print(json.dumps(breakdown(sys.argv[1], sys.argv[2], import_seconds=imported)))
"""
"""The in-process breakdown, in a fresh interpreter like the command's (cold imports and caches)."""


def breakdown(stage_path: str, cache_dir: str, *, import_seconds: float = 0.0) -> dict:
    """One `plan` done step by step, as cmd_plan and Pipeline.plan do it: seconds of each part."""
    started = time.perf_counter()
    import warp as wp

    from usdbake import init_warp

    wp.config.log_level = wp.LOG_WARNING  # as the CLI does (_quiet_warp)
    init_warp("cpu")
    parts: dict = {"import_cli": import_seconds, "warp_init": time.perf_counter() - started}

    from usdbake.core import registry
    from usdbake.core.cache import step_key
    from usdbake.core.pipeline import Pipeline
    from usdbake.stages.composition import quiet_composition_warnings
    from usdbake.stages.extract import extract_scene
    from usdbake.stages.inputs import open_source

    started = time.perf_counter()
    pipeline = Pipeline.build(sorted(registry.registry()), {}, cache_dir=cache_dir, allow_conflicts=True)
    parts["build_pipeline"] = time.perf_counter() - started
    started = time.perf_counter()
    with quiet_composition_warnings():
        _, stage = open_source(str(stage_path))
    parts["open_stage"] = time.perf_counter() - started
    started = time.perf_counter()
    scene = extract_scene(stage)
    parts["extract_scene"] = time.perf_counter() - started

    bvh = {"seconds": 0.0, "by": ""}
    current = {"name": ""}
    make_tracer = pipeline.tracer_for

    def timed_tracer_for(scene_):
        build = make_tracer(scene_)

        def timed():
            t0 = time.perf_counter()
            tracer = build()
            if not bvh["by"]:  # the first call builds the shared BVH; later ones reuse it
                bvh["seconds"], bvh["by"] = time.perf_counter() - t0, current["name"]
            return tracer
        return timed

    pipeline.tracer_for = timed_tracer_for
    keys: dict[str, str] = {}
    producers = {product: step.name for step in pipeline.steps for product in step.processor.provides}
    key_seconds, applies = {}, {}
    for step in pipeline.steps:
        current["name"] = step.name
        upstream = sorted({producers[p] for p in step.processor.requires})
        t0 = time.perf_counter()
        keys[step.name] = step_key(step, scene, [keys[name] for name in sorted({*upstream, *step.after})])
        key_seconds[step.name] = time.perf_counter() - t0
        t0 = time.perf_counter()
        step.processor.applies(pipeline.context(step, scene))
        applies[step.name] = time.perf_counter() - t0
    parts["cache_keys_total"] = sum(key_seconds.values())
    parts["applies_total"] = sum(applies.values())
    parts["bvh_build"] = bvh["seconds"]
    parts["bvh_built_by"] = bvh["by"]
    parts["cache_keys"] = key_seconds
    parts["applies"] = applies
    parts["scene_triangles"] = int(scene.num_triangles)
    parts["scene_points"] = int(scene.num_points)
    parts["scene_prims"] = len(scene.prim_paths)
    parts["scene_instances"] = len(scene.instances)
    return parts


def _breakdown_runs(stage_path: Path, cache_dir: str, repeats: int) -> list[dict]:
    runs = []
    for _ in range(repeats):
        done = subprocess.run([sys.executable, "-c", BREAKDOWN, str(stage_path), cache_dir], check=True,
                              capture_output=True, text=True)
        runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    return runs


def run(quick: bool = False) -> dict:
    from . import harness

    triangles = QUICK_TRIANGLES if quick else TARGET_TRIANGLES
    repeats = 1 if quick else 5
    help_repeats = 1 if quick else 7
    started = time.perf_counter()
    stage_path = cached_stage(triangles)
    stage_seconds = time.perf_counter() - started
    usdbake = _usdbake_command()
    cache_dir = tempfile.mkdtemp(prefix="usdbake-plan-bench-")  # empty: every step plans 'run' or 'skip'
    try:
        plan = usdbake + ["plan", str(stage_path), "--cache", cache_dir]
        # warm-up (Warp kernel cache, OS file cache); the quick sweep's one run is its own warm-up
        first = None if quick else _wall(plan, 1)[0]
        plan_runs = _wall(plan, repeats)
        first = plan_runs[0] if first is None else first
        help_runs = _wall(usdbake + ["--help"], help_repeats)
        plan_help_runs = _wall(usdbake + ["plan", "--help"], help_repeats)
        parts_runs = _breakdown_runs(stage_path, cache_dir, 1 if quick else 3)
    finally:
        shutil.rmtree(cache_dir, ignore_errors=True)

    def median(key, sub=None):
        return statistics.median(p[key] if sub is None else p[key][sub] for p in parts_runs)

    parts = parts_runs[0]
    names = list(parts["applies"])
    applies = {name: median("applies", name) for name in names}
    keys = {name: median("cache_keys", name) for name in names}
    plan_seconds = statistics.median(plan_runs)
    in_process = sum(median(k) for k in ("import_cli", "warp_init", "build_pipeline", "open_stage",
                                         "extract_scene", "cache_keys_total", "applies_total"))
    figures = {
        "triangles": parts["scene_triangles"],
        "plan_seconds": round(plan_seconds, 3),
        "plan_first_run_seconds": round(first, 3),
        "help_seconds": round(statistics.median(help_runs), 3),
        "plan_help_seconds": round(statistics.median(plan_help_runs), 3),
        "import_cli_seconds": round(median("import_cli"), 3),
        "warp_init_seconds": round(median("warp_init"), 3),
        "build_pipeline_seconds": round(median("build_pipeline"), 3),
        "open_stage_seconds": round(median("open_stage"), 3),
        "extract_scene_seconds": round(median("extract_scene"), 3),
        "cache_keys_seconds": round(median("cache_keys_total"), 3),
        "applies_seconds": round(median("applies_total"), 3),
        "bvh_build_seconds": round(median("bvh_build"), 3),
        "measured_parts_seconds": round(in_process, 3),
        "unaccounted_seconds": round(plan_seconds - in_process, 3),
    }
    figures.update({f"applies_{name}_seconds": round(seconds, 4) for name, seconds in applies.items()})
    print(f"  stage {stage_path.name}: {parts['scene_triangles']} triangles, {parts['scene_points']} points, "
          f"{parts['scene_prims']} mesh prims, {parts['scene_instances']} PointInstancer instances"
          + (f" (built in {stage_seconds:.1f} s)" if stage_seconds > 0.5 else ""))
    print(f"  plan {plan_seconds:.2f} s (runs {', '.join(f'{s:.2f}' for s in plan_runs)}; first {first:.2f}); "
          f"--help {figures['help_seconds']:.2f} s; plan --help {figures['plan_help_seconds']:.2f} s")
    print(f"  breakdown: import {figures['import_cli_seconds']:.2f}, warp init {figures['warp_init_seconds']:.2f}, "
          f"build pipeline {figures['build_pipeline_seconds']:.2f}, open {figures['open_stage_seconds']:.2f}, "
          f"extract {figures['extract_scene_seconds']:.2f}, cache keys {figures['cache_keys_seconds']:.2f}, "
          f"applies {figures['applies_seconds']:.2f} (BVH {figures['bvh_build_seconds']:.2f} in "
          f"{parts['bvh_built_by'] or 'none'}), unaccounted {figures['unaccounted_seconds']:.2f}")
    print("  applies: " + ", ".join(f"{n} {s:.3f}" for n, s in sorted(applies.items(), key=lambda i: -i[1])))
    print("  cache keys: " + ", ".join(f"{n} {s:.3f}" for n, s in sorted(keys.items(), key=lambda i: -i[1])))

    points = [
        {"label": f"plan {parts['scene_triangles'] // 1000}k", "seconds": plan_seconds, "error": 0.0,
         "runs": plan_runs, "default": True},
        {"label": "--help", "seconds": figures["help_seconds"], "error": 0.0, "runs": help_runs},
        {"label": "plan --help", "seconds": figures["plan_help_seconds"], "error": 0.0, "runs": plan_help_runs},
    ]
    rows = [{"part": "import usdbake.cli.main", "seconds": median("import_cli")},
            {"part": "Warp init", "seconds": median("warp_init")},
            {"part": "build pipeline (imports the processors)", "seconds": median("build_pipeline")},
            {"part": "open stage", "seconds": median("open_stage")},
            {"part": "extract_scene", "seconds": median("extract_scene")},
            {"part": "cache keys (code and scene fingerprints), all steps", "seconds": median("cache_keys_total")}]
    rows += [{"part": f"applies: {name}", "seconds": applies[name]} for name in names]
    rows += [{"part": f"(BVH build, inside applies: {parts['bvh_built_by'] or 'none'})",
              "seconds": median("bvh_build")},
             {"part": "interpreter start, output (plan - parts above)", "seconds": figures["unaccounted_seconds"]},
             {"part": "**usdbake plan (subprocess, median)**", "seconds": plan_seconds}]
    table = "\n\n".join([
        harness.markdown_table([{"command": f"usdbake {p['label']}", "seconds": p["seconds"]} for p in points],
                               ["command", "seconds"]),
        f"Where `plan` spends its time ({parts['scene_triangles']:,} triangles, fresh interpreter):\n\n"
        + harness.markdown_table(rows, ["part", "seconds"]),
    ])
    return harness.result(NAME, description=DESCRIPTION,
                          settings={"triangles_requested": triangles, "stage": stage_path.name,
                                    "stage_version": STAGE_VERSION, "repeats": repeats,
                                    "help_repeats": help_repeats, "breakdown_repeats": len(parts_runs),
                                    "command": "usdbake plan STAGE --cache EMPTY_DIR",
                                    "scene_points": parts["scene_points"], "scene_mesh_prims": parts["scene_prims"],
                                    "scene_point_instances": parts["scene_instances"],
                                    "cache_key_seconds_per_step": {n: round(s, 4) for n, s in keys.items()}},
                          points=points, figures=figures, table=table, knob="command",
                          error_label="(none: timing only)")
