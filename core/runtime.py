"""The run-time object: where one run computes, the BVH of each of its scenes, and where its chunks run.

A front end (``usdbake.bake``, the ``usdbake`` command, a farm worker, a test) builds one ``Runtime`` per
run; the Pipeline hands it to every step, whose Context reads device, threads, tracer and chunk runner
from it. Nothing changes it afterwards. "Every core" is written ``threads=None``, and only so.

Core holds no Warp code, so the tracer factory comes from the caller: usually
``usdbake.kernels.tracer.Tracer.from_scene``, called as ``build_tracer(scene, device=..., threads=...)``.
"""

from __future__ import annotations

import threading
import weakref
from typing import Any, Callable

from .chunks import ChunkRunner, InProcess, SceneChunks
from .errors import UsageError
from .scene import Scene


def check_threads(threads) -> None:
    """UsageError unless ``threads`` is a whole number of at least 1, or None (every core)."""
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
        raise UsageError(f"threads={threads!r}: expected a whole number of at least 1")


class Runtime:
    """How one run computes: device, CPU threads, one BVH per scene, and the chunk runner.

    Parameters
    ----------
    build_tracer : callable
        ``build_tracer(scene, *, device, threads)`` -> the scene's tracer (``Tracer.from_scene``).
    device : str
        Warp device: "cpu" or "cuda:N".
    threads : int or None
        CPU threads for kernel launches; None: every core.
    chunks : ChunkRunner, optional
        Where work split by receivers runs: ``InProcess`` (default) or ``usdbake.farm.chunks.DaskChunks``.
    """

    def __init__(self, build_tracer: Callable[..., Any], *, device: str = "cpu", threads: int | None = None,
                 chunks: ChunkRunner | None = None):
        check_threads(threads)
        self.build_tracer = build_tracer
        self.device, self.threads = device, threads
        self.chunks = chunks if chunks is not None else InProcess()
        self._tracers: dict[int, Any] = {}
        self._lock = threading.Lock()

    def tracer(self, scene: Scene) -> Any:
        """The scene's one BVH in this run: built on the first call (by ``applies``, ``run`` or a chunk),
        then the same object; dropped with the scene."""
        key = id(scene)
        with self._lock:  # a Dask worker runs several chunks of one scene at once
            tracer = self._tracers.get(key)
            if tracer is None:
                tracer = self._tracers[key] = self.build_tracer(scene, device=self.device, threads=self.threads)
                weakref.finalize(scene, _forget, weakref.ref(self), key)  # holds the run only weakly
        return tracer

    def scene_chunks(self, scene: Scene) -> SceneChunks:
        """The chunk runner's ``map`` for ``scene``."""
        return self.chunks.for_scene(scene, self)


def _forget(runtime: weakref.ref, key: int) -> None:
    """A scene is gone: drop its BVH from the run that built it, if that run is still alive."""
    alive = runtime()
    if alive is not None:
        alive._tracers.pop(key, None)
