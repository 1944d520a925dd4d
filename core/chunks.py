"""Work split by receivers: a range of items (points, faces) run as chunks, here or on a cluster.

A processor whose work splits by receivers hands it to ``ctx.chunks.map(fn, items, **static)``:

- ``fn(tracer, first, *item_slices, **static)`` is a module-level function (so a Dask worker can
  import it) that computes items ``first .. first + len(slice) - 1`` and returns an array, or a
  tuple of arrays, whose first axis runs over those items. It must seed its random numbers from
  the global item index (``first + i``) or from ids carried in ``items``, never from its position
  in the chunk: then the result does not depend on how the range was cut, and a chunked bake is
  bit-identical to a local one.
- ``items`` are per-item arrays (sliced per chunk); ``static`` are the settings every chunk shares.

A chunk runner (``ChunkRunner``) is part of the run's ``core.runtime.Runtime``. ``InProcess`` (the
default) runs the whole range as one call on the scene's tracer of the run, whose launches use the run's
threads. ``usdbake.farm.chunks.DaskChunks`` cuts the range into tasks on a Dask cluster, sending the
scene once per worker.
"""

from __future__ import annotations

from typing import Callable, Protocol

import numpy as np


def concatenate_parts(parts: list) -> np.ndarray | tuple[np.ndarray, ...]:
    """Chunk results, in item order, joined along their first axis (tuples element by element)."""
    if isinstance(parts[0], tuple):
        return tuple(np.concatenate([part[k] for part in parts]) for k in range(len(parts[0])))
    return np.concatenate(parts)


def chunk_bounds(count: int, chunk_size: int) -> list[tuple[int, int]]:
    """[(lo, hi), ...] covering 0 .. count - 1 in chunks of ``chunk_size`` items (the last may be short)."""
    return [(lo, min(count, lo + chunk_size)) for lo in range(0, count, max(1, int(chunk_size)))]


class SceneChunks:
    """Runs chunk functions over items of one scene in this process (``InProcess.for_scene``)."""

    def __init__(self, tracer: Callable[[], object] | object):
        self._tracer = tracer

    @property
    def tracer(self):
        if callable(self._tracer):
            self._tracer = self._tracer()
        return self._tracer

    def map(self, fn: Callable, items: tuple[np.ndarray, ...], *, progress: Callable[[float], None] | None = None,
            **static):
        """``fn`` over every item at once (its launches are chunked across threads); see the module docstring."""
        result = fn(self.tracer, 0, *items, **static)
        if progress:
            progress(1.0)
        return result


class ChunkRunner(Protocol):
    """Where a run's chunks go: ``for_scene(scene, runtime)`` gives the object whose ``map`` runs them."""

    def for_scene(self, scene, runtime) -> SceneChunks: ...


class InProcess:
    """The default runner: every chunk here, on the run's tracer of the scene (``runtime.tracer(scene)``)."""

    def for_scene(self, scene, runtime) -> SceneChunks:
        return SceneChunks(lambda: runtime.tracer(scene))
