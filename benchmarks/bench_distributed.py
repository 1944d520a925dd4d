"""Bakes on a Dask cluster (usdbake.farm): what distribution costs at equal cores, what a task moves,
and a model of scaling to 16 and 64 workers built from measured task times and transfer sizes.

Three parts:

1. A batch of the six samples, one stage per task: in this process one after the other (``bake_file``,
   2 ray threads), ``bake_many(workers=2)`` (spawned pool, 1 thread each) and ``bake_many`` on a
   LocalCluster of 2 workers x 1 thread. Overhead = distributed / in-process - 1; bytes of a task's
   arguments and of its StageOutcome (pickled); the three bakes' layers compared value by value.
2. One large scene (the atrium sample referenced 4 times side by side, ~205k triangles):
   ambient_occlusion and sky_visibility in process (2 threads), with ``DaskChunks`` on 2 workers x 1
   thread and on 1 worker x 1 thread, and a profile run (1 worker, fine chunks) for the model. Outputs
   compared with ``np.array_equal``; tasks, bytes per task, scene bytes scattered, per-task compute
   times from Dask's task stream; time outside tasks (Amdahl's serial part).
3. The scaling model (``predict``): scene broadcast (tree copy) + one BVH per worker + per map of
   chunks: a round trip + longest-processing-time list scheduling of the chunks' measured compute
   (plus per-task overhead) over W workers, floored by the scheduler's task rate + items and results
   at the measured bandwidth + the serial part measured in process. Checked against the measured
   1- and 2-worker runs, then evaluated for 4, 16 and 64 workers with the default chunking.

The parts live beside this module: ``distributed_batch`` (1), ``distributed_large`` (2 and 3),
``distributed_runs`` (a timed run in process or on Dask), ``distributed_model`` (the model) and
``distributed_cluster`` (clusters and their fixed costs); this module runs them and reports.
"""

from __future__ import annotations

import os

import numpy as np

from . import harness
from .distributed_batch import BATCH_PARAMS, BATCH_PROCESSORS, QUICK_BATCH_PARAMS, QUICK_SAMPLES, SAMPLES, batch
from .distributed_cluster import GATHER_BYTES, MMAP_THRESHOLD, NOOP_TASKS
from .distributed_large import MODEL_WORKERS, PROFILE_CHUNK, large
from .distributed_runs import THREADS

NAME = "distributed"
DESCRIPTION = (
    "usdbake.farm on one machine, as a stand-in for a cluster: wall time of the same work in process and "
    "on Dask (LocalCluster, worker processes of 1 thread each, so the cores are equal: 2 workers x 1 thread "
    "against 2 ray threads in process), with every stage computed (force, no cache) and everything warm "
    "(Warp kernel cache; Dask workers started and given one warm-up bake before timing, their start-up "
    "timed alone; the spawned pool of `bake_many(workers=2)` cannot be warmed, so its start-up is inside "
    "its time and also measured alone). Batch: the six samples with ambient_occlusion (samples 64) and "
    "sky_visibility (defaults), one task per stage; bytes per task are the pickled arguments "
    "(paths + options) and the pickled StageOutcome. Large scene: atrium.usda referenced 4 times side by "
    "side (flattened, ~205k triangles), ambient_occlusion (samples 64) and sky_visibility (patch_count 64, "
    "max_level 1, to keep the run short), each on a fresh copy of the scene (its own BVH and scatter), "
    "median of 3 runs per configuration; outputs of every run must be bit-identical. Per-task compute and "
    "transfer times come from Dask's task stream; the time outside tasks is the run's wall time minus the "
    "union of its tasks' compute intervals. The BVH build (1 thread) is also timed here, inside a Dask "
    "worker, and in fresh interpreters with and without the environment Dask's nanny gives its workers. "
    "Scaling model (see `predict`): T(W) = in-process serial part + client-side BVH + scene broadcast "
    "(Dask's tree copy, branching 2) + one BVH per worker + sum over maps of (round trip + LPT schedule of "
    "the chunks' compute + per-task overhead over W workers, at least tasks x the scheduler's per-task "
    "time) + items and results at the measured bandwidth; chunk times for W workers are re-cut from a "
    "profile run with fine chunks. Everything runs on one 2-core machine: the scheduler, the client and "
    "the workers share the cores and transfers are memory copies, so the overheads are pessimistic for "
    "compute and optimistic for bandwidth (see docs/distributed.md). Ratios come from one run.")


def run(quick: bool = False) -> dict:
    """The benchmark; the process environment is put back afterwards (a LocalCluster's nannies write
    Dask's worker settings into it, which would reach the subprocesses of later benchmarks)."""
    clean_environ = dict(os.environ)
    try:
        return _run(quick, clean_environ)
    finally:
        os.environ.clear()
        os.environ.update(clean_environ)


def _run(quick: bool, clean_environ: dict) -> dict:
    import warp as wp

    from usdbake import init_warp

    if hasattr(wp, "LOG_WARNING"):
        wp.config.log_level = wp.LOG_WARNING
    init_warp("cpu")
    load_before = os.getloadavg()
    names = QUICK_SAMPLES if quick else SAMPLES
    batch_params = QUICK_BATCH_PARAMS if quick else BATCH_PARAMS
    b = batch(names, batch_params)
    print_batch(b, names)
    big = large(quick, clean_environ)
    print_large(big, quick)
    figures = {**batch_figures(b, names), **large_figures(big, quick)}
    rows = {"large": [], "bytes": [], "check": [], "model": []}
    points = []
    for name, p in big["processors"].items():
        short = "ao" if name == "ambient_occlusion" else "sky"
        figures.update(processor_figures(short, p))
        add_processor_rows(rows, name, p)
        points += [{"label": f"{short} in process", "seconds": p["in_process_seconds"], "error": 0.0, "default": True},
                   {"label": f"{short} Dask 2x1", "seconds": p["dask_2_seconds"], "error": 0.0},
                   {"label": f"{short} Dask 1x1", "seconds": p["dask_1_seconds"], "error": 0.0}]
        print_processor(name, p, big)
    points += [{"label": "batch in process", "seconds": b["in_process_seconds"], "error": 0.0},
               {"label": "batch pool 2", "seconds": b["pool_seconds"], "error": 0.0},
               {"label": "batch Dask 2x1", "seconds": b["dask_seconds"], "error": 0.0}]
    result = harness.result(NAME, description=DESCRIPTION,
                            settings={"threads_in_process": THREADS, "worker_threads": 1, "samples": list(names),
                                      "batch_processors": list(BATCH_PROCESSORS), "batch_params": batch_params,
                                      "large_copies": big["copies"], "large_params": big["params"],
                                      "profile_chunk": PROFILE_CHUNK, "model_workers": list(MODEL_WORKERS),
                                      "noop_tasks": NOOP_TASKS, "gather_bytes": GATHER_BYTES,
                                      "load_average_before": list(load_before),
                                      "load_average_after": list(os.getloadavg())},
                            points=points, figures=figures, table=report_table(b, big, names, rows),
                            knob="where the work runs", error_label="(none: timing only)")
    return result | {"batch": b, "large": _plain(big)}


def print_batch(b: dict, names) -> None:
    """One line on the batch: wall times, overheads, bytes per task, layers compared."""
    print(f"  batch of {len(names)}: in process {b['in_process_seconds']:.2f} s, pool of 2 {b['pool_seconds']:.2f} s "
          f"({b['pool_overhead']:+.1%}; pool start-up {b['pool_startup_seconds']:.2f} s), Dask 2 x 1 "
          f"{b['dask_seconds']:.2f} s ({b['dask_overhead']:+.1%}; its stage times scheduled in input order "
          f"{b['dask_in_order_seconds']:.2f} s, longest first {b['dask_lpt_seconds']:.2f} s; cluster start-up "
          f"{b['dask_startup_seconds']:.2f} s + warm-up {b['dask_warmup_seconds']:.2f} s, not timed); "
          f"a task sends {b['task_argument_bytes_mean']:.0f} B, "
          f"returns {b['task_result_bytes_mean']:.0f} B; layers identical: pool {b['pool_layers_identical']}, "
          f"Dask {b['dask_layers_identical']} ({b['attributes_compared']} attributes)")


def print_large(big: dict, quick: bool) -> None:
    """The large scene's BVH builds: here, in a worker, and (unless quick) in fresh processes."""
    print(f"  BVH of the large scene, 1 thread: here {big['bvh_1_thread_seconds']:.2f} s, in a Dask worker "
          f"{big['bvh_worker_seconds']:.2f} s")
    if not quick:
        print(f"  BVH of the large scene in a fresh process, 1 thread: {big['bvh_fresh_process_seconds']:.2f} s; with "
              f"the nanny's environment {big['nanny_environ']} {big['bvh_fresh_process_nanny_environ_seconds']:.2f} "
              f"s; and MALLOC_MMAP_THRESHOLD_={MMAP_THRESHOLD} "
              f"{big['bvh_fresh_process_nanny_environ_mmap_seconds']:.2f} s")


def batch_figures(b: dict, names) -> dict:
    """The batch's figures (part 1)."""
    return {
        "batch_stages": len(names),
        "batch_in_process_seconds": round(b["in_process_seconds"], 3),
        "batch_pool_seconds": round(b["pool_seconds"], 3),
        "batch_dask_seconds": round(b["dask_seconds"], 3),
        "batch_pool_overhead": round(b["pool_overhead"], 4),
        "batch_dask_overhead": round(b["dask_overhead"], 4),
        "batch_pool_startup_seconds": round(b["pool_startup_seconds"], 3),
        "batch_dask_startup_seconds": round(b["dask_startup_seconds"], 3),
        "batch_dask_lpt_bound_seconds": round(b["dask_lpt_seconds"], 3),
        "batch_dask_in_order_bound_seconds": round(b["dask_in_order_seconds"], 3),
        "batch_task_argument_bytes": round(b["task_argument_bytes_mean"]),
        "batch_task_result_bytes": round(b["task_result_bytes_mean"]),
        "batch_layers_identical": int(b["pool_layers_identical"] and b["dask_layers_identical"]),
    }


def large_figures(big: dict, quick: bool) -> dict:
    """The large scene's figures common to its processors (BVH builds; in fresh processes unless quick)."""
    figures = {
        "large_triangles": big["triangles"],
        "large_bvh_1_thread_seconds": round(big["bvh_1_thread_seconds"], 3),
        "large_bvh_worker_seconds": round(big["bvh_worker_seconds"], 3),
    }
    if not quick:
        figures.update({
            "large_bvh_fresh_process_seconds": round(big["bvh_fresh_process_seconds"], 3),
            "large_bvh_fresh_process_nanny_environ_seconds": round(big["bvh_fresh_process_nanny_environ_seconds"], 3),
            "large_bvh_fresh_process_nanny_environ_mmap_seconds":
                round(big["bvh_fresh_process_nanny_environ_mmap_seconds"], 3)})
    return figures


def processor_figures(short: str, p: dict) -> dict:
    """One processor's figures on the large scene, named ``large_<short>_...``."""
    figures = {
        f"large_{short}_in_process_seconds": round(p["in_process_seconds"], 3),
        f"large_{short}_dask_2_seconds": round(p["dask_2_seconds"], 3),
        f"large_{short}_dask_1_seconds": round(p["dask_1_seconds"], 3),
        f"large_{short}_overhead_equal_cores": round(p["overhead_equal_cores"], 4),
        f"large_{short}_bit_identical": int(p["bit_identical"]),
        f"large_{short}_tasks": p["tasks_2"],
        f"large_{short}_item_bytes_per_task": round(p["item_bytes_per_task"]),
        f"large_{short}_result_bytes_per_task": round(p["result_bytes_per_task"]),
        f"large_{short}_scene_bytes": p["scene_bytes"],
        f"large_{short}_outside_tasks_seconds_2": round(p["outside_tasks_seconds_2"], 3),
        f"large_{short}_worker_setup_seconds": round(p["worker_setup_seconds"], 3),
        f"large_{short}_per_task_compute_ms": round(1e3 * p["per_task_compute_seconds"], 3),
        f"large_{short}_serial_fraction_1_worker": round(p["serial_fraction_1_worker"], 4),
        f"large_{short}_model_error_1": round(p["model_check"][1]["error"], 4),
        f"large_{short}_model_error_2": round(p["model_check"][2]["error"], 4),
    }
    for pred in p["predictions"]:
        if pred["workers"] in (16, 64):
            figures[f"large_{short}_predicted_{pred['workers']}_seconds"] = round(pred["seconds"], 3)
            figures[f"large_{short}_predicted_{pred['workers']}_speedup"] = round(pred["speedup"], 2)
    for pred in p["predictions_scheduler_1ms"]:
        if pred["workers"] in (16, 64):
            figures[f"large_{short}_predicted_{pred['workers']}_seconds_scheduler_1ms"] = round(pred["seconds"], 3)
    figures[f"large_{short}_stops_scaling_workers"] = _stop_scaling(p["predictions"])
    return figures


def add_processor_rows(rows: dict, name: str, p: dict) -> None:
    """Append one processor's rows to the report's tables (``rows``: large, bytes, check, model)."""
    rows["large"].append({"processor": name, "in process, 2 threads (s)": p["in_process_seconds"],
                          "Dask 2 x 1 (s)": p["dask_2_seconds"], "Dask 1 x 1 (s)": p["dask_1_seconds"],
                          "overhead at equal cores": f"{p['overhead_equal_cores']:+.1%}",
                          "outside tasks, 2 workers (s)": p["outside_tasks_seconds_2"],
                          "bit-identical": "yes" if p["bit_identical"] else "**no**"})
    rows["bytes"].append({"processor": name, "maps": p["maps"], "tasks (2 workers)": p["tasks_2"],
                          "items / task (B)": round(p["item_bytes_per_task"]),
                          "settings / task (B)": round(p["static_bytes_per_task"]),
                          "pickled arguments / task (B)": round(p["argument_bytes_per_task"]),
                          "results / task (B)": round(p["result_bytes_per_task"]),
                          "scene arrays (B)": p["scene_bytes"], "scene pickled (B)": p["scene_pickled_bytes"],
                          "task compute median (s)": p["task_seconds_2"]["median"]})
    for workers, check in p["model_check"].items():
        rows["check"].append({"processor": name, "workers": workers, "predicted (s)": check["predicted"],
                              "measured (s)": check["measured"], "error": f"{check['error']:+.1%}",
                              "scatter predicted / measured (s)":
                                  f"{check['scatter_predicted']:.3f} / {check['scatter_measured']:.3f}"})
    for pred, alt in zip(p["predictions"], p["predictions_scheduler_1ms"]):
        rows["model"].append({"processor": name, "workers": pred["workers"], "tasks": pred["tasks"],
                              "T (s)": pred["seconds"], "T at 1 ms/task (s)": alt["seconds"],
                              "speed-up vs 1": pred["speedup"],
                              "efficiency": f"{pred['efficiency']:.0%}", "serial": pred["serial"],
                              "scatter": pred["scatter"], "BVH": pred["bvh"], "maps": pred["compute"],
                              "transfer": pred["transfer"]})


def print_processor(name: str, p: dict, big: dict) -> None:
    """One processor on the large scene: its runs, what a task moves, the model checked, its predictions."""
    print(f"  {name} on {big['triangles']} triangles: in process {p['in_process_seconds']:.2f} s, Dask 2 x 1 "
          f"{p['dask_2_seconds']:.2f} s ({p['overhead_equal_cores']:+.1%}), 1 x 1 {p['dask_1_seconds']:.2f} s; "
          f"bit-identical {p['bit_identical']}; {p['tasks_2']} tasks in {p['maps']} maps, "
          f"{p['item_bytes_per_task']:.0f} B items + {p['static_bytes_per_task']:.0f} B settings out, "
          f"{p['result_bytes_per_task']:.0f} B back per task; scene {p['scene_pickled_bytes'] / 1e6:.1f} MB "
          f"scattered in {p['scatter_seconds_2']:.3f} s; outside tasks {p['outside_tasks_seconds_2']:.2f} s "
          f"(in-process serial part {p['in_process_serial_seconds']:.2f} s)")
    for workers, check in p["model_check"].items():
        print(f"    model {workers} worker(s): predicted {check['predicted']:.2f} s, measured "
              f"{check['measured']:.2f} s ({check['error']:+.1%})")
    print("    predicted: " + ", ".join(f"{q['workers']}w {q['seconds']:.2f} s ({q['efficiency']:.0%})"
                                        for q in p["predictions"]))
    print("    at 1 ms a task: " + ", ".join(f"{q['workers']}w {q['seconds']:.2f} s ({q['efficiency']:.0%})"
                                           for q in p["predictions_scheduler_1ms"]))
    q = p["predictions"][-1]
    print(f"    {q['workers']} workers by parts: serial {q['serial']:.2f}, scatter {q['scatter']:.3f}, "
          f"worker set-up {q['bvh']:.2f}, maps {q['compute']:.2f}, transfer {q['transfer']:.3f} s; worker "
          f"set-up measured {p['worker_setup_seconds']:.2f} s (BVH here {big['bvh_1_thread_seconds']:.2f} s), "
          f"fixed compute per task {1e3 * p['per_task_compute_seconds']:.2f} ms")


def report_table(b: dict, big: dict, names, rows: dict) -> str:
    """The report's tables: the batch, the large scene's runs and bytes, the clusters' fixed costs, the
    model against measurement and its predictions."""
    clusters = big["clusters"]
    costs = harness.markdown_table([{"workers": w, "cluster start-up (s)": c["startup_seconds"],
                                     "warm-up bake (s)": c["warmup_seconds"], "no-op round trip (ms)":
                                     1e3 * c["round_trip_s"], "scheduler time / task (ms)":
                                     1e3 * c["scheduler_per_task_s"], "overhead / task / worker (ms)":
                                     1e3 * c["overhead_per_task_s"], "gather (GB/s)": c["gather_bytes_per_s"] / 1e9}
                                    for w, c in clusters.items()],
                                   ["workers", "cluster start-up (s)", "warm-up bake (s)", "no-op round trip (ms)",
                                    "scheduler time / task (ms)", "overhead / task / worker (ms)", "gather (GB/s)"])
    return "\n\n".join([
        f"Batch of {len(names)} stages ({', '.join(BATCH_PROCESSORS)}), wall seconds:\n\n" + harness.markdown_table(
            [{"mode": "in process, one by one, 2 threads", "seconds": b["in_process_seconds"], "overhead": ""},
             {"mode": "bake_many(workers=2), spawned pool", "seconds": b["pool_seconds"],
              "overhead": f"{b['pool_overhead']:+.1%}"},
             {"mode": "bake_many on Dask, 2 workers x 1 thread", "seconds": b["dask_seconds"],
              "overhead": f"{b['dask_overhead']:+.1%}"}], ["mode", "seconds", "overhead"]),
        harness.markdown_table(b["per_stage"], ["stage", "in process (s)", "Dask task, bake only (s)"]),
        f"Large scene ({big['triangles']:,} triangles):\n\n" + harness.markdown_table(
            rows["large"], ["processor", "in process, 2 threads (s)", "Dask 2 x 1 (s)", "Dask 1 x 1 (s)",
                            "overhead at equal cores", "outside tasks, 2 workers (s)", "bit-identical"]),
        harness.markdown_table(rows["bytes"], ["processor", "maps", "tasks (2 workers)", "items / task (B)",
                                               "settings / task (B)", "pickled arguments / task (B)",
                                               "results / task (B)", "scene arrays (B)", "scene pickled (B)",
                                               "task compute median (s)"]),
        costs,
        "Model against measurement:\n\n" + harness.markdown_table(
            rows["check"], ["processor", "workers", "predicted (s)", "measured (s)", "error",
                            "scatter predicted / measured (s)"]),
        "Model, default chunking (parts in seconds):\n\n" + harness.markdown_table(
            rows["model"], ["processor", "workers", "tasks", "T (s)", "T at 1 ms/task (s)", "speed-up vs 1",
                            "efficiency", "serial", "scatter", "BVH", "maps", "transfer"]),
    ])


def _stop_scaling(predictions: list[dict]) -> int:
    """The most workers whose predicted parallel efficiency is still >= 50%."""
    good = [p["workers"] for p in predictions if p["efficiency"] >= 0.5]
    return max(good) if good else 1


def _plain(value):
    """``value`` without numpy scalars and with int keys as strings (for the JSON file)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value
