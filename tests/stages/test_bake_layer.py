"""Non-destructive output: the bake layer sublayers the untouched input, holds only
bake: opinions with provenance, is saved atomically and never nests on re-bake."""

import errno
import hashlib
import json
import os
from pathlib import Path

import pytest
from pxr import Sdf, Usd, UsdGeom, UsdShade

import fake_processors as fakes
import usdbake
from usdbake.processors.occlusion.ambient_occlusion import AmbientOcclusion
from usdbake.core import OutputError
from usdbake.stages import bake_layer
from usdbake.cli.main import main

FAST = ["--set", "ambient_occlusion.samples=16"]


def digest(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def bake(*argv, cache) -> int:
    return main(["bake", *map(str, argv), "--cache", cache, *FAST])


def bake_json(capsys, *argv, cache) -> dict:
    capsys.readouterr()
    assert bake(*argv, "--json", cache=cache) == 0
    return json.loads(capsys.readouterr().out)


def authored_properties(layer: Sdf.Layer) -> list[Sdf.AttributeSpec]:
    found = []

    def visit(path):
        if path.IsPropertyPath():
            spec = layer.GetAttributeAtPath(path)
            if spec is not None:
                found.append(spec)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return found


def test_bake_writes_a_layer_over_the_untouched_input(tmp_path, stage_in, cache):
    before = digest(stage_in)
    out = tmp_path / "out.usda"
    assert bake(stage_in, "-o", out, cache=cache) == 0
    assert digest(stage_in) == before

    layer = Sdf.Layer.OpenAsAnonymous(str(out))  # a fresh read of what is on disk
    assert list(layer.subLayerPaths) == ["in.usda"]  # relative to the output's folder

    specs = authored_properties(layer)
    assert {str(spec.path) for spec in specs} == {"/World/Ground.primvars:bake:ao", "/World/Cube.primvars:bake:ao"}
    for spec in specs:
        assert spec.name.startswith("primvars:bake:")
        assert spec.HasInfo("interpolation") and spec.GetInfo("interpolation") == "vertex"
        assert spec.HasInfo("elementSize") and spec.GetInfo("elementSize") == 1

    provenance = dict(layer.customLayerData)["usdbake"]
    assert provenance["version"] == usdbake.__version__
    assert provenance["device"] == "cpu"
    assert provenance["source"] == "in.usda"
    ao = provenance["processors"]["ambient_occlusion"]
    assert ao["params"]["samples"] == 16
    assert len(ao["fingerprint"]) == 32
    assert isinstance(ao["seconds"], float) and ao["seconds"] >= 0.0
    assert ao["action"] == "run"

    stage = Usd.Stage.Open(str(out))
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/World")
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    for path, count in (("/World/Ground", fakes.GROUND_POINTS), ("/World/Cube", fakes.CUBE_POINTS)):
        primvar = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(path)).GetPrimvar("bake:ao")
        assert primvar and primvar.GetInterpolation() == UsdGeom.Tokens.vertex
        values = primvar.Get()
        assert len(values) == count
        assert all(0.0 <= v <= 1.0 for v in values)
    # The cube stands on the ground: some ground vertex near it is occluded.
    assert min(UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Cube")).GetPrimvar("bake:ao").Get()) < 1.0


def test_default_output_is_beside_the_input(tmp_path, stage_in, cache):
    assert bake(stage_in, cache=cache) == 0
    out = tmp_path / "in.baked.usdc"
    assert out.exists()
    assert list(Sdf.Layer.OpenAsAnonymous(str(out)).subLayerPaths) == ["in.usda"]


def test_rebake_unchanged_is_up_to_date_and_a_param_change_reruns(tmp_path, stage_in, cache, capsys,
                                                                   monkeypatch):
    calls = []
    original = AmbientOcclusion.run
    monkeypatch.setattr(AmbientOcclusion, "run", lambda self, ctx: calls.append(1) or original(self, ctx))
    out = tmp_path / "out.usda"

    first = bake_json(capsys, stage_in, "-o", out, cache=cache)
    assert [s["action"] for s in first["steps"]] == ["run"] and len(calls) == 1

    second = bake_json(capsys, stage_in, "-o", out, cache=cache)
    assert second["steps"][0]["action"] == "cached"
    assert second["steps"][0]["reason"].startswith("up to date")
    assert len(calls) == 1
    assert second["steps"][0]["fingerprint"] == first["steps"][0]["fingerprint"]

    third = bake_json(capsys, stage_in, "-o", out, "--set", "ambient_occlusion.seed=7", cache=cache)
    assert third["steps"][0]["action"] == "run" and len(calls) == 2
    assert third["steps"][0]["fingerprint"] != first["steps"][0]["fingerprint"]


@pytest.mark.parametrize("same_output", [False, True], ids=["no -o", "-o OUT"])
def test_rebaking_the_output_does_not_nest(tmp_path, stage_in, cache, same_output):
    out = tmp_path / "out.usda"
    assert bake(stage_in, "-o", out, cache=cache) == 0
    first = Sdf.Layer.OpenAsAnonymous(str(out))
    before = sorted(str(spec.path) for spec in authored_properties(first))
    for seed in ("1", "2"):  # twice, and with a change, so a nested or stale result would show
        argv = [out, "-o", out] if same_output else [out]
        assert main(["bake", *map(str, argv), "--cache", cache, *FAST,
                     "--set", f"ambient_occlusion.seed={seed}"]) == 0
    layer = Sdf.Layer.OpenAsAnonymous(str(out))
    assert list(layer.subLayerPaths) == ["in.usda"]
    assert sorted(str(spec.path) for spec in authored_properties(layer)) == before
    provenance = dict(layer.customLayerData)["usdbake"]
    assert provenance["source"] == "in.usda"
    assert provenance["processors"]["ambient_occlusion"]["params"]["seed"] == 2
    # No other layer appeared beside the input and the output.
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_file()) == ["in.usda", "out.usda"]
    # The composed stage reads the input once, through one sublayer.
    stage = Usd.Stage.Open(str(out))
    assert [Path(l.realPath).name for l in stage.GetLayerStack(includeSessionLayers=False)] == ["out.usda", "in.usda"]


def test_refuses_to_overwrite_the_input(stage_in, cache, capsys):
    before = digest(stage_in)
    assert bake(stage_in, "-o", stage_in, cache=cache) == 2
    assert "refusing to overwrite the input" in capsys.readouterr().err
    assert digest(stage_in) == before


def test_failing_processor_leaves_existing_output_untouched(tmp_path, stage_in, cache, capsys, monkeypatch):
    out = tmp_path / "out.usda"
    assert bake(stage_in, "-o", out, cache=cache) == 0
    before = digest(out)

    def boom(self, ctx):
        raise RuntimeError("simulated kernel failure")

    monkeypatch.setattr(AmbientOcclusion, "run", boom)
    capsys.readouterr()
    assert bake(stage_in, "-o", out, "--force", cache=cache) == 1
    err = capsys.readouterr().err
    assert "ambient_occlusion" in err and "simulated kernel failure" in err and "Traceback" not in err
    assert digest(out) == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_file()) == ["in.usda", "out.usda"]


def test_atomic_save_leaves_no_temp_files(tmp_path, stage_in, cache):
    outdir = tmp_path / "baked"
    assert bake(stage_in, "-o", outdir / "out.usdc", cache=cache) == 0
    assert [p.name for p in outdir.iterdir()] == ["out.usdc"]
    assert list(Sdf.Layer.OpenAsAnonymous(str(outdir / "out.usdc")).subLayerPaths) == ["../in.usda"]


def test_save_that_fails_midway_leaves_no_temp_and_no_output(tmp_path, stage_in, monkeypatch):
    def broken_author(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(bake_layer, "author", broken_author)
    out = tmp_path / "out.usda"
    with pytest.raises(OutputError) as raised:
        bake_layer.save_atomically(str(out), stage_in, [], {"version": "test"})
    assert str(raised.value) == (f"{out}: could not be written (No space left on device); the previous output "
                                 f"is unchanged")
    assert sorted(os.listdir(tmp_path)) == ["in.usda"]


def test_connect_occlusion_wires_a_primvar_reader_into_the_preview_surface(tmp_path, cache):
    stage_in = fakes.write_stage(tmp_path / "in.usda", material=True)
    out = tmp_path / "out.usda"
    assert bake(stage_in, "-o", out, "--set", "ambient_occlusion.connect_occlusion=true", cache=cache) == 0

    stage = Usd.Stage.Open(str(out))
    for mesh in ("/World/Ground", "/World/Cube"):
        material, _ = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(mesh)).ComputeBoundMaterial()
        surface = material.ComputeSurfaceSource()[0]
        assert surface.GetIdAttr().Get() == "UsdPreviewSurface"
        sources, invalid = surface.GetInput("occlusion").GetConnectedSources()
        assert not invalid and len(sources) == 1
        reader = UsdShade.Shader(sources[0].source.GetPrim())
        assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float"
        assert sources[0].sourceName == "result" and sources[0].sourceType == UsdShade.AttributeType.Output
        assert reader.GetInput("varname").Get() == "bake:ao"
    # The input layer still has no occlusion input: the wiring lives in the bake layer only.
    source = Usd.Stage.Open(stage_in)
    assert not UsdShade.Shader(source.GetPrimAtPath("/World/Looks/Grey/Surface")).GetInput("occlusion")


def test_time_samples_widen_the_layer_time_range():
    """Time-sampled outputs (daylight over a day, instance AO per frame) set start/endTimeCode."""
    import numpy as np
    from pxr import Sdf

    from usdbake.core import Primvar
    from usdbake.stages.bake_layer import author

    layer = Sdf.Layer.CreateAnonymous()
    layer.startTimeCode, layer.endTimeCode = 1.0, 3.0  # copied from the source stage
    outputs = [Primvar("/World/m", "bake:daylight", np.ones((2, 3), np.float32), "color3f", "uniform", time=t)
               for t in (0.0, 1.0, 24.0)]
    author(layer, outputs, {"version": "test"})
    assert (layer.startTimeCode, layer.endTimeCode) == (0.0, 24.0)
    assert layer.GetNumTimeSamplesForPath("/World/m.primvars:bake:daylight") == 3


def test_primvars_that_do_not_fit_a_refined_mesh_are_refused():
    """AO computed on the original 4 points cannot sit on a mesh refined to 9 points."""
    import numpy as np
    import pytest
    from pxr import Sdf

    from usdbake.core import Attribute, Primvar
    from usdbake.stages.bake_layer import author
    from usdbake.core.errors import UsageError

    refined = [Attribute("/World/m", "points", np.zeros((9, 3), np.float32), "point3f[]"),
               Attribute("/World/m", "faceVertexCounts", np.full(8, 3, np.int32), "int[]")]
    fitting = Primvar("/World/m", "bake:skyExposure", np.ones(8, np.float32), "float", "uniform")
    stale = Primvar("/World/m", "bake:ao", np.ones(4, np.float32), "float", "vertex")
    layer = Sdf.Layer.CreateAnonymous()
    author(layer, refined + [fitting], {"version": "test"})  # consistent: accepted
    other = Sdf.Layer.CreateAnonymous()
    with pytest.raises(UsageError, match=r"/World/m\.primvars:bake:ao: 4 vertex values.*9"):
        author(other, refined + [fitting, stale], {"version": "test"})
    assert not other.rootPrims  # nothing authored
