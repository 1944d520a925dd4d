"""A large scene's receiver work as Dask tasks (the cluster side of core.chunks).

The scene is scattered once per run to every worker (``Client.scatter(broadcast=True)``), so a task
carries only its own items (a range of points or faces) and the chunk's settings. On the worker the
scene is one object held by Dask, and the worker's run-time object (``worker_runtime``, built on its
first task) keys its BVH by that object: each worker builds the BVH once per scene, whatever the number
of tasks it runs. Chunk functions seed their random numbers from global item indices (core.chunks), so
results are bit-identical to an in-process bake for any chunk size and any number of workers; Dask
re-runs the tasks of a worker that dies, which changes nothing in the output for the same reason.
"""

from __future__ import annotations

import math
import uuid
import weakref
from functools import cache
from typing import Callable

import numpy as np

from ..core.chunks import chunk_bounds, concatenate_parts
from ..core.runtime import Runtime
from ..kernels.startup import start_warp_quietly
from ..kernels.tracer import Tracer
from .cluster import worker_count, worker_threads

TASKS_PER_WORKER = 4
"""Default chunks per worker and map: enough to balance uneven chunks, few enough to keep per-task
overhead (~1 ms scheduling, the items' transfer) small against the work."""
MIN_CHUNK_ITEMS = 64
"""The smallest default chunk: below this a task's overhead outweighs its rays."""
SCATTER_BYTES = 1 << 20
"""A shared setting of a map (``static``) larger than this (form factors' patches, a scene's normals)
goes to every worker once per map, not once per task."""


@cache
def worker_runtime(device: str) -> Runtime:
    """This worker process's run-time object on ``device``, with the worker's share of the cores: built on
    its first task, so later tasks reuse the BVH of their scene."""
    start_warp_quietly(device)
    return Runtime(Tracer.from_scene, device=device, threads=worker_threads())


def run_chunk(fn: Callable, scene, device: str, first: int, items: tuple, static: dict):
    """On a worker: ``fn`` over one chunk with the worker's BVH of ``scene`` (built on its first task)."""
    return fn(worker_runtime(device).tracer(scene), first, *items, **static)


class DaskChunks:
    """Receiver work on a Dask cluster: chunks of ``chunk_size`` items (default: TASKS_PER_WORKER
    chunks per worker, at least MIN_CHUNK_ITEMS items)."""

    def __init__(self, client, *, chunk_size: int | None = None):
        if chunk_size is not None and chunk_size < 1:
            raise ValueError(f"chunk_size={chunk_size!r}: at least 1 item")
        self.client = client
        self.chunk_size = chunk_size
        self._scattered: dict[int, object] = {}
        self.stats = {"tasks": 0, "item_bytes": 0, "result_bytes": 0, "scene_bytes": 0, "static_bytes": 0,
                      "scatters": 0}
        """Totals over every map: tasks sent, bytes of items sent and results received, scene bytes
        scattered (once per scene, to every worker) and large shared settings scattered (once per map)."""

    @property
    def description(self) -> str:
        return f"Dask scheduler {self.client.scheduler.address} ({worker_count(self.client)} workers)"

    def for_scene(self, scene, runtime: Runtime) -> "DaskSceneChunks":
        """Chunks of ``scene`` as tasks; each worker traces on ``runtime.device`` with its own threads."""
        return DaskSceneChunks(self, scene, runtime.device)

    def scene_future(self, scene):
        """The scene scattered to every worker, once per scene object (dropped with the scene)."""
        key = id(scene)
        if key not in self._scattered:
            self._scattered[key] = self.client.scatter(scene, broadcast=True, hash=False)
            weakref.finalize(scene, self._scattered.pop, key, None)
            self.stats["scene_bytes"] += array_nbytes(scene)
            self.stats["scatters"] += 1
        return self._scattered[key]


class DaskSceneChunks:
    """``map`` for one scene on a DaskChunks cluster (see core.chunks.SceneChunks)."""

    def __init__(self, runner: DaskChunks, scene, device: str):
        self.runner, self.scene, self.device = runner, scene, device

    def map(self, fn: Callable, items: tuple[np.ndarray, ...], *, progress: Callable[[float], None] | None = None,
            **static):
        """``fn`` over the items in chunks, one Dask task each; results joined in item order."""
        from distributed import as_completed

        client = self.runner.client
        count = len(items[0])
        size = self.runner.chunk_size or max(MIN_CHUNK_ITEMS,
                                             math.ceil(count / (TASKS_PER_WORKER * worker_count(client))))
        bounds = chunk_bounds(count, size) or [(0, 0)]  # no items: one empty chunk gives the empty result's shape
        scene = self.runner.scene_future(self.scene)
        static = {name: self._shared(value) for name, value in static.items()}
        stats = self.runner.stats
        token = uuid.uuid4().hex[:8]
        futures = []
        for lo, hi in bounds:
            part = tuple(np.ascontiguousarray(a[lo:hi]) for a in items)
            stats["item_bytes"] += sum(a.nbytes for a in part)
            futures.append(client.submit(run_chunk, fn, scene, self.device, lo, part, static, pure=False,
                                         key=f"usdbake-{fn.__name__}-{token}-{lo}"))
        stats["tasks"] += len(futures)
        for done, _ in enumerate(as_completed(futures, loop=client.loop), start=1):
            if progress:
                progress(done / len(futures))
        parts = client.gather(futures)  # in submission order: item order
        stats["result_bytes"] += sum(sum(a.nbytes for a in p) if isinstance(p, tuple) else p.nbytes
                                          for p in parts)
        return concatenate_parts(parts)

    def _shared(self, value):
        """``value``; the scene's future for the scene itself (sent once per run); a future of ``value`` on
        every worker when it is larger than SCATTER_BYTES."""
        if value is self.scene:
            return self.runner.scene_future(self.scene)
        size = array_nbytes(value)
        if size <= SCATTER_BYTES:
            return value
        self.runner.stats["static_bytes"] += size
        return self.runner.client.scatter(value, broadcast=True, hash=False)


def array_nbytes(value) -> int:
    """Bytes of the numpy arrays in a value and the dataclasses it nests (what a scatter sends, near enough)."""
    from dataclasses import fields, is_dataclass

    total, pending = 0, [value]
    while pending:
        value = pending.pop()
        if isinstance(value, np.ndarray):
            total += value.nbytes
        elif is_dataclass(value):
            pending.extend(getattr(value, f.name) for f in fields(value))
    return total
