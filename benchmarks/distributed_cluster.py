"""Dask on one machine for the distributed benchmark: clusters of warm workers, their fixed costs per
task, and BVH builds timed in a worker and in fresh interpreters (with and without the nanny's environment)."""

from __future__ import annotations

import logging
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

NOOP_TASKS = 400
"""No-op tasks in flight at once when the scheduler's time per task is measured (``fixed_costs``)."""
GATHER_BYTES = 64 * 2 ** 20
"""Size of the array whose gather times the client's bandwidth (``fixed_costs``)."""


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
from usdbake.benchmarks.distributed_large import large_scene
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
