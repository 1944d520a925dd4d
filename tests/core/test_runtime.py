"""The run-time object (core.runtime): one BVH per scene and run, built by the caller's tracer factory, and
"every core" written threads=None only."""

import gc
import weakref

import pytest

import fake_processors as fakes
from usdbake import core
from usdbake.core.chunks import InProcess
from usdbake.core.runtime import Runtime
from usdbake.kernels.tracer import Tracer


def counting_factory(built: list):
    def build_tracer(scene, *, device, threads):
        built.append((scene, device, threads))
        return object()
    return build_tracer


def test_the_tracer_factory_runs_once_per_scene_with_the_run_s_device_and_threads():
    built = []
    runtime = Runtime(counting_factory(built), device="cpu", threads=2)
    scene, other = fakes.make_scene(), fakes.make_scene()
    first = runtime.tracer(scene)
    assert runtime.tracer(scene) is first and runtime.tracer(other) is not first
    assert built == [(scene, "cpu", 2), (other, "cpu", 2)]


def test_a_bvh_lives_no_longer_than_its_scene_or_its_run():
    """A scene that outlives many runs (a test fixture, a notebook) keeps none of their BVHs alive."""
    class Built:
        pass

    scene = fakes.make_scene()
    runtime = Runtime(lambda scene, **options: Built())
    kept = weakref.ref(runtime.tracer(scene))
    del runtime
    gc.collect()
    assert kept() is None
    runtime = Runtime(lambda scene, **options: Built())
    kept = weakref.ref(runtime.tracer(scene))
    del scene
    gc.collect()
    assert kept() is None


def test_the_chunk_runner_traces_on_the_run_s_tracer():
    built = []
    runtime = Runtime(counting_factory(built))
    assert isinstance(runtime.chunks, InProcess)
    scene = fakes.make_scene()
    chunks = runtime.scene_chunks(scene)
    assert built == []  # nothing is built until a chunk needs it
    assert chunks.map(lambda tracer, first, items: (tracer, first, items), ([1, 2],)) == \
        (runtime.tracer(scene), 0, [1, 2])
    assert len(built) == 1


def test_a_runtime_builds_one_tracer_per_scene_and_keeps_its_threads():
    """Two runs on one scene each build their own BVH with their own threads; neither changes the other's
    (the shared tracer of old took the thread count of whichever run asked last)."""
    scene, other = fakes.make_scene(), fakes.make_scene()
    one, two = Runtime(Tracer.from_scene, threads=1), Runtime(Tracer.from_scene, threads=2)
    first = one.tracer(scene)
    assert two.tracer(scene).threads == 2 and two.tracer(scene) is not first
    assert one.tracer(scene) is first and first.threads == 1
    assert one.tracer(other) is not first


@pytest.mark.parametrize("threads", [0, -2, 1.5, "4", True])
def test_every_core_is_written_none(threads):
    assert Runtime(Tracer.from_scene).threads is None
    with pytest.raises(core.UsageError) as raised:
        Runtime(Tracer.from_scene, threads=threads)
    assert str(raised.value) == f"threads={threads!r}: expected a whole number of at least 1"
