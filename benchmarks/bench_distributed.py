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
"""

from __future__ import annotations

import dataclasses
import gc
import heapq
import logging
import math
import os
import pickle
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from . import harness

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

SAMPLES = ("atrium", "building", "city_block", "cornell_box", "instanced_props", "window_room")
QUICK_SAMPLES = ("cornell_box", "window_room")
BATCH_PROCESSORS = ("ambient_occlusion", "sky_visibility")
BATCH_PARAMS = {"ambient_occlusion": {"samples": 64}}
QUICK_BATCH_PARAMS = {"ambient_occlusion": {"samples": 16}, "sky_visibility": {"patch_count": 16, "max_level": 1}}
LARGE_COPIES = 4
"""atrium.usda (51,216 triangles) referenced this many times: 204,864 triangles."""
QUICK_LARGE_COPIES = 1
LARGE_PARAMS = {"ambient_occlusion": {"samples": 64}, "sky_visibility": {"patch_count": 64, "max_level": 1}}
QUICK_LARGE_PARAMS = {"ambient_occlusion": {"samples": 4}, "sky_visibility": {"patch_count": 16, "max_level": 0}}
THREADS = 2
"""Cores of the in-process bakes: equal to 2 workers x 1 thread."""
REPEATS = 3
"""Runs of each large-scene configuration; the median is reported (the machine is shared)."""
PROFILE_CHUNK = 256
"""Items per task of the profile run: about the chunks 64 workers get by default (4 per worker) on this
scene's sky-visibility maps (62,500 faces each), fine enough to re-cut into any coarser chunking."""
MODEL_WORKERS = (1, 2, 4, 8, 16, 32, 64)
DOCUMENTED_TASK_OVERHEAD = 1e-3
"""Dask's own figure, "each task suffers about 1ms of overhead" (distributed.dask.org): the scheduler's
per-task time of a second set of predictions, beside the bound measured here (2 cores shared)."""
NOOP_TASKS = 400
GATHER_BYTES = 64 * 2 ** 20


# ---------------------------------------------------------------------------
# Dask: clusters, fixed costs


def start_cluster(workers: int, warm_stage: Path, warm_options) -> tuple[object, object, dict]:
    """A LocalCluster of ``workers`` processes x 1 thread and a client; each worker has baked
    ``warm_stage`` once (imports, Warp modules). Returns cluster, client and the start-up seconds."""
    from distributed import Client, LocalCluster

    from usdbake.farm.batch import bake_stage

    started = time.perf_counter()
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                           silence_logs=logging.CRITICAL)
    client = Client(cluster, set_as_default=False)
    client.wait_for_workers(workers)
    startup = time.perf_counter() - started
    started = time.perf_counter()
    folder = tempfile.mkdtemp(prefix="usdbake-bench-warm-")
    futures = [client.submit(bake_stage, str(warm_stage), f"{folder}/warm{k}.baked.usdc", warm_options, pure=False,
                             workers=[address], allow_other_workers=False)
               for k, address in enumerate(client.scheduler_info(n_workers=-1)["workers"])]
    failed = [outcome.error for outcome in client.gather(futures) if outcome.error]
    shutil.rmtree(folder, ignore_errors=True)
    if failed:
        raise RuntimeError(f"warm-up bake failed on a worker: {failed[0]}")
    return cluster, client, {"startup_seconds": startup, "warmup_seconds": time.perf_counter() - started}


def worker_bvh_seconds(client, scene, repeats: int) -> float:
    """Median compute time Dask books for ``Tracer.from_scene`` (1 thread) of ``scene`` on a worker."""
    from distributed import get_task_stream

    from usdbake.kernels.tracer import Tracer

    future = client.scatter(scene, broadcast=True, hash=False)
    seconds = []
    for _ in range(repeats):
        with get_task_stream(client) as stream:
            tracer = client.submit(Tracer.from_scene, future, threads=1, pure=False)
            client.gather(client.submit(id, tracer, pure=False))  # wait without fetching the tracer
            del tracer
        seconds += [s["stop"] - s["start"] for record in stream.data if "from_scene" in str(record["key"])
                    for s in record["startstops"] if s["action"] == "compute"]
    return statistics.median(seconds)


BVH_SCRIPT = """
import statistics, sys, time
from usdbake import init_warp
init_warp("cpu")
from usdbake.benchmarks.bench_distributed import large_scene
from usdbake.kernels.tracer import Tracer
scene = large_scene(int(sys.argv[1]))
seconds = []
for _ in range(3):
    started = time.perf_counter()
    Tracer.from_scene(scene, threads=1)
    seconds.append(time.perf_counter() - started)
print(statistics.median(seconds))
"""


MMAP_THRESHOLD = 32 * 2 ** 20
"""MALLOC_MMAP_THRESHOLD_ of the what-if: glibc's own ceiling for its dynamic threshold (32 MiB on 64-bit)."""


def bvh_in_fresh_process(copies: int, environ: dict) -> float:
    """Median BVH build (1 thread) of large_scene(copies) in a new interpreter whose environment is
    ``environ`` (this one as it was before any cluster started: see ``run``)."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", BVH_SCRIPT, str(copies)], check=True, capture_output=True,
                          text=True, env={k: str(v) for k, v in environ.items()})
    return float(done.stdout.strip().splitlines()[-1])


def nanny_environ() -> dict:
    """What Dask's nanny adds to each worker process's environment (distributed.nanny.pre-spawn-environ;
    MALLOC_TRIM_THRESHOLD_ among them: glibc then stops adapting its mmap threshold, and every large
    numpy temporary is a fresh mmap). A nanny sets these in its own process's os.environ, so after a
    LocalCluster starts they are in this process's environment too (``run`` puts it back)."""
    import dask
    import distributed  # noqa: F401  (loads distributed's config defaults)

    return dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))


def stop_cluster(cluster, client) -> None:
    client.close()
    cluster.close()


def fixed_costs(client, workers: int) -> dict:
    """Per-task costs of the cluster, with no-op tasks (``abs`` of an int): one round trip at a time
    (submit, run, result: the latency a map's barrier pays), and ``NOOP_TASKS`` in flight at once
    (elapsed / tasks: at most the scheduler's time per task, the ceiling on its task rate; times the
    workers: each task's share of a worker's time; and the median time Dask books as a no-op's
    compute, the part of that share a real task's compute time already holds). And the client's
    gather bandwidth (an array made on a worker, fetched once to warm, then timed)."""
    for k in range(20):  # warm the comms
        client.submit(abs, -k, pure=False).result()
    trips = []
    for k in range(50):
        started = time.perf_counter()
        client.submit(abs, -k, pure=False).result()
        trips.append(time.perf_counter() - started)
    from distributed import get_task_stream

    with get_task_stream(client) as stream:
        started = time.perf_counter()
        client.gather([client.submit(abs, -k, pure=False) for k in range(NOOP_TASKS)])
        burst = time.perf_counter() - started
    noop_compute = [s["stop"] - s["start"] for record in stream.data for s in record["startstops"]
                    if s["action"] == "compute"]
    block = client.submit(np.ones, GATHER_BYTES, dtype=np.uint8, pure=False)
    client.gather(block)
    gathers = []
    for _ in range(3):
        started = time.perf_counter()
        client.gather(block)
        gathers.append(time.perf_counter() - started)
    del block
    return {"round_trip_s": statistics.median(trips), "scheduler_per_task_s": burst / NOOP_TASKS,
            "overhead_per_task_s": burst * workers / NOOP_TASKS,
            "noop_compute_s": statistics.median(noop_compute) if noop_compute else 0.0,
            "gather_bytes_per_s": GATHER_BYTES / statistics.median(gathers)}


# ---------------------------------------------------------------------------
# Part 1: a batch of stages


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
    from usdbake.farm.batch import BatchOptions, StageOutcome, bake_many, bake_stage
    from usdbake.stages.bake_file import bake_file

    paths = [str(harness.SAMPLES / f"{name}.usda") for name in names]
    root = Path(tempfile.mkdtemp(prefix="usdbake-bench-batch-"))
    folders = {mode: root / mode for mode in ("in_process", "pool", "dask", "pool_startup")}
    for folder in folders.values():
        folder.mkdir()
    options = BatchOptions(BATCH_PROCESSORS, params, "cpu", None, True)
    warm_stage = harness.SAMPLES / "cornell_box.usda"
    tiny = BatchOptions(("ambient_occlusion",), {"ambient_occlusion": {"samples": 4}}, "cpu", None, True)
    bake_stage(str(warm_stage), str(root / "warm.baked.usdc"), BatchOptions(BATCH_PROCESSORS, params, "cpu",
                                                                             None, True, THREADS))

    in_process = {}
    started = time.perf_counter()
    for name, path in zip(names, paths):
        t0 = time.perf_counter()
        bake_file(path, str(folders["in_process"] / f"{name}.baked.usdc"),
                  Pipeline.build(list(BATCH_PROCESSORS), params, cache_dir=None, force=True, threads=THREADS))
        in_process[name] = time.perf_counter() - t0
    in_process_seconds = time.perf_counter() - started

    # the pool's fixed cost: a one-stage, one-worker pool on a tiny bake, less the same bake here
    started = time.perf_counter()
    bake_file(str(harness.SAMPLES / "window_room.usda"), str(folders["pool_startup"] / "here.baked.usdc"),
              tiny.pipeline(THREADS))
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


# ---------------------------------------------------------------------------
# Part 2: one large scene


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


class TimedSceneChunks:
    """core.chunks.SceneChunks that times its maps, the BVH build kept apart (the in-process run)."""

    def __init__(self, inner, clock: dict):
        self.inner, self.clock = inner, clock

    def map(self, fn, items, *, progress=None, **static):
        started = time.perf_counter()
        self.inner.tracer  # built here on the first map when nothing built it before (timed by tracer_for)
        self.clock["bvh_in_map"] += time.perf_counter() - started
        started = time.perf_counter()
        result = self.inner.map(fn, items, progress=progress, **static)
        self.clock["maps"] += time.perf_counter() - started
        self.clock["map_calls"] += 1
        return result


class TimedInProcess:
    """The default runner (core.chunks.InProcess) with its maps timed."""

    def __init__(self):
        self.clock = {"maps": 0.0, "map_calls": 0, "bvh_in_map": 0.0}

    def for_scene(self, scene, tracer, *, device: str = "cpu", threads: int | None = None):
        from usdbake.core.chunks import InProcess

        return TimedSceneChunks(InProcess().for_scene(scene, tracer, device=device, threads=threads), self.clock)


class MeteredClient:
    """A distributed.Client as DaskChunks uses it, recording each scatter (seconds, what, bytes) and each
    task's arguments (their pickled sizes are measured after the run, outside the timing)."""

    def __init__(self, client):
        self._client = client
        self.scatters: list[dict] = []
        self.submitted: list[dict] = []

    def __getattr__(self, name):
        return getattr(self._client, name)

    def scatter(self, data, **kwargs):
        from usdbake.farm.chunks import array_nbytes

        started = time.perf_counter()
        future = self._client.scatter(data, **kwargs)
        self.scatters.append({"seconds": time.perf_counter() - started, "type": type(data).__name__,
                              "array_bytes": array_nbytes(data), "data": data})
        return future

    def submit(self, function, *args, key=None, **kwargs):
        fn, _scene, device, first, items, static = args
        self.submitted.append({"key": key, "first": int(first), "items": len(items[0]),
                               "arguments": (fn, device, first, items, static)})
        return self._client.submit(function, *args, key=key, **kwargs)


def pickled_bytes(value) -> int:
    """Pickled size of a task argument; a Dask future (a setting scattered once per map) counts as its key."""
    from distributed import Future

    if isinstance(value, dict):
        value = {k: (str(v.key) if isinstance(v, Future) else v) for k, v in value.items()}
    return len(pickle.dumps(value, protocol=5))


def timed_tracer_for(pipeline) -> dict:
    """Wrap ``pipeline.tracer_for`` so the BVH build it triggers (first use, in applies() or a map) is
    timed: returns the dict that receives the seconds."""
    bvh = {"seconds": 0.0, "builds": 0}
    make = pipeline.tracer_for

    def tracer_for(scene):
        build = make(scene)

        def timed():
            from usdbake.kernels import tracer as tracer_module

            fresh = (id(scene), "cpu") not in tracer_module._SHARED
            started = time.perf_counter()
            tracer = build()
            if fresh:
                bvh["seconds"] += time.perf_counter() - started
                bvh["builds"] += 1
            return tracer
        return timed

    pipeline.tracer_for = tracer_for
    return bvh


def output_arrays(pipeline) -> list:
    """Every output record's fields, in order: what two bakes must agree on bit for bit."""
    return [(type(record).__name__, [getattr(record, f.name) for f in dataclasses.fields(record)])
            for record in pipeline.outputs()]


def identical(a: list, b: list) -> bool:
    if len(a) != len(b):
        return False
    for (kind_a, fields_a), (kind_b, fields_b) in zip(a, b):
        if kind_a != kind_b or len(fields_a) != len(fields_b):
            return False
        for x, y in zip(fields_a, fields_b):
            if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
                if not (isinstance(x, np.ndarray) and isinstance(y, np.ndarray) and x.dtype == y.dtype
                        and np.array_equal(x, y)):
                    return False
            elif x != y:
                return False
    return True


def run_in_process(scene, processor: str, params: dict) -> dict:
    """One processor on a fresh copy of ``scene`` here, 2 threads: wall time, time inside maps, BVH."""
    from usdbake.core.pipeline import Pipeline

    scene = dataclasses.replace(scene)  # a new object: its own BVH (shared_tracer keys by the object)
    runner = TimedInProcess()
    pipeline = Pipeline.build([processor], params, cache_dir=None, force=True, threads=THREADS, chunks=runner)
    bvh = timed_tracer_for(pipeline)
    started = time.perf_counter()
    pipeline.run(scene)
    wall = time.perf_counter() - started
    maps = runner.clock["maps"]
    return {"wall": wall, "maps_seconds": maps, "map_calls": runner.clock["map_calls"], "bvh_seconds": bvh["seconds"],
            "serial_seconds": max(0.0, wall - maps - bvh["seconds"]), "outputs": output_arrays(pipeline),
            "stats": dict(pipeline.steps[-1].result.stats)}


def union_seconds(intervals: list[tuple[float, float]]) -> float:
    """Length of the union of [start, stop) intervals."""
    total, end = 0.0, -math.inf
    for start, stop in sorted(intervals):
        if stop > end:
            total += stop - max(start, end)
            end = stop
    return total


def run_on_dask(scene, processor: str, params: dict, client, chunk_size: int | None = None) -> dict:
    """One processor on a fresh copy of ``scene`` with DaskChunks: wall time, the task stream's compute
    and transfer times per task, what was sent, time outside tasks."""
    from distributed import get_task_stream

    from usdbake.core.pipeline import Pipeline
    from usdbake.farm.chunks import DaskChunks, array_nbytes

    scene = dataclasses.replace(scene)
    metered = MeteredClient(client)
    chunks = DaskChunks(metered, chunk_size=chunk_size)
    pipeline = Pipeline.build([processor], params, cache_dir=None, force=True, threads=THREADS, chunks=chunks)
    bvh = timed_tracer_for(pipeline)
    with get_task_stream(client) as stream:
        started, wall_clock = time.perf_counter(), time.time()
        pipeline.run(scene)
        wall = time.perf_counter() - started
        finished = time.time()
    by_key = {record["key"]: record for record in stream.data if str(record["key"]).startswith("usdbake-")}
    tasks = []
    for sent in metered.submitted:
        record = by_key[sent["key"]]
        compute = [s for s in record["startstops"] if s["action"] == "compute"][0]
        transfer = sum(s["stop"] - s["start"] for s in record["startstops"] if s["action"] == "transfer")
        token = sent["key"].rsplit("-", 2)[-2]
        tasks.append({"map": token, "first": sent["first"], "items": sent["items"], "worker": record["worker"],
                      "start": compute["start"], "stop": compute["stop"], "seconds": compute["stop"] - compute["start"],
                      "transfer_seconds": transfer, "result_nbytes": int(record.get("nbytes", 0) or 0)})
    covered = union_seconds([(t["start"], t["stop"]) for t in tasks])
    argument_bytes = [pickled_bytes(sent["arguments"][:4]) + pickled_bytes(sent["arguments"][4])
                      for sent in metered.submitted]
    item_bytes = [sum(a.nbytes for a in sent["arguments"][3]) for sent in metered.submitted]
    static_bytes = [pickled_bytes(sent["arguments"][4]) for sent in metered.submitted]
    scene_scatters = [s for s in metered.scatters if s["type"] == "Scene"]
    setting_scatters = [s for s in metered.scatters if s["type"] != "Scene"]
    maps = list(dict.fromkeys(t["map"] for t in tasks))
    return {
        "wall": wall, "run_start": wall_clock, "run_stop": finished, "tasks": tasks, "maps": maps,
        "covered_seconds": covered, "outside_tasks_seconds": max(0.0, wall - covered),
        "scatter_seconds": sum(s["seconds"] for s in scene_scatters), "scatters": len(scene_scatters),
        "setting_scatter_seconds": sum(s["seconds"] for s in setting_scatters),
        "setting_scatter_bytes": sum(len(pickle.dumps(s["data"], protocol=5)) for s in setting_scatters),
        "setting_scatters": len(setting_scatters),
        "scene_bytes": array_nbytes(scene), "scene_pickled_bytes": len(pickle.dumps(scene, protocol=5)),
        "stats": dict(chunks.stats), "client_bvh_seconds": bvh["seconds"],
        "argument_bytes": argument_bytes, "item_bytes": item_bytes, "static_bytes": static_bytes,
        "outputs": output_arrays(pipeline), "workers": len({t["worker"] for t in tasks}),
    }


# ---------------------------------------------------------------------------
# Part 3: the scaling model


def lpt_makespan(durations: list[float], workers: int) -> float:
    """Longest-processing-time-first list scheduling over ``workers``: the finishing time of the busiest."""
    loads = [0.0] * max(1, workers)
    for duration in sorted(durations, reverse=True):
        heapq.heappush(loads, heapq.heappop(loads) + duration)
    return max(loads)


def list_makespan(durations: list[float], workers: int) -> float:
    """Greedy list scheduling in the given order (each task to the worker free first), as a pool or
    Dask hands out tasks submitted in that order."""
    loads = [0.0] * max(1, workers)
    for duration in durations:
        heapq.heappush(loads, heapq.heappop(loads) + duration)
    return max(loads)


def broadcast_hops(workers: int) -> int:
    """Scene transfers on the critical path of ``Client.scatter(broadcast=True)``: client -> scheduler ->
    one worker (2), then Dask's replicate tree copy, where each holder sends to up to 2 new workers a
    generation (``Scheduler.replicate``, branching_factor 2): a generation costs 2 transfers from the
    busiest holder, 1 when each holder sends one copy."""
    hops, holders = 2, 1
    while holders < workers:
        new = min(workers - holders, 2 * holders)
        hops += math.ceil(new / holders)
        holders += new
    return hops


def map_chunks(count: int, workers: int, chunk_size: int | None = None) -> list[tuple[int, int]]:
    """The (lo, hi) chunks DaskChunks cuts a map of ``count`` items into on ``workers`` workers."""
    from usdbake.core.chunks import chunk_bounds
    from usdbake.farm.chunks import MIN_CHUNK_ITEMS, TASKS_PER_WORKER

    size = chunk_size or max(MIN_CHUNK_ITEMS, math.ceil(count / (TASKS_PER_WORKER * workers)))
    return chunk_bounds(count, size) or [(0, 0)]


def first_tasks(run: dict) -> dict[str, int]:
    """{worker: index of its first task} (by compute start): the task that built the worker's BVH."""
    first: dict[str, int] = {}
    for index, task in enumerate(run["tasks"]):
        if task["worker"] not in first or task["start"] < run["tasks"][first[task["worker"]]]["start"]:
            first[task["worker"]] = index
    return first


def worker_setup_seconds(run: dict) -> float:
    """What a worker's first task of a scene costs beyond its compute (the BVH build, the scene's first
    use): its time less the median per-item time of the other tasks of its map times its items; the
    slowest worker's (they set up at once)."""
    excess = []
    for index in first_tasks(run).values():
        task = run["tasks"][index]
        others = [t["seconds"] / t["items"] for k, t in enumerate(run["tasks"])
                  if t["map"] == task["map"] and k != index and t["items"]]
        excess.append(task["seconds"] - (statistics.median(others) * task["items"] if others else 0.0))
    return max(excess, default=0.0)


def per_task_compute(profile: dict, coarse: dict) -> float:
    """Seconds of a task's compute that do not depend on its items (dispatch to the worker's thread,
    arrays and launch set-up): the same maps run on 1 worker in many and in few chunks differ by this
    much per extra task."""
    def compute(run):
        return sum(t["seconds"] for t in run["tasks"]) - worker_setup_seconds(run)

    extra = len(profile["tasks"]) - len(coarse["tasks"])
    return max(0.0, (compute(profile) - compute(coarse)) / extra) if extra > 0 else 0.0


def profile_maps(run: dict, setup: float) -> list[dict]:
    """Per map of a profile run: its item count and its chunks' compute seconds (each spread evenly over
    its items, ``recut``); the first task of each worker less the set-up time ``setup``."""
    firsts = set(first_tasks(run).values())
    maps = []
    for token in run["maps"]:
        pieces = sorted((task["first"], task["first"] + task["items"],
                         max(task["seconds"] - (setup if index in firsts else 0.0), 0.0))
                        for index, task in enumerate(run["tasks"]) if task["map"] == token)
        maps.append({"count": pieces[-1][1], "pieces": pieces})
    return maps


def recut(profile: dict, lo: int, hi: int, fixed: float) -> float:
    """Compute seconds of a task of items lo .. hi - 1 of a profiled map: ``fixed`` (per_task_compute)
    plus each profile chunk's time beyond ``fixed`` spread evenly over its items."""
    total = fixed
    for a, b, seconds in profile["pieces"]:
        overlap = min(hi, b) - max(lo, a)
        if overlap > 0:
            total += max(seconds - fixed, 0.0) * overlap / max(b - a, 1)
    return total


def predict(maps: list[dict], workers: int, c: dict) -> dict:
    """T(W) of one processor on ``workers`` workers of 1 thread, by parts (seconds).

    serial: the processor's time outside its maps in process (numpy between passes), and the BVH the
    client builds for applies(); scatter: the scene's pickled bytes (and any large setting a map
    scatters) x broadcast_hops / bandwidth; bvh:
    one set-up per worker (first-task excess: BVH build), all at once; compute: per map, one round
    trip + the LPT makespan of its chunks (compute re-cut from the profile, with its fixed part per
    task, + each task's worker time outside compute), at least tasks x the scheduler's time per task;
    transfer: items, results and each task's settings at the gather bandwidth.
    """
    compute, tasks = 0.0, 0
    for profile in maps:
        bounds = map_chunks(profile["count"], workers, c.get("chunk_size"))
        outside = max(c["overhead_per_task_s"] - c["noop_compute_s"], 0.0)  # a task's worker time outside compute
        durations = [recut(profile, lo, hi, c["per_task_compute_s"]) + outside for lo, hi in bounds]
        compute += c["round_trip_s"] + max(lpt_makespan(durations, workers),
                                           len(bounds) * c["scheduler_per_task_s"])
        tasks += len(bounds)
    parts = {
        "serial": c["serial_seconds"] + c["client_bvh_seconds"],
        "scatter": (c["scene_pickled_bytes"] + c["setting_scatter_bytes"]) * broadcast_hops(workers)
        / c["scatter_bytes_per_s"],
        "bvh": c["worker_bvh_seconds"],
        "compute": compute,
        "transfer": (c["item_bytes"] + c["result_bytes"] + tasks * c["static_bytes_per_task"])
        / c["gather_bytes_per_s"],
    }
    return {"workers": workers, "tasks": tasks, "seconds": sum(parts.values()), **parts}


# ---------------------------------------------------------------------------
# The benchmark


def median_run(runs: list[dict], reference: list | None) -> dict:
    """The run of median wall time, with every run's wall time and whether every run's outputs equal
    ``reference`` bit for bit (their outputs are dropped: only the flag is kept)."""
    chosen = sorted(runs, key=lambda r: r["wall"])[len(runs) // 2]
    chosen["walls"] = [r["wall"] for r in runs]
    chosen["identical"] = all(identical(reference, r["outputs"]) for r in runs) if reference is not None else True
    for r in runs:
        r.pop("outputs", None)
    return chosen


def large(quick: bool, clean_environ: dict) -> dict:
    """Parts 2 and 3: the large scene in process and on 2 and 1 workers (median of ``repeats`` runs
    each), the profile run, the model."""
    from usdbake.farm.batch import BatchOptions
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
                bvh["worker"] = worker_bvh_seconds(client, scene, repeats)
                for name in processors:
                    runs[name]["profile"] = median_run([run_on_dask(scene, name, params, client,
                                                                    chunk_size=PROFILE_CHUNK)], reference[name])
                    gc.collect()
        finally:
            stop_cluster(cluster, client)
        clusters[workers] = {**startup, **costs}

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
    for name in processors:
        here, two, one, profile = (runs[name][k] for k in ("in_process", "dask_2", "dask_1", "profile"))
        same = all(runs[name][k]["identical"] for k in ("in_process", "dask_2", "dask_1", "profile"))
        tasks = two["tasks"]
        bandwidth = one["scene_pickled_bytes"] * broadcast_hops(1) / max(one["scatter_seconds"], 1e-9)
        setup = worker_setup_seconds(profile)
        fixed = per_task_compute(profile, one)
        maps = profile_maps(profile, setup)
        model_check, constants = {}, {}
        for workers, measured in ((1, one), (2, two)):
            c = {"serial_seconds": here["serial_seconds"], "client_bvh_seconds": measured["client_bvh_seconds"],
                 "scene_pickled_bytes": one["scene_pickled_bytes"], "scatter_bytes_per_s": bandwidth,
                 "setting_scatter_bytes": one["setting_scatter_bytes"], "worker_bvh_seconds": setup,
                 "item_bytes": sum(one["item_bytes"]), "result_bytes": one["stats"]["result_bytes"],
                 "static_bytes_per_task": statistics.mean(one["static_bytes"]),
                 "gather_bytes_per_s": clusters[workers]["gather_bytes_per_s"],
                 "round_trip_s": clusters[workers]["round_trip_s"], "per_task_compute_s": fixed,
                 "noop_compute_s": clusters[workers]["noop_compute_s"],
                 "overhead_per_task_s": clusters[workers]["overhead_per_task_s"],
                 "scheduler_per_task_s": clusters[workers]["scheduler_per_task_s"]}
            constants[workers] = c
            predicted = predict(maps, workers, c)
            model_check[workers] = {"predicted": predicted["seconds"], "measured": measured["wall"],
                                    "error": predicted["seconds"] / measured["wall"] - 1.0, "parts": predicted,
                                    "scatter_measured": measured["scatter_seconds"],
                                    "scatter_predicted": predicted["scatter"],
                                    "outside_tasks_measured": measured["outside_tasks_seconds"]}
        # beyond this machine: the 2-worker constants (its scheduler shares the cores with the workers,
        # as on a busy head node; its bandwidth is a memory copy: see docs/distributed.md)
        predictions = [predict(maps, w, constants[2]) for w in MODEL_WORKERS]
        documented = {**constants[2], "scheduler_per_task_s": DOCUMENTED_TASK_OVERHEAD}
        predictions_documented = [predict(maps, w, documented) for w in MODEL_WORKERS]
        for series in (predictions, predictions_documented):
            for p in series:
                p["speedup"] = series[0]["seconds"] / p["seconds"]
                p["efficiency"] = p["speedup"] / p["workers"]
        serial_all = here["serial_seconds"] + two["client_bvh_seconds"] + setup
        out["processors"][name] = {
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
    return out


def _spread(values: list[float]) -> dict:
    values = sorted(values)
    return {"count": len(values), "min": values[0], "median": statistics.median(values), "max": values[-1],
            "sum": sum(values)}


def _stop_scaling(predictions: list[dict]) -> int:
    """The most workers whose predicted parallel efficiency is still >= 50%."""
    good = [p["workers"] for p in predictions if p["efficiency"] >= 0.5]
    return max(good) if good else 1


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
    print(f"  batch of {len(names)}: in process {b['in_process_seconds']:.2f} s, pool of 2 {b['pool_seconds']:.2f} s "
          f"({b['pool_overhead']:+.1%}; pool start-up {b['pool_startup_seconds']:.2f} s), Dask 2 x 1 "
          f"{b['dask_seconds']:.2f} s ({b['dask_overhead']:+.1%}; its stage times scheduled in input order "
          f"{b['dask_in_order_seconds']:.2f} s, longest first {b['dask_lpt_seconds']:.2f} s; cluster start-up "
          f"{b['dask_startup_seconds']:.2f} s + warm-up {b['dask_warmup_seconds']:.2f} s, not timed); "
          f"a task sends {b['task_argument_bytes_mean']:.0f} B, "
          f"returns {b['task_result_bytes_mean']:.0f} B; layers identical: pool {b['pool_layers_identical']}, "
          f"Dask {b['dask_layers_identical']} ({b['attributes_compared']} attributes)")
    big = large(quick, clean_environ)
    print(f"  BVH of the large scene, 1 thread: here {big['bvh_1_thread_seconds']:.2f} s, in a Dask worker "
          f"{big['bvh_worker_seconds']:.2f} s")
    figures = {
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
        print(f"  BVH of the large scene in a fresh process, 1 thread: {big['bvh_fresh_process_seconds']:.2f} s; with "
              f"the nanny's environment {big['nanny_environ']} {big['bvh_fresh_process_nanny_environ_seconds']:.2f} "
              f"s; and MALLOC_MMAP_THRESHOLD_={MMAP_THRESHOLD} "
              f"{big['bvh_fresh_process_nanny_environ_mmap_seconds']:.2f} s")
    rows_large, rows_bytes, rows_check, rows_model, points = [], [], [], [], []
    for name, p in big["processors"].items():
        short = "ao" if name == "ambient_occlusion" else "sky"
        figures.update({
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
        })
        for pred in p["predictions"]:
            if pred["workers"] in (16, 64):
                figures[f"large_{short}_predicted_{pred['workers']}_seconds"] = round(pred["seconds"], 3)
                figures[f"large_{short}_predicted_{pred['workers']}_speedup"] = round(pred["speedup"], 2)
        for pred in p["predictions_scheduler_1ms"]:
            if pred["workers"] in (16, 64):
                figures[f"large_{short}_predicted_{pred['workers']}_seconds_scheduler_1ms"] = round(pred["seconds"], 3)
        figures[f"large_{short}_stops_scaling_workers"] = _stop_scaling(p["predictions"])
        rows_large.append({"processor": name, "in process, 2 threads (s)": p["in_process_seconds"],
                           "Dask 2 x 1 (s)": p["dask_2_seconds"], "Dask 1 x 1 (s)": p["dask_1_seconds"],
                           "overhead at equal cores": f"{p['overhead_equal_cores']:+.1%}",
                           "outside tasks, 2 workers (s)": p["outside_tasks_seconds_2"],
                           "bit-identical": "yes" if p["bit_identical"] else "**no**"})
        rows_bytes.append({"processor": name, "maps": p["maps"], "tasks (2 workers)": p["tasks_2"],
                           "items / task (B)": round(p["item_bytes_per_task"]),
                           "settings / task (B)": round(p["static_bytes_per_task"]),
                           "pickled arguments / task (B)": round(p["argument_bytes_per_task"]),
                           "results / task (B)": round(p["result_bytes_per_task"]),
                           "scene arrays (B)": p["scene_bytes"], "scene pickled (B)": p["scene_pickled_bytes"],
                           "task compute median (s)": p["task_seconds_2"]["median"]})
        for workers, check in p["model_check"].items():
            rows_check.append({"processor": name, "workers": workers, "predicted (s)": check["predicted"],
                               "measured (s)": check["measured"], "error": f"{check['error']:+.1%}",
                               "scatter predicted / measured (s)":
                                   f"{check['scatter_predicted']:.3f} / {check['scatter_measured']:.3f}"})
        for pred, alt in zip(p["predictions"], p["predictions_scheduler_1ms"]):
            rows_model.append({"processor": name, "workers": pred["workers"], "tasks": pred["tasks"],
                               "T (s)": pred["seconds"], "T at 1 ms/task (s)": alt["seconds"],
                               "speed-up vs 1": pred["speedup"],
                               "efficiency": f"{pred['efficiency']:.0%}", "serial": pred["serial"],
                               "scatter": pred["scatter"], "BVH": pred["bvh"], "maps": pred["compute"],
                               "transfer": pred["transfer"]})
        points += [{"label": f"{short} in process", "seconds": p["in_process_seconds"], "error": 0.0, "default": True},
                   {"label": f"{short} Dask 2x1", "seconds": p["dask_2_seconds"], "error": 0.0},
                   {"label": f"{short} Dask 1x1", "seconds": p["dask_1_seconds"], "error": 0.0}]
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
    points += [{"label": "batch in process", "seconds": b["in_process_seconds"], "error": 0.0},
               {"label": "batch pool 2", "seconds": b["pool_seconds"], "error": 0.0},
               {"label": "batch Dask 2x1", "seconds": b["dask_seconds"], "error": 0.0}]
    clusters = big["clusters"]
    costs = harness.markdown_table([{"workers": w, "cluster start-up (s)": c["startup_seconds"],
                                     "warm-up bake (s)": c["warmup_seconds"], "no-op round trip (ms)":
                                     1e3 * c["round_trip_s"], "scheduler time / task (ms)":
                                     1e3 * c["scheduler_per_task_s"], "overhead / task / worker (ms)":
                                     1e3 * c["overhead_per_task_s"], "gather (GB/s)": c["gather_bytes_per_s"] / 1e9}
                                    for w, c in clusters.items()],
                                   ["workers", "cluster start-up (s)", "warm-up bake (s)", "no-op round trip (ms)",
                                    "scheduler time / task (ms)", "overhead / task / worker (ms)", "gather (GB/s)"])
    table = "\n\n".join([
        f"Batch of {len(names)} stages ({', '.join(BATCH_PROCESSORS)}), wall seconds:\n\n" + harness.markdown_table(
            [{"mode": "in process, one by one, 2 threads", "seconds": b["in_process_seconds"], "overhead": ""},
             {"mode": "bake_many(workers=2), spawned pool", "seconds": b["pool_seconds"],
              "overhead": f"{b['pool_overhead']:+.1%}"},
             {"mode": "bake_many on Dask, 2 workers x 1 thread", "seconds": b["dask_seconds"],
              "overhead": f"{b['dask_overhead']:+.1%}"}], ["mode", "seconds", "overhead"]),
        harness.markdown_table(b["per_stage"], ["stage", "in process (s)", "Dask task, bake only (s)"]),
        f"Large scene ({big['triangles']:,} triangles):\n\n" + harness.markdown_table(
            rows_large, ["processor", "in process, 2 threads (s)", "Dask 2 x 1 (s)", "Dask 1 x 1 (s)",
                         "overhead at equal cores", "outside tasks, 2 workers (s)", "bit-identical"]),
        harness.markdown_table(rows_bytes, ["processor", "maps", "tasks (2 workers)", "items / task (B)",
                                            "settings / task (B)", "pickled arguments / task (B)",
                                            "results / task (B)", "scene arrays (B)", "scene pickled (B)",
                                            "task compute median (s)"]),
        costs,
        "Model against measurement:\n\n" + harness.markdown_table(
            rows_check, ["processor", "workers", "predicted (s)", "measured (s)", "error",
                         "scatter predicted / measured (s)"]),
        "Model, default chunking (parts in seconds):\n\n" + harness.markdown_table(
            rows_model, ["processor", "workers", "tasks", "T (s)", "T at 1 ms/task (s)", "speed-up vs 1", "efficiency",
                         "serial", "scatter", "BVH", "maps", "transfer"]),
    ])
    return harness.result(NAME, description=DESCRIPTION,
                          settings={"threads_in_process": THREADS, "worker_threads": 1, "samples": list(names),
                                    "batch_processors": list(BATCH_PROCESSORS), "batch_params": batch_params,
                                    "large_copies": big["copies"], "large_params": big["params"],
                                    "profile_chunk": PROFILE_CHUNK, "model_workers": list(MODEL_WORKERS),
                                    "noop_tasks": NOOP_TASKS, "gather_bytes": GATHER_BYTES,
                                    "load_average_before": list(load_before),
                                    "load_average_after": list(os.getloadavg())},
                          points=points, figures=figures, table=table, knob="where the work runs",
                          error_label="(none: timing only)") | {"batch": b, "large": _plain(big)}


def _plain(value):
    """``value`` without numpy scalars and with int keys as strings (for the JSON file)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value
