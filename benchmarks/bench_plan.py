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

from .city_stage import STAGE_VERSION, TARGET_TRIANGLES, cached_stage

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
QUICK_TRIANGLES = 30_000


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

    wp.config.log_level = wp.LOG_WARNING  # as the CLI does (kernels.startup.start_warp_quietly)
    init_warp("cpu")
    parts: dict = {"import_cli": import_seconds, "warp_init": time.perf_counter() - started}

    from usdbake.core import registry
    from usdbake.core.cache import step_key
    from usdbake.core.pipeline import Pipeline
    from usdbake.core.runtime import Runtime
    from usdbake.kernels.tracer import Tracer
    from usdbake.stages.composition import quiet_composition_warnings
    from usdbake.stages.extract import extract_scene
    from usdbake.stages.inputs import open_source

    bvh = {"seconds": 0.0, "by": ""}
    current = {"name": ""}

    def timed_tracer(scene_, **options):  # the run's one BVH: built when a step first needs it
        t0 = time.perf_counter()
        tracer = Tracer.from_scene(scene_, **options)
        bvh["seconds"], bvh["by"] = time.perf_counter() - t0, current["name"]
        return tracer

    started = time.perf_counter()
    pipeline = Pipeline.build(sorted(registry.registry()), {}, runtime=Runtime(timed_tracer), cache_dir=cache_dir,
                              allow_conflicts=True)
    parts["build_pipeline"] = time.perf_counter() - started
    started = time.perf_counter()
    with quiet_composition_warnings():
        _, stage = open_source(str(stage_path))
    parts["open_stage"] = time.perf_counter() - started
    started = time.perf_counter()
    scene = extract_scene(stage)
    parts["extract_scene"] = time.perf_counter() - started

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
