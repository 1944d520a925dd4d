"""Part 1 of the distributed benchmark: a batch of stages, one stage per task, baked in process, on a
spawned pool and on a Dask cluster; wall times, bytes per task, and the bake layers compared value by value."""

from __future__ import annotations

import pickle
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from . import harness
from .distributed_cluster import start_cluster, stop_cluster
from .distributed_model import list_makespan, lpt_makespan
from .distributed_runs import THREADS

SAMPLES = ("atrium", "building", "city_block", "cornell_box", "instanced_props", "window_room")
QUICK_SAMPLES = ("cornell_box", "window_room")
BATCH_PROCESSORS = ("ambient_occlusion", "sky_visibility")
BATCH_PARAMS = {"ambient_occlusion": {"samples": 64}}
QUICK_BATCH_PARAMS = {"ambient_occlusion": {"samples": 16}, "sky_visibility": {"patch_count": 16, "max_level": 1}}


def layer_values(path: Path) -> dict:
    """{property path: (default, time samples)} of every attribute a bake layer authors: what the bakes
    compare (provenance metadata, which holds timings, left out)."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(path))
    values = {}

    def visit(spec_path):
        spec = layer.GetObjectAtPath(spec_path)
        if isinstance(spec, Sdf.AttributeSpec):
            samples = {t: layer.QueryTimeSample(spec_path, t) for t in layer.ListTimeSamplesForPath(spec_path)}
            values[str(spec_path)] = (spec.default, samples)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return values


def same_layers(folder_a: Path, folder_b: Path, names: tuple[str, ...]) -> tuple[bool, int]:
    """Whether every stage's bake layer in ``folder_a`` authors the same values as in ``folder_b``, and
    how many attributes were compared."""
    same, compared = True, 0
    for name in names:
        a, b = layer_values(folder_a / f"{name}.baked.usdc"), layer_values(folder_b / f"{name}.baked.usdc")
        same &= a.keys() == b.keys() and all(a[k][0] == b[k][0] and a[k][1] == b[k][1] for k in a)
        compared += len(a)
    return bool(same), compared


def batch(names: tuple[str, ...], params: dict) -> dict:
    """Part 1: the stages baked in process one by one, on a spawned pool of 2, and on a 2-worker Dask
    cluster; wall times, overheads, bytes per task, layers compared."""
    from usdbake.core.pipeline import Pipeline
    from usdbake.core.runtime import Runtime
    from usdbake.kernels.tracer import Tracer
    from usdbake.farm.batch import BatchOptions, StageOutcome, bake_many, bake_stage
    from usdbake.stages.bake_file import bake_file

    paths = [str(harness.SAMPLES / f"{name}.usda") for name in names]
    root = Path(tempfile.mkdtemp(prefix="usdbake-bench-batch-"))
    folders = {mode: root / mode for mode in ("in_process", "pool", "dask", "pool_startup")}
    for folder in folders.values():
        folder.mkdir()
    options = BatchOptions(BATCH_PROCESSORS, params, "cpu", None, True)
    warm_stage = harness.SAMPLES / "cornell_box.usda"
    tiny = BatchOptions(("ambient_occlusion",), {"ambient_occlusion": {"samples": 4}}, "cpu", None, True, THREADS)
    bake_stage(str(warm_stage), str(root / "warm.baked.usdc"), BatchOptions(BATCH_PROCESSORS, params, "cpu",
                                                                             None, True, THREADS))

    in_process = {}
    started = time.perf_counter()
    for name, path in zip(names, paths):
        t0 = time.perf_counter()
        bake_file(path, str(folders["in_process"] / f"{name}.baked.usdc"),
                  Pipeline.build(list(BATCH_PROCESSORS), params, cache_dir=None, force=True,
                                 runtime=Runtime(Tracer.from_scene, threads=THREADS)))
        in_process[name] = time.perf_counter() - t0
    in_process_seconds = time.perf_counter() - started

    # the pool's fixed cost: a one-stage, one-worker pool on a tiny bake, less the same bake here
    started = time.perf_counter()
    bake_file(str(harness.SAMPLES / "window_room.usda"), str(folders["pool_startup"] / "here.baked.usdc"),
              tiny.pipeline())
    tiny_here = time.perf_counter() - started
    started = time.perf_counter()
    bake_many([str(harness.SAMPLES / "window_room.usda")], str(folders["pool_startup"]), processors=tiny.processors,
              params=tiny.params, force=True, workers=1)
    pool_startup = time.perf_counter() - started - tiny_here

    started = time.perf_counter()
    pool = bake_many(paths, str(folders["pool"]), processors=BATCH_PROCESSORS, params=params, force=True, workers=2)
    pool_seconds = time.perf_counter() - started

    cluster, client, startup = start_cluster(2, warm_stage, options)
    try:
        started = time.perf_counter()
        dask = bake_many(paths, str(folders["dask"]), processors=BATCH_PROCESSORS, params=params, force=True,
                         scheduler=cluster.scheduler_address)
        dask_seconds = time.perf_counter() - started
    finally:
        stop_cluster(cluster, client)
    failed = [o for o in pool + dask if o.status != "baked"]
    if failed:
        raise RuntimeError(f"{failed[0].input}: {failed[0].status} {failed[0].error}")

    argument_bytes = [len(pickle.dumps((bake_stage, path, str(folders["dask"] / f"{name}.baked.usdc"), options)))
                      for name, path in zip(names, paths)]
    outcome_bytes = [len(pickle.dumps(outcome)) for outcome in dask]
    assert all(isinstance(o, StageOutcome) for o in dask)
    pool_same, compared = same_layers(folders["in_process"], folders["pool"], names)
    dask_same, _ = same_layers(folders["in_process"], folders["dask"], names)
    shutil.rmtree(root, ignore_errors=True)
    stage_seconds = {o.input: o.seconds for o in dask}
    rows = [{"stage": name, "in process (s)": in_process[name], "Dask task, bake only (s)": stage_seconds[path]}
            for name, path in zip(names, paths)]
    return {
        "stages": list(names), "processors": list(BATCH_PROCESSORS), "params": params,
        "in_process_seconds": in_process_seconds, "pool_seconds": pool_seconds, "dask_seconds": dask_seconds,
        "pool_overhead": pool_seconds / in_process_seconds - 1.0,
        "dask_overhead": dask_seconds / in_process_seconds - 1.0,
        "pool_startup_seconds": pool_startup, "dask_startup_seconds": startup["startup_seconds"],
        "dask_warmup_seconds": startup["warmup_seconds"],
        "task_argument_bytes_mean": statistics.mean(argument_bytes), "task_argument_bytes_max": max(argument_bytes),
        "task_result_bytes_mean": statistics.mean(outcome_bytes), "task_result_bytes_max": max(outcome_bytes),
        "dask_stage_seconds_sum": sum(stage_seconds.values()),
        "dask_lpt_seconds": lpt_makespan(list(stage_seconds.values()), 2),
        "dask_in_order_seconds": list_makespan([stage_seconds[path] for path in paths], 2),
        "pool_layers_identical": pool_same, "dask_layers_identical": dask_same, "attributes_compared": compared,
        "per_stage": rows,
    }
