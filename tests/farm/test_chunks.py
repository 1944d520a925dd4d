"""A scene's receiver work as Dask tasks (usdbake.farm.chunks) equals the in-process bake bit for bit:
for 1, 2 and 3 workers, odd chunk sizes, and a worker killed in the middle of a task."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

pytest.importorskip("distributed")
from distributed import Client, LocalCluster  # noqa: E402

from pxr import Usd  # noqa: E402

from repo_paths import SAMPLES  # noqa: E402
from usdbake.core.pipeline import Pipeline  # noqa: E402
from usdbake.core.runtime import Runtime  # noqa: E402
from usdbake.farm.chunks import DaskChunks  # noqa: E402
from usdbake.kernels.tracer import Tracer  # noqa: E402
from usdbake.stages.extract import extract_scene  # noqa: E402

PROCESSORS = ["ambient_occlusion", "sky_visibility"]
PARAMS = {"ambient_occlusion": {"samples": 16, "per_face": True},
          "sky_visibility": {"patch_count": 32, "max_level": 2}}
"""Cheap settings: each refinement pass and both AO kernels still run as several chunks."""


def bake_outputs(scene, chunks=None, processors=PROCESSORS, params=PARAMS):
    pipeline = Pipeline.build(processors, params, runtime=Runtime(Tracer.from_scene, chunks=chunks))
    pipeline.run(scene)
    return pipeline.outputs()


def assert_same_outputs(expected, got):
    assert len(expected) == len(got)
    for want, have in zip(expected, got):
        assert type(want) is type(have)
        for name in want.__dataclass_fields__:
            a, b = getattr(want, name), getattr(have, name)
            if isinstance(a, np.ndarray):
                assert a.dtype == b.dtype and a.shape == b.shape, (want, name)
                assert np.array_equal(a, b), f"{getattr(want, 'prim', '')}.{getattr(want, 'name', '')}: {name} differs"
            else:
                assert a == b, (want, name)


@pytest.fixture(scope="module")
def city_block():
    return extract_scene(Usd.Stage.Open(str(SAMPLES / "city_block.usda")))


@pytest.fixture(scope="module")
def local_outputs(city_block):
    return bake_outputs(city_block)


@pytest.fixture(scope="module")
def cluster():
    with LocalCluster(n_workers=3, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster, set_as_default=False) as client:
        yield cluster, client


def scale_to(cluster, client, workers: int) -> None:
    cluster.scale(workers)
    deadline = time.monotonic() + 60
    while len(client.scheduler_info(n_workers=-1)["workers"]) != workers:
        assert time.monotonic() < deadline, "the cluster did not reach its size"
        time.sleep(0.1)


@pytest.mark.parametrize("workers, chunk_size", [(3, None), (3, 97), (2, 1001), (1, 333)])
def test_chunked_bake_equals_the_local_bake(cluster, city_block, local_outputs, workers, chunk_size):
    """Seeds come from global item indices, so any cut of the work gives the same bits (the runs go from
    3 workers down to 1: scaling down is quick, starting workers is not)."""
    scale_to(*cluster, workers)
    chunks = DaskChunks(cluster[1], chunk_size=chunk_size)
    assert_same_outputs(local_outputs, bake_outputs(city_block, chunks))
    # The scene went once to the workers per scene (the original, then the refined one AO runs on),
    # and every task carried only its own receivers.
    assert chunks.stats["scatters"] == 2
    assert chunks.stats["tasks"] > 3
    if chunk_size:  # AO alone sends one task per chunk_size points of the (refined) scene
        assert chunks.stats["tasks"] >= city_block.num_points // chunk_size


@pytest.mark.parametrize("processor, params, chunk_size", [
    ("form_factors", {"target_patches": 300, "rays": 64}, 37),  # rows of F
    ("irradiance_grid", {"vertices": 600, "rays": 16, "bounces": 2}, 71),  # grid vertices, both passes
    ("light_probes", {"probes": 64, "rays": 16, "placement_rays": 16, "iterations": 1}, 9),  # final capture
])
def test_capture_work_on_the_cluster_equals_the_local_work(cluster, processor, params, chunk_size):
    """Form-factor rows and probe and grid captures by point ranges: each ray is seeded by its global
    index, whichever task computes it."""
    scene = extract_scene(Usd.Stage.Open(str(SAMPLES / "cornell_box.usda")))
    expected = bake_outputs(scene, processors=[processor], params={processor: params})
    scale_to(*cluster, 2)
    chunks = DaskChunks(cluster[1], chunk_size=chunk_size)
    assert_same_outputs(expected, bake_outputs(scene, chunks, processors=[processor], params={processor: params}))
    assert chunks.stats["tasks"] >= 4


def test_chunk_size_must_be_positive():
    with pytest.raises(ValueError, match="chunk_size=0"):
        DaskChunks(None, chunk_size=0)


def test_a_worker_killed_during_a_task_changes_nothing(city_block):
    """Dask re-runs the dead worker's tasks on the other one; the output is bit-identical."""
    params = {"ambient_occlusion": {"samples": 400}}
    expected = bake_outputs(city_block, processors=["ambient_occlusion"], params=params)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster, set_as_default=False) as client:
        pids = client.run(os.getpid)
        killed: list[str] = []

        def kill_a_busy_worker():
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline and not killed:
                busy = [address for address, keys in client.processing().items()
                        if any("vertex_ao_chunk" in str(key) for key in keys)]
                if busy:
                    time.sleep(0.3)  # well inside the task: each takes seconds
                    os.kill(pids[busy[0]], signal.SIGKILL)
                    killed.append(busy[0])
                time.sleep(0.02)

        killer = threading.Thread(target=kill_a_busy_worker, daemon=True)
        killer.start()
        got = bake_outputs(city_block, DaskChunks(client, chunk_size=1500), processors=["ambient_occlusion"],
                           params=params)
        killer.join(timeout=5)
    assert killed, "no worker was killed: the test did not exercise a failure"
    assert_same_outputs(expected, got)
