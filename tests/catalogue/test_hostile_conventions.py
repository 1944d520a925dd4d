"""Hostile and careless calls of the command and the hook (issue 27, items 8-11): each is one line
before any compute, with the exit code or exception type the docs give, and leaves its inputs as
they were. docs/reliability.md lists them."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from pxr import Sdf, Usd, UsdGeom

import usdbake
from usdbake.cli.main import main
from usdbake.core import ParamError, UsageError

SAMPLES = Path(__file__).resolve().parents[2] / "samples"


def digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def run(capsys, *argv) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def last_line(text: str) -> str:
    return text.strip().splitlines()[-1]


def floor_stage(path: Path, *, animated: bool = False) -> Path:
    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, "/World/Floor")
    corners = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    if animated:
        mesh.CreatePointsAttr().Set(corners, 1)
        mesh.GetPointsAttr().Set(corners, 24)
    else:
        mesh.CreatePointsAttr(corners)
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    stage.SetDefaultPrim(stage.GetPrimAtPath("/World"))
    stage.Save()
    return path


NO_LIGHT_FIX = ("add a sky and sun with 'usdbake sky STAGE -o STAGE.sky.usda' and bake that layer, or add a "
                "UsdLux DomeLight, a DistantLight or an emissive material")


# ---------------------------------------------------------------------------
# Conventions: tables on stdout, diagnostics on stderr


def test_list_prints_its_tables_on_stdout(capsys):
    code, out, err = run(capsys, "list")
    assert code == 0 and err == ""
    assert any("weather" in line for line in out.splitlines())  # `usdbake list | grep weather` finds it


def test_plan_without_processors_reports_no_conflict_nobody_asked_for(capsys):
    code, out, err = run(capsys, "plan", SAMPLES / "cornell_box.usda")
    assert code == 0 and "conflict" not in err and "ambient_occlusion" in out
    code, out, err = run(capsys, "plan", SAMPLES / "cornell_box.usda", "-p", "ambient_occlusion", "-p", "instance_ao")
    assert "conflict: ambient_occlusion and instance_ao both write primvars:bake:ao; run one of them" in err


@pytest.mark.parametrize("processor", ["radiosity", "light_probes", "irradiance_grid"])
def test_a_processor_that_does_not_apply_exits_2_naming_the_fix(capsys, tmp_path, processor):
    """One exit code (2) whenever nothing asked for applies; the dependencies of a skipped processor
    (form_factors under radiosity) do not run."""
    source = floor_stage(tmp_path / "unlit.usda")
    before = digest(source)
    code, out, err = run(capsys, "bake", source, "-o", tmp_path / "out.usdc", "-p", processor)
    assert code == 2 and not (tmp_path / "out.usdc").exists() and digest(source) == before
    line = last_line(err)
    assert line.startswith("usdbake: error: nothing to bake: ") and NO_LIGHT_FIX in line
    assert ("form_factors skipped (needed only by radiosity (skipped))" in line) == (processor == "radiosity")


def test_a_skipped_processor_beside_one_that_runs_is_exit_0_with_the_reason_recorded(capsys, tmp_path):
    source = floor_stage(tmp_path / "unlit.usda")
    out_path = tmp_path / "out.usda"
    code, out, err = run(capsys, "bake", source, "-o", out_path, "-p", "ambient_occlusion", "-p", "radiosity",
                         "--set", "ambient_occlusion.samples=16")
    assert code == 0, err
    processors = dict(Sdf.Layer.OpenAsAnonymous(str(out_path)).customLayerData)["usdbake"]["processors"]
    assert processors["radiosity"]["action"] == "skip" and NO_LIGHT_FIX in processors["radiosity"]["reason"]
    assert processors["form_factors"]["action"] == "skip"


# ---------------------------------------------------------------------------
# usdbake sky: values checked as arguments


@pytest.mark.parametrize("argv, line", [
    (["--time", "2026-13-45T99:00"],
     "usdbake: error: argument --time: '2026-13-45T99:00' is not an ISO 8601 date-time like 2026-06-21T12:00"),
    (["--model", "perez", "--dni", "-500", "--dhi", "100"], "usdbake: error: argument --dni: -500 is outside 0..1500"),
    (["--model", "perez", "--dni", "500", "--dhi", "nan"], "usdbake: error: argument --dhi: nan is outside 0..1000"),
    (["--latitude", "inf"], "usdbake: error: argument --latitude: inf is outside -90..90"),
    (["--ground-albedo", "two"], "usdbake: error: argument --ground-albedo: 'two' is not a number"),
], ids=["month-13", "negative-dni", "nan-dhi", "infinite-latitude", "albedo-text"])
def test_sky_refuses_impossible_values(capsys, tmp_path, argv, line):
    source = tmp_path / "box.usda"
    source.write_bytes((SAMPLES / "cornell_box.usda").read_bytes())
    code, out, err = run(capsys, "sky", source, "-o", tmp_path / "sky.usda", *argv)
    assert (code, last_line(err)) == (2, line)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["box.usda"]


# ---------------------------------------------------------------------------
# Messages that name the fix


def test_time_sampled_points_without_time_name_the_frames(capsys, tmp_path):
    source = floor_stage(tmp_path / "anim.usda", animated=True)
    code, out, err = run(capsys, "bake", source, "-o", tmp_path / "out.usdc")
    assert (code, last_line(err)) == (2, "usdbake: error: /World/Floor.points: has 2 time samples (1..24) and no "
                                         "default value; bake one frame with --time T (hook: time=T)")
    code, out, err = run(capsys, "bake", source, "-o", tmp_path / "out.usdc", "--time", "1",
                         "--set", "ambient_occlusion.samples=16")
    assert code == 0, err


def test_error_lines_print_plain_numbers(capsys, tmp_path):
    source = floor_stage(tmp_path / "nan.usda")
    stage = Usd.Stage.Open(str(source))
    UsdGeom.Mesh.Get(stage, "/World/Floor").GetPointsAttr().Set([(0, 0, 0), (1, 0, 0), (1, float("nan"), 0), (0, 1, 0)])
    stage.Save()
    code, out, err = run(capsys, "bake", source, "-o", tmp_path / "out.usdc")
    assert (code, last_line(err)) == (2, "usdbake: error: /World/Floor.points: point 2 is (1.0, nan, 0.0) "
                                         "(1 non-finite points); fix or remove them")


# ---------------------------------------------------------------------------
# The hook: usdbake's own exceptions, the same lines, before the stage is read


@pytest.fixture
def stage(tmp_path):
    return Usd.Stage.Open(str(floor_stage(tmp_path / "floor.usda")))


def test_hook_takes_one_processor_name_as_a_string(stage, tmp_path):
    layer = usdbake.bake(stage, "ambient_occlusion", {"ambient_occlusion": {"samples": 16}},
                         cache_dir=str(tmp_path / "cache"))
    assert UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Floor")).GetPrimvar("bake:ao").Get() is not None
    assert layer.identifier in stage.GetSessionLayer().subLayerPaths


@pytest.mark.parametrize("kwargs, kind, message", [
    ({"device": "gpu"}, UsageError, "device=gpu: expected cpu or cuda:N"),
    ({"processors": 3}, UsageError, "processors=3: expected a processor name or a list of names"),
    ({"params": ["samples", 64]}, ParamError,
     "params=['samples', 64]: expected {processor: {param: value}}, e.g. {'ambient_occlusion': {'samples': 64}}"),
    ({"params": {"ambient_occlusion": 64}}, ParamError,
     "params={'ambient_occlusion': 64}: expected {processor: {param: value}}, e.g. "
     "{'ambient_occlusion': {'samples': 64}}"),
    ({"threads": 0}, UsageError, "threads=0: expected a whole number of at least 1"),
], ids=["device", "processors-a-number", "params-a-list", "params-flat", "threads"])
def test_hook_refuses_bad_arguments_before_reading_the_stage(stage, no_read, kwargs, kind, message):
    before = stage.GetRootLayer().ExportToString()
    with pytest.raises(kind) as raised:
        usdbake.bake(stage, **kwargs)
    assert str(raised.value) == message
    assert stage.GetRootLayer().ExportToString() == before
    assert list(stage.GetSessionLayer().subLayerPaths) == []


@pytest.mark.parametrize("value", [None, "floor.usda"], ids=["none", "a-path"])
def test_hook_refuses_what_is_not_a_stage(value, no_read):
    with pytest.raises(UsageError) as raised:
        usdbake.bake(value)
    assert str(raised.value) == f"stage={value!r}: expected an open Usd.Stage (Usd.Stage.Open(path))"


def test_hook_refuses_a_cache_folder_that_is_a_file(stage, tmp_path, no_read):
    file = tmp_path / "cache"
    file.write_text("not a folder")
    with pytest.raises(UsageError) as raised:
        usdbake.bake(stage, cache_dir=str(file))
    assert str(raised.value) == f"cache_dir={file}: is a file, not a folder"
    assert file.read_text() == "not a folder"


def test_hook_refuses_to_author_into_the_stage_s_own_layers(stage, no_read):
    root = stage.GetRootLayer()
    before = root.ExportToString()
    for _ in range(2):  # the second call was "Cannot mute cache's root layer"
        with pytest.raises(UsageError) as raised:
            usdbake.bake(stage, layer=root)
        assert str(raised.value) == (f"layer={root.identifier}: a layer of the stage's own content; a bake replaces "
                                     f"everything in its layer, so give a new layer (Sdf.Layer.CreateAnonymous()) "
                                     f"or none")
    assert root.ExportToString() == before


def test_hook_param_errors_print_numpy_values_plainly(stage, no_read):
    import numpy as np

    with pytest.raises(ParamError) as raised:
        usdbake.bake(stage, "ambient_occlusion", {"ambient_occlusion": {"samples": np.float64(1.5)}})
    assert str(raised.value) == "samples=1.5 is not a valid int"
