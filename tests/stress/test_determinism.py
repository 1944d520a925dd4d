"""Determinism: the same inputs and seed give bit-identical outputs across runs and thread counts.

Every processor's random numbers are seeded by item index (wp.rand_init(seed, i)), so splitting a
launch into chunks on several threads must not change a single bit. Launches on these small scenes
are far below tracer.MIN_CHUNK (4096), so it is lowered to 8 here: launch_chunked reads it at call
time, and every processor launches through it (Tracer.launch, or launch_chunked directly in
form_factors). Each run builds a fresh Pipeline with no cache, so everything is recomputed.

Thread counts reach the kernels through the run's Runtime(threads=...) -> its Tracer, and -> ctx.threads for
the processors that build BVHs of their own (displacement_fields, instance_ao).
"""

from __future__ import annotations


import numpy as np
import pytest
from stress.stage_builders_stress import fast_params, hostile_lit_stage, small_lit_stage, walk_values
from usdbake import core
from usdbake.kernels import tracer
from usdbake.stages.extract import extract_scene
from usdbake.core.pipeline import Pipeline
from usdbake.core.runtime import Runtime
from usdbake.kernels.tracer import Tracer

PROCESSORS = sorted(name for name, cls in core.registry.registry().items()
                    if cls.__module__.startswith("usdbake.processors."))

SMALL_CHUNK = 8
"""Chunks of 8 items: every launch of more than 16 items is split across threads."""


TIMINGS = ("build_seconds", "seconds")
"""Wall-clock fields in products: measurements, not outputs."""


NO_KERNELS = ("progressive_mesh",)
"""Processors that launch no Warp kernel (pure numpy): nothing to split."""


def record_arrays(value, where: str):
    """(where, array) for every value in the output records and products: numpy arrays of any dtype,
    raw bytes (files) as uint8 arrays, and numeric scalars; wall-clock fields left out."""
    for key, leaf in walk_values(value, where, skip_fields=TIMINGS):
        if isinstance(leaf, (bytes, bytearray)):
            yield key, np.frombuffer(bytes(leaf), np.uint8)
        else:
            yield key, np.asarray(leaf)


def run_once(name: str, scene, threads: int) -> dict[str, np.ndarray]:
    steps = Pipeline.build([name], fast_params(name), runtime=Runtime(Tracer.from_scene, threads=threads)).run(scene)
    out = {}
    for step in steps:
        assert step.action == "run", f"{step.name}: {step.action} ({step.reason})"
        out.update(record_arrays(step.result.outputs, f"{step.name}.outputs"))
        out.update(record_arrays(step.result.products, f"{step.name}.products"))
    return out


@pytest.fixture(scope="module")
def scenes():
    return {"hostile": extract_scene(hostile_lit_stage()), "small": extract_scene(small_lit_stage())}


@pytest.fixture
def small_chunks(monkeypatch):
    """MIN_CHUNK lowered; returns the list of chunk counts of every launch split across threads."""
    monkeypatch.setattr(tracer, "MIN_CHUNK", SMALL_CHUNK)
    calls: list[int] = []
    original = tracer.ThreadPoolExecutor

    class Counting(original):
        def map(self, fn, *iterables, **kwargs):
            items = list(iterables[0])
            calls.append(len(items))
            return super().map(fn, items, **kwargs)

    monkeypatch.setattr(tracer, "ThreadPoolExecutor", Counting)
    return calls


@pytest.mark.parametrize("name", PROCESSORS)
@pytest.mark.parametrize("scene_name", ["small", "hostile"])
def test_bit_identical_across_runs_and_threads(name, scene_name, scenes, small_chunks):
    scene = scenes[scene_name]
    runs = {label: run_once(name, scene, threads) for label, threads in
            (("threads=1", 1), ("threads=2", 2), ("threads=2 again", 2))}
    reference = runs["threads=1"]
    assert reference, f"{name} produced nothing to compare"
    if name not in NO_KERNELS:
        assert small_chunks and max(small_chunks) > 1, f"{name}: no launch was split across threads"
    assert sum(a.size for a in reference.values()) > 0
    for label, other in runs.items():
        assert other.keys() == reference.keys(), label
        for key, array in reference.items():
            assert other[key].dtype == array.dtype and other[key].shape == array.shape, f"{label}: {key}"
            assert np.array_equal(other[key], array), \
                f"{label}: {key} differs in {np.count_nonzero(other[key] != array)} of {array.size} values"
