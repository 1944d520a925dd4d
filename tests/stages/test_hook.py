"""The Python hook: usdbake.bake(stage, ...) on an open, possibly never-saved stage,
and third-party processors found through the 'usdbake.processors' entry points."""

import sys
from pathlib import Path
import tempfile
import textwrap

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom

import fake_processors as fakes
import usdbake
from usdbake import core
from usdbake.stages.bake_file import READING
from usdbake.stages.hook import last_report
from usdbake.core.pipeline import Pipeline
from usdbake.core.runtime import Runtime
from usdbake.kernels.tracer import Tracer

AO_FAST = {"ambient_occlusion": {"samples": 16}}


@pytest.fixture
def stage():
    return fakes.build_stage(Usd.Stage.CreateInMemory())


def ao_values(stage, path):
    primvar = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(path)).GetPrimvar("bake:ao")
    return primvar.Get() if primvar else None


def test_bake_in_memory_stage_into_a_session_sublayer(stage, cache, tmp_path, monkeypatch):
    # Point tempfile at an empty folder: a bake without textures must create nothing there.
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))

    root_before = stage.GetRootLayer().ExportToString()
    layer = usdbake.bake(stage, processors=["ambient_occlusion"], params=AO_FAST, cache_dir=cache)

    assert layer.anonymous
    assert list(stage.GetSessionLayer().subLayerPaths) == [layer.identifier]
    assert stage.GetRootLayer().ExportToString() == root_before
    assert len(ao_values(stage, "/World/Ground")) == fakes.GROUND_POINTS
    assert len(ao_values(stage, "/World/Cube")) == fakes.CUBE_POINTS
    provenance = dict(layer.customLayerData)["usdbake"]
    assert provenance["processors"]["ambient_occlusion"]["params"]["samples"] == 16
    assert "pending" not in provenance
    assert [row["action"] for row in last_report(layer)] == ["run"]
    assert list(scratch.iterdir()) == []


def test_second_bake_reuses_the_layer_without_duplicating(stage, cache):
    first = usdbake.bake(stage, params=AO_FAST, cache_dir=cache)
    values = list(ao_values(stage, "/World/Cube"))
    second = usdbake.bake(stage, params=AO_FAST, cache_dir=cache)

    assert second.identifier == first.identifier
    assert list(stage.GetSessionLayer().subLayerPaths) == [first.identifier]
    # Earlier results are not read back as input: the unchanged stage is up to date.
    assert [row["action"] for row in last_report(second)] == ["cached"]
    assert list(ao_values(stage, "/World/Cube")) == values
    assert sorted(prim.name for prim in second.GetPrimAtPath("/World").nameChildren) == ["Cube", "Ground"]

    # A changed param replaces the values in the same layer.
    third = usdbake.bake(stage, params={"ambient_occlusion": {"samples": 16, "seed": 5}}, cache_dir=cache)
    assert third.identifier == first.identifier
    assert list(stage.GetSessionLayer().subLayerPaths) == [first.identifier]
    assert [row["action"] for row in last_report(third)] == ["run"]
    assert len(ao_values(stage, "/World/Cube")) == fakes.CUBE_POINTS


def test_bake_into_a_given_layer(stage, cache):
    target = Sdf.Layer.CreateAnonymous()
    returned = usdbake.bake(stage, params=AO_FAST, cache_dir=cache, layer=target)
    assert returned.identifier == target.identifier
    assert list(stage.GetSessionLayer().subLayerPaths) == []  # nothing inserted into the stage
    spec = target.GetAttributeAtPath("/World/Ground.primvars:bake:ao")
    assert spec is not None and len(spec.default) == fakes.GROUND_POINTS
    assert spec.GetInfo("interpolation") == "vertex"
    assert ao_values(stage, "/World/Ground") is None  # the stage does not see a layer it does not hold


def test_progress_hears_the_reading_then_each_processor(stage, cache):
    heard = []
    usdbake.bake(stage, params=AO_FAST, cache_dir=cache, on_progress=lambda name, f: heard.append((name, f)))
    assert heard[:2] == [(READING, 0.0), (READING, 1.0)]  # the same sequence as the file bake (compute_outputs)
    assert ("ambient_occlusion", 1.0) in heard[2:]


def test_failed_bake_authors_nothing(stage, cache, monkeypatch):
    from usdbake.processors.occlusion.ambient_occlusion import AmbientOcclusion
    from usdbake.core.pipeline import ProcessorFailed

    def boom(self, ctx):
        raise RuntimeError("kaboom")

    monkeypatch.setattr(AmbientOcclusion, "run", boom)
    with pytest.raises(ProcessorFailed, match="ambient_occlusion"):
        usdbake.bake(stage, params=AO_FAST, cache_dir=cache, force=True)
    assert list(stage.GetSessionLayer().subLayerPaths) == []
    assert ao_values(stage, "/World/Ground") is None


# ---------------------------------------------------------------------------
# Entry points

PLUGIN = '''
import numpy as np

from usdbake.core import Primvar, Processor, Result


class FakeProcessor(Processor):
    name = "fake_ep"
    summary = "a processor from another distribution"
    writes = ("primvars:bake:ep",)

    def run(self, ctx):
        scene = ctx.scene
        result = Result()
        for prim, path in enumerate(scene.prim_paths):
            values = np.full(scene.prim_points(prim).stop - scene.prim_points(prim).start, 0.25, np.float32)
            result.outputs.append(Primvar(path, "bake:ep", values, "float", "vertex"))
        return result
'''


@pytest.fixture
def fake_distribution(tmp_path, monkeypatch):
    """A 'fakeplugin' distribution on sys.path that declares fake_ep in the usdbake.processors group."""
    site = tmp_path / "site"
    info = site / "fakeplugin-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: fakeplugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[usdbake.processors]\nfake_ep = fakeplugin_mod:FakeProcessor\n")
    (site / "fakeplugin_mod.py").write_text(textwrap.dedent(PLUGIN))
    monkeypatch.syspath_prepend(str(site))
    yield site
    core.registry.unregister("fake_ep")
    sys.modules.pop("fakeplugin_mod", None)


def test_processor_from_an_entry_point(fake_distribution, stage, cache):
    assert "fake_ep" in list(core.registry.plugins())
    cls = core.registry.get("fake_ep")
    assert cls.__module__ == "fakeplugin_mod" and issubclass(cls, core.Processor)

    steps = Pipeline.build(["fake_ep"], runtime=Runtime(Tracer.from_scene), cache_dir=cache).run(fakes.make_scene())
    assert [(step.name, step.action) for step in steps] == [("fake_ep", "run")]
    records = steps[0].result.outputs
    assert len(records) == 1 and isinstance(records[0], core.Primvar)
    np.testing.assert_array_equal(records[0].values, np.full(4, 0.25, np.float32))

    # And end to end through the hook: the plugin's primvar appears on the stage.
    usdbake.bake(stage, processors=["fake_ep"], cache_dir=cache)
    primvar = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Cube")).GetPrimvar("bake:ep")
    assert list(primvar.Get()) == [0.25] * fakes.CUBE_POINTS


def test_entry_point_that_is_not_a_processor_is_rejected(tmp_path, monkeypatch):
    site = tmp_path / "site"
    info = site / "badplugin-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: badplugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[usdbake.processors]\nbad_ep = badplugin_mod:not_a_class\n")
    (site / "badplugin_mod.py").write_text("def not_a_class():\n    pass\n")
    monkeypatch.syspath_prepend(str(site))
    try:
        with pytest.raises(TypeError, match="bad_ep"):
            list(core.registry.plugins())
    finally:
        sys.modules.pop("badplugin_mod", None)


def test_file_outputs_of_an_unsaved_stage_go_to_a_temp_folder_not_the_cwd(tmp_path, monkeypatch):
    """Radiosity writes a .dds and a sparse .npz (File records); an in-memory stage has no folder."""
    from pxr import UsdLux

    monkeypatch.chdir(tmp_path)
    stage = Usd.Stage.CreateInMemory()
    fakes.build_stage(stage)
    UsdLux.DistantLight.Define(stage, "/World/sun")
    layer = usdbake.bake(stage, processors=["form_factors"], params={"form_factors": {"rays": 16}},
                         cache_dir=str(tmp_path / "cache"))
    assert not any(p.suffix in (".dds", ".npz") for p in tmp_path.iterdir())
    matrix = stage.GetPrimAtPath("/usdbake/RadiosityPatches").GetAttribute("matrixFile").Get()
    assert matrix is not None and Path(matrix.resolvedPath or matrix.path).suffix == ".dds"
    assert layer is not None


@pytest.mark.parametrize("threads", [0, -2, 1.5, "4"])
def test_bad_thread_count_is_refused_before_any_work(threads):
    stage = Usd.Stage.CreateInMemory()
    with pytest.raises(ValueError, match=r"threads=.*at least 1"):
        usdbake.bake(stage, ["ambient_occlusion"], threads=threads)
    assert not stage.GetSessionLayer().subLayerPaths  # nothing authored


def test_threads_reach_the_ray_core(monkeypatch):
    """The hook's threads= is the thread count of the tracer the processors share."""
    seen = []
    original = Tracer.from_scene
    monkeypatch.setattr(Tracer, "from_scene",
                        lambda scene, **kwargs: seen.append(kwargs.get("threads")) or original(scene, **kwargs))
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.Cube.Define(stage, "/Box")
    mesh = UsdGeom.Mesh.Define(stage, "/Floor")
    mesh.CreatePointsAttr([(-2, -1, -2), (2, -1, -2), (2, -1, 2), (-2, -1, 2)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
    usdbake.bake(stage, ["ambient_occlusion"], {"ambient_occlusion": {"samples": 4}}, threads=2, force=True)
    assert seen and set(seen) == {2}
