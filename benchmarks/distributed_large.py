"""Parts 2 and 3 of the distributed benchmark: one large scene (the atrium sample referenced side by side)
baked in process and on 2 and 1 Dask workers, a profile run in fine chunks, and the scaling model
(``distributed_model.predict``) checked against the 1- and 2-worker runs, then evaluated up to 64 workers."""

from __future__ import annotations

import gc
import statistics
import time

from . import harness
from .distributed_batch import BATCH_PROCESSORS, QUICK_BATCH_PARAMS
from .distributed_cluster import (MMAP_THRESHOLD, bvh_in_fresh_process, fixed_costs, nanny_environ, start_cluster,
                                  stop_cluster, worker_bvh_seconds)
from .distributed_model import broadcast_hops, per_task_compute, predict, profile_maps, worker_setup_seconds
from .distributed_runs import THREADS, median_run, run_in_process, run_on_dask

LARGE_COPIES = 4
"""atrium.usda (51,216 triangles) referenced this many times: 204,864 triangles."""
QUICK_LARGE_COPIES = 1
LARGE_PARAMS = {"ambient_occlusion": {"samples": 64}, "sky_visibility": {"patch_count": 64, "max_level": 1}}
QUICK_LARGE_PARAMS = {"ambient_occlusion": {"samples": 4}, "sky_visibility": {"patch_count": 16, "max_level": 0}}
REPEATS = 3
"""Runs of each large-scene configuration; the median is reported (the machine is shared)."""
PROFILE_CHUNK = 256
"""Items per task of the profile run: about the chunks 64 workers get by default (4 per worker) on this
scene's sky-visibility maps (62,500 faces each), fine enough to re-cut into any coarser chunking."""
MODEL_WORKERS = (1, 2, 4, 8, 16, 32, 64)
DOCUMENTED_TASK_OVERHEAD = 1e-3
"""Dask's own figure, "each task suffers about 1ms of overhead" (distributed.dask.org): the scheduler's
per-task time of a second set of predictions, beside the bound measured here (2 cores shared)."""


def large_scene(copies: int):
    """atrium.usda referenced ``copies`` times side by side (10% gaps, rows of 2), flattened by extraction."""
    from pxr import Gf, Usd, UsdGeom

    from usdbake.stages.extract import extract_scene

    source = harness.SAMPLES / "atrium.usda"
    atrium = Usd.Stage.Open(str(source))
    size = UsdGeom.BBoxCache(Usd.TimeCode.Default(), ["default"]).ComputeWorldBound(
        atrium.GetPseudoRoot()).ComputeAlignedRange().GetSize()
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.GetStageUpAxis(atrium))
    UsdGeom.SetStageMetersPerUnit(stage, UsdGeom.GetStageMetersPerUnit(atrium))
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    for k in range(copies):
        copy = UsdGeom.Xform.Define(stage, f"/World/Atrium_{k}")
        copy.AddTranslateOp().Set(Gf.Vec3d((k % 2) * size[0] * 1.1, 0.0, (k // 2) * size[2] * 1.1))
        copy.GetPrim().GetReferences().AddReference(str(source))
    return extract_scene(stage)


def large(quick: bool, clean_environ: dict) -> dict:
    """Parts 2 and 3: the large scene in process and on 2 and 1 workers (median of ``repeats`` runs
    each), the profile run, the model."""
    from usdbake.kernels.tracer import Tracer

    copies = QUICK_LARGE_COPIES if quick else LARGE_COPIES
    params = QUICK_LARGE_PARAMS if quick else LARGE_PARAMS
    repeats = 1 if quick else REPEATS
    started = time.perf_counter()
    scene = large_scene(copies)
    extract_seconds = time.perf_counter() - started
    bvh = {}
    for threads in (1, THREADS):
        started = time.perf_counter()
        Tracer.from_scene(scene, threads=threads)
        bvh[threads] = time.perf_counter() - started
    runs, clusters, bvh["worker"] = measure_runs(scene, params, repeats)

    environ = nanny_environ()
    bvh["fresh"] = bvh["fresh_nanny_environ"] = bvh["fresh_nanny_mmap"] = None  # the quick sweep skips these
    if not quick:
        bvh["fresh"] = bvh_in_fresh_process(copies, clean_environ)
        bvh["fresh_nanny_environ"] = bvh_in_fresh_process(copies, {**clean_environ, **environ})
        bvh["fresh_nanny_mmap"] = bvh_in_fresh_process(copies, {**clean_environ, **environ,
                                                                "MALLOC_MMAP_THRESHOLD_": MMAP_THRESHOLD})
    out = {"triangles": int(scene.num_triangles), "points": int(scene.num_points), "copies": copies,
           "bvh_worker_seconds": bvh["worker"], "bvh_fresh_process_seconds": bvh["fresh"],
           "bvh_fresh_process_nanny_environ_seconds": bvh["fresh_nanny_environ"], "nanny_environ": environ,
           "bvh_fresh_process_nanny_environ_mmap_seconds": bvh["fresh_nanny_mmap"],
           "params": params, "repeats": repeats, "extract_seconds": extract_seconds, "bvh_1_thread_seconds": bvh[1],
           "bvh_2_threads_seconds": bvh[THREADS], "clusters": clusters, "processors": {}}
    for name in params:
        out["processors"][name] = processor_summary(runs[name], clusters)
    return out


def measure_runs(scene, params: dict, repeats: int) -> tuple[dict, dict, float]:
    """Each processor of ``params`` on ``scene`` in process, on 2 and on 1 workers (median of ``repeats``
    runs), and a profile run in chunks of PROFILE_CHUNK on 1 worker: {processor: {configuration: run}},
    {workers: the cluster's start-up and fixed costs}, and the median BVH build in a worker."""
    from usdbake.farm.batch import BatchOptions

    warm_options = BatchOptions(BATCH_PROCESSORS, QUICK_BATCH_PARAMS, "cpu", None, True)
    warm_stage = harness.SAMPLES / "cornell_box.usda"
    processors = list(params)
    runs: dict = {name: {} for name in processors}
    reference = {}
    for name in processors:  # this process is warm: the batch baked the same processors
        here = [run_in_process(scene, name, params) for _ in range(repeats)]
        reference[name] = here[0]["outputs"]
        runs[name]["in_process"] = median_run(here, reference[name])
    clusters = {}
    for workers in (2, 1):
        cluster, client, startup = start_cluster(workers, warm_stage, warm_options)
        try:
            costs = fixed_costs(client, workers)
            for name in processors:
                done = []
                for _ in range(repeats):
                    done.append(run_on_dask(scene, name, params, client))
                    gc.collect()  # the run's scene copy goes, and with it its scatter on the workers
                runs[name][f"dask_{workers}"] = median_run(done, reference[name])
            if workers == 1:
                worker_bvh = worker_bvh_seconds(client, scene, repeats)
                for name in processors:
                    runs[name]["profile"] = median_run([run_on_dask(scene, name, params, client,
                                                                    chunk_size=PROFILE_CHUNK)], reference[name])
                    gc.collect()
        finally:
            stop_cluster(cluster, client)
        clusters[workers] = {**startup, **costs}
    return runs, clusters, worker_bvh


def model_constants(here: dict, measured: dict, one: dict, cluster: dict, *, bandwidth: float, setup: float,
                    fixed: float) -> dict:
    """The constants ``predict`` reads for a run ``measured`` on ``cluster``: the serial part of the run in
    process (``here``), transfer sizes of the 1-worker run (``one``), the scatter ``bandwidth``, the
    worker set-up and per-task compute of the profile, the cluster's fixed costs."""
    return {"serial_seconds": here["serial_seconds"], "client_bvh_seconds": measured["client_bvh_seconds"],
            "scene_pickled_bytes": one["scene_pickled_bytes"], "scatter_bytes_per_s": bandwidth,
            "setting_scatter_bytes": one["setting_scatter_bytes"], "worker_bvh_seconds": setup,
            "item_bytes": sum(one["item_bytes"]), "result_bytes": one["stats"]["result_bytes"],
            "static_bytes_per_task": statistics.mean(one["static_bytes"]),
            "gather_bytes_per_s": cluster["gather_bytes_per_s"],
            "round_trip_s": cluster["round_trip_s"], "per_task_compute_s": fixed,
            "noop_compute_s": cluster["noop_compute_s"],
            "overhead_per_task_s": cluster["overhead_per_task_s"],
            "scheduler_per_task_s": cluster["scheduler_per_task_s"]}


def scaling_predictions(maps: list[dict], constants: dict) -> tuple[list[dict], list[dict]]:
    """``predict`` for each of MODEL_WORKERS with ``constants``, and again with the scheduler's time per
    task at DOCUMENTED_TASK_OVERHEAD; each with its speed-up over 1 worker and its efficiency."""
    predictions = [predict(maps, w, constants) for w in MODEL_WORKERS]
    documented = {**constants, "scheduler_per_task_s": DOCUMENTED_TASK_OVERHEAD}
    predictions_documented = [predict(maps, w, documented) for w in MODEL_WORKERS]
    for series in (predictions, predictions_documented):
        for p in series:
            p["speedup"] = series[0]["seconds"] / p["seconds"]
            p["efficiency"] = p["speedup"] / p["workers"]
    return predictions, predictions_documented


def processor_summary(runs: dict, clusters: dict) -> dict:
    """What one processor's runs (``measure_runs``) measured, the model checked against the 1- and
    2-worker runs, and its predictions."""
    here, two, one, profile = (runs[k] for k in ("in_process", "dask_2", "dask_1", "profile"))
    same = all(runs[k]["identical"] for k in ("in_process", "dask_2", "dask_1", "profile"))
    tasks = two["tasks"]
    bandwidth = one["scene_pickled_bytes"] * broadcast_hops(1) / max(one["scatter_seconds"], 1e-9)
    setup = worker_setup_seconds(profile)
    fixed = per_task_compute(profile, one)
    maps = profile_maps(profile, setup)
    model_check, constants = {}, {}
    for workers, measured in ((1, one), (2, two)):
        c = model_constants(here, measured, one, clusters[workers], bandwidth=bandwidth, setup=setup, fixed=fixed)
        constants[workers] = c
        predicted = predict(maps, workers, c)
        model_check[workers] = {"predicted": predicted["seconds"], "measured": measured["wall"],
                                "error": predicted["seconds"] / measured["wall"] - 1.0, "parts": predicted,
                                "scatter_measured": measured["scatter_seconds"],
                                "scatter_predicted": predicted["scatter"],
                                "outside_tasks_measured": measured["outside_tasks_seconds"]}
    # beyond this machine: the 2-worker constants (its scheduler shares the cores with the workers,
    # as on a busy head node; its bandwidth is a memory copy: see docs/distributed.md)
    predictions, predictions_documented = scaling_predictions(maps, constants[2])
    serial_all = here["serial_seconds"] + two["client_bvh_seconds"] + setup
    return {
        "bit_identical": bool(same),
        "in_process_seconds": here["wall"], "dask_2_seconds": two["wall"], "dask_1_seconds": one["wall"],
        "in_process_walls": here["walls"], "dask_2_walls": two["walls"], "dask_1_walls": one["walls"],
        "profile_seconds": profile["wall"],
        "overhead_equal_cores": two["wall"] / here["wall"] - 1.0,
        "speedup_2_over_1_workers": one["wall"] / two["wall"],
        "in_process_maps_seconds": here["maps_seconds"], "in_process_map_calls": here["map_calls"],
        "in_process_bvh_seconds": here["bvh_seconds"], "in_process_serial_seconds": here["serial_seconds"],
        "tasks_2": len(tasks), "tasks_1": len(one["tasks"]), "tasks_profile": len(profile["tasks"]),
        "maps": len(two["maps"]),
        "item_bytes_per_task": statistics.mean(two["item_bytes"]),
        "static_bytes_per_task": statistics.mean(two["static_bytes"]),
        "argument_bytes_per_task": statistics.mean(two["argument_bytes"]),
        "result_bytes_per_task": two["stats"]["result_bytes"] / max(1, len(tasks)),
        "result_nbytes_per_task_dask": statistics.mean(t["result_nbytes"] for t in tasks),
        "setting_scatters": two["setting_scatters"], "setting_scatter_bytes": two["setting_scatter_bytes"],
        "scene_bytes": two["scene_bytes"], "scene_pickled_bytes": two["scene_pickled_bytes"],
        "scatter_seconds_2": two["scatter_seconds"], "scatter_seconds_1": one["scatter_seconds"],
        "scatter_bytes_per_s": bandwidth, "client_bvh_seconds_2": two["client_bvh_seconds"],
        "worker_setup_seconds": setup,
        "task_seconds_2": _spread([t["seconds"] for t in tasks]),
        "task_transfer_seconds_2": sum(t["transfer_seconds"] for t in tasks),
        "task_seconds_profile": _spread([t["seconds"] for t in profile["tasks"]]),
        "compute_seconds_profile": sum(t["seconds"] for t in profile["tasks"]) - setup,
        "covered_seconds_2": two["covered_seconds"], "outside_tasks_seconds_2": two["outside_tasks_seconds"],
        "outside_tasks_seconds_1": one["outside_tasks_seconds"],
        "serial_seconds_total": serial_all, "serial_fraction_1_worker": serial_all / one["wall"],
        "per_task_compute_seconds": fixed, "model_constants": constants[2],
        "model_check": model_check, "predictions": predictions,
        "predictions_scheduler_1ms": predictions_documented, "stats": here["stats"],
    }


def _spread(values: list[float]) -> dict:
    values = sorted(values)
    return {"count": len(values), "min": values[0], "median": statistics.median(values), "max": values[-1],
            "sum": sum(values)}
