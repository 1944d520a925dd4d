"""Batches of stages (usdbake.farm.batch): the same bytes as baking one by one, on a local pool and
on a Dask cluster; failures (bad input, a worker that dies, an unreachable scheduler) stay the
failing stage's own, or are one line before any work."""

from __future__ import annotations

import importlib
import os
import shutil
import sys
import textwrap

import pytest

from pxr import Sdf

import fake_processors
from repo_paths import SAMPLES
from usdbake.cli.main import main
from usdbake.core.errors import UsageError
from usdbake.farm import batch as batch_module
from usdbake.farm import cluster as cluster_module
from usdbake.farm.batch import FAILED, UP_TO_DATE, WORKER_DIED, bake_many, batch_outputs, expand_inputs
from usdbake.stages.bake_file import bake_file
from usdbake.stages.provenance import PROVENANCE_KEY
from usdbake.core.pipeline import Pipeline
from usdbake.core.runtime import Runtime
from usdbake.kernels.tracer import Tracer

STAGES = ("cornell_box", "city_block", "window_room")
PARAMS = {"ambient_occlusion": {"samples": 16}}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """Copies of three samples in a folder of their own (outputs beside them are the test's own)."""
    folder = tmp_path_factory.mktemp("stages")
    for name in STAGES:
        shutil.copy(SAMPLES / f"{name}.usda", folder / f"{name}.usda")
    return [str(folder / f"{name}.usda") for name in STAGES]


def without_timings(value):
    """Provenance with every 'seconds' entry dropped (the one part of a bake that differs run to run)."""
    if isinstance(value, dict):
        return {key: without_timings(item) for key, item in value.items() if key != "seconds"}
    if isinstance(value, (list, tuple)):
        return [without_timings(item) for item in value]
    return value


def layer_text(path: str) -> tuple[str, dict]:
    """A bake layer's opinions as usda text, and its provenance without timings."""
    layer = Sdf.Layer.FindOrOpen(path)
    layer.Reload(force=True)
    copy = Sdf.Layer.CreateAnonymous(".usda")
    copy.TransferContent(layer)
    provenance = dict(copy.customLayerData).get(PROVENANCE_KEY, {})
    copy.customLayerData = {}
    return copy.ExportToString(), without_timings(dict(provenance))


def serial_bakes(inputs, folder):
    for path, output in zip(inputs, batch_outputs(inputs, str(folder))):
        bake_file(path, output, Pipeline.build(["ambient_occlusion"], PARAMS, runtime=Runtime(Tracer.from_scene)))
    return [layer_text(output) for output in batch_outputs(inputs, str(folder))]


@pytest.fixture(scope="module")
def serial(inputs, tmp_path_factory):
    return serial_bakes(inputs, tmp_path_factory.mktemp("serial") / "out")  # as deep as tmp_path / "out"


def test_batch_on_a_local_pool_equals_baking_one_by_one(inputs, serial, tmp_path):
    outcomes = bake_many(inputs, str(tmp_path / "out"), processors=["ambient_occlusion"], params=PARAMS, workers=2)
    assert [o.status for o in outcomes] == ["baked"] * 3, [o.error for o in outcomes]
    assert [layer_text(o.output) for o in outcomes] == serial


def test_batch_on_a_dask_cluster_equals_baking_one_by_one_and_shares_the_cache(inputs, serial, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        options = dict(processors=["ambient_occlusion"], params=PARAMS, scheduler=cluster.scheduler_address,
                       cache_dir=str(tmp_path / "cache"))
        first = bake_many(inputs, str(tmp_path / "out"), **options)
        again = bake_many(inputs, str(tmp_path / "again"), **options)
    assert [o.status for o in first] == ["baked"] * 3, [o.error for o in first]
    assert [layer_text(o.output) for o in first] == serial
    assert [o.status for o in again] == [UP_TO_DATE] * 3  # whichever worker takes a stage reads the shared cache
    assert [layer_text(o.output)[0] for o in again] == [text for text, _ in serial]


def test_a_failing_stage_never_stops_the_others(inputs, tmp_path, capsys):
    broken = tmp_path / "broken.usda"
    broken.write_text("#usda 1.0\n(\n  this is not usda\n")
    missing = tmp_path / "missing.usda"
    code = main(["bake", inputs[0], str(broken), str(missing), "-o", str(tmp_path / "out") + "/",
                 "--set", "ambient_occlusion.samples=16", "--workers", "2", "--cache", str(tmp_path / "cache")])
    err = capsys.readouterr().err
    assert code == 1
    assert "2 failed" in err and "1 of 3 stages baked" in err
    assert (tmp_path / "out" / "cornell_box.baked.usdc").exists()
    assert not (tmp_path / "out" / "broken.baked.usdc").exists()
    assert sorted(os.listdir(tmp_path / "out")) == ["cornell_box.baked.usdc"]  # no partial or temporary files
    outcomes = bake_many([str(broken), str(missing)], str(tmp_path / "out2"), processors=["ambient_occlusion"],
                         params=PARAMS, workers=1)
    assert [o.status for o in outcomes] == [FAILED, FAILED]
    assert "cannot be read as USD" in outcomes[0].error and "no such file" in outcomes[1].error


def test_a_shared_config_table_for_a_processor_not_run_is_a_warning_in_a_batch_too(inputs, tmp_path, capsys):
    """The batch leaves the table out, as one stage does, instead of failing every stage."""
    config = tmp_path / "studio.toml"
    config.write_text("[radiosity]\ngather_rays = 16\n\n[ambient_occlusion]\nsamples = 16\n")
    code = main(["bake", inputs[0], "-o", str(tmp_path / "out") + "/", "--config", str(config), "--workers", "1",
                 "--cache", str(tmp_path / "cache")])
    err = capsys.readouterr().err
    assert code == 0, err
    assert f"warning: {config}: [radiosity] is ignored: radiosity is not part of this run (ambient_occlusion)" in err
    assert "1 of 1 stages baked" in err


CRASH_PLUGIN = """
    import os

    from usdbake.core import Processor, Result


    class CrashWorker(Processor):
        '''Test plugin: ends its process at once on a stage with a prim named Crash (as an OOM kill would).'''

        name = "crash_worker"
        summary = "kills its process on stages with a /World/Crash prim"

        def run(self, ctx):
            if any(path.endswith("/Crash") for path in ctx.scene.prim_paths):
                os._exit(9)
            return Result()
"""


@pytest.fixture
def crash_plugin(tmp_path, monkeypatch):
    """A processor plugin found through its entry point in this process and in every worker process."""
    folder = tmp_path / "plugin"
    (folder / "crash_plugin-1.0.dist-info").mkdir(parents=True)
    (folder / "crash_plugin.py").write_text(textwrap.dedent(CRASH_PLUGIN))
    (folder / "crash_plugin-1.0.dist-info" / "METADATA").write_text("Metadata-Version: 2.1\nName: crash-plugin\n"
                                                                     "Version: 1.0\n")
    (folder / "crash_plugin-1.0.dist-info" / "entry_points.txt").write_text(
        "[usdbake.processors]\ncrash_worker = crash_plugin:CrashWorker\n")
    monkeypatch.syspath_prepend(str(folder))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(folder), os.environ.get("PYTHONPATH")])))
    importlib.invalidate_caches()
    yield
    sys.modules.pop("crash_plugin", None)


@pytest.fixture
def crashing_stage(tmp_path):
    path = fake_processors.write_stage(tmp_path / "crashing.usda")
    layer = Sdf.Layer.FindOrOpen(path)
    assert Sdf.CopySpec(layer, "/World/Cube", layer, "/World/Crash")
    layer.Save()
    return path


def test_a_stage_that_kills_its_pool_worker_is_reported_by_name(inputs, crash_plugin, crashing_stage, tmp_path):
    outcomes = bake_many([inputs[0], crashing_stage], str(tmp_path / "out"),
                         processors=["ambient_occlusion", "crash_worker"], params=PARAMS, workers=2)
    assert outcomes[0].status == "baked", outcomes[0].error
    assert (outcomes[1].status, outcomes[1].error) == (FAILED, WORKER_DIED)
    assert sorted(os.listdir(tmp_path / "out")) == ["cornell_box.baked.usdc"]


def test_a_stage_that_kills_its_dask_worker_is_reported_by_name(inputs, crash_plugin, crashing_stage, tmp_path):
    distributed = pytest.importorskip("distributed")
    import dask

    # Dask re-runs a task whose worker died (allowed-failures times) before it gives up with KilledWorker.
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}), \
            distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                     dashboard_address=None) as cluster:
        outcomes = bake_many([inputs[0], crashing_stage], str(tmp_path / "out"),
                             processors=["ambient_occlusion", "crash_worker"], params=PARAMS,
                             scheduler=cluster.scheduler_address)
    assert outcomes[0].status == "baked", outcomes[0].error
    assert (outcomes[1].status, outcomes[1].error) == (FAILED, WORKER_DIED)


def test_an_unreachable_scheduler_is_one_line_before_any_work(inputs, tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setattr(cluster_module, "CONNECT_TIMEOUT", 1.0)
    for extra in ([], [inputs[1]]):  # one stage (chunks) and a batch
        code = main(["bake", inputs[0], *extra, "-o", str(tmp_path / "out") + ("/" if extra else ".usdc"),
                     "--scheduler", "tcp://127.0.0.1:9"])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2
        assert len(err) == 1 and "cannot reach the Dask scheduler" in err[0] and "tcp://127.0.0.1:9" in err[0]
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.usdc").exists()


def test_scheduler_without_dask_says_how_to_install_it(inputs, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    assert main(["bake", inputs[0], "--scheduler", "tcp://127.0.0.1:8786"]) == 2
    assert "pip install -e \".[distributed]\"" in capsys.readouterr().err


def test_inputs_from_globs_and_list_files(inputs, tmp_path):
    folder = os.path.dirname(inputs[0])
    assert expand_inputs([os.path.join(folder, "c*.usda")]) == sorted(inputs[:2])
    listing = tmp_path / "stages.txt"
    listing.write_text(f"# stages to bake\n{inputs[2]}\n\n{os.path.relpath(inputs[0], tmp_path)}\n")
    assert expand_inputs([], str(listing)) == [inputs[2], str(tmp_path / os.path.relpath(inputs[0], tmp_path))]
    with pytest.raises(UsageError, match="matches no file"):
        expand_inputs([os.path.join(folder, "nothing*.usda")])
    with pytest.raises(UsageError, match="would both write"):
        batch_outputs([inputs[0], str(tmp_path / "cornell_box.usda")], str(tmp_path / "out"))


def test_bad_params_are_refused_before_any_stage_runs(inputs, tmp_path):
    with pytest.raises(UsageError):
        bake_many(inputs, str(tmp_path), processors=["ambient_occlusion"], params={"ambient_occlusion": {"bogus": 1}})
    with pytest.raises(UsageError, match="not part of this run"):
        bake_many(inputs, str(tmp_path), processors=["ambient_occlusion"], params={"light_probes": {"probes": 8}})
    with pytest.raises(UsageError, match="threads=0: expected a whole number of at least 1"):
        bake_many(inputs, str(tmp_path), processors=["ambient_occlusion"], threads=0)  # every core is None
    assert not any(name.endswith(".usdc") for name in os.listdir(tmp_path))
    assert batch_module.BAKED == "baked"
