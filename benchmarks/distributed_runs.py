"""One processor on one scene, timed: in process with its maps timed, or on Dask with every task's
compute, transfer and arguments recorded; outputs kept for the bit-for-bit comparison of runs."""

from __future__ import annotations

import dataclasses
import math
import pickle
import time

import numpy as np

THREADS = 2
"""Cores of the in-process bakes: equal to 2 workers x 1 thread."""


class TimedSceneChunks:
    """core.chunks.SceneChunks that times its maps, the BVH build kept apart (the in-process run)."""

    def __init__(self, inner, clock: dict):
        self.inner, self.clock = inner, clock

    def map(self, fn, items, *, progress=None, **static):
        started = time.perf_counter()
        self.inner.tracer  # built here on the first map when nothing built it before (timed by timed_tracer_factory)
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

    def for_scene(self, scene, runtime):
        from usdbake.core.chunks import InProcess

        return TimedSceneChunks(InProcess().for_scene(scene, runtime), self.clock)


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


def timed_tracer_factory() -> tuple:
    """(factory, seconds): ``Tracer.from_scene`` timed, for a Runtime; each call is one BVH build (a run
    builds one per scene, on first use in applies() or a map)."""
    from usdbake.kernels.tracer import Tracer

    bvh = {"seconds": 0.0, "builds": 0}

    def build(scene, **options):
        started = time.perf_counter()
        tracer = Tracer.from_scene(scene, **options)
        bvh["seconds"] += time.perf_counter() - started
        bvh["builds"] += 1
        return tracer
    return build, bvh


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

    from usdbake.core.runtime import Runtime

    scene = dataclasses.replace(scene)  # a new object, as a new run reads one
    runner = TimedInProcess()
    build, bvh = timed_tracer_factory()
    pipeline = Pipeline.build([processor], params, cache_dir=None, force=True,
                              runtime=Runtime(build, threads=THREADS, chunks=runner),
                              ignorable=tuple(params))  # one table for every processor of the sweep
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

    from usdbake.core.runtime import Runtime

    scene = dataclasses.replace(scene)
    metered = MeteredClient(client)
    chunks = DaskChunks(metered, chunk_size=chunk_size)
    build, bvh = timed_tracer_factory()
    pipeline = Pipeline.build([processor], params, cache_dir=None, force=True,
                              runtime=Runtime(build, threads=THREADS, chunks=chunks),
                              ignorable=tuple(params))
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


def median_run(runs: list[dict], reference: list | None) -> dict:
    """The run of median wall time, with every run's wall time and whether every run's outputs equal
    ``reference`` bit for bit (their outputs are dropped: only the flag is kept)."""
    chosen = sorted(runs, key=lambda r: r["wall"])[len(runs) // 2]
    chosen["walls"] = [r["wall"] for r in runs]
    chosen["identical"] = all(identical(reference, r["outputs"]) for r in runs) if reference is not None else True
    for r in runs:
        r.pop("outputs", None)
    return chosen
