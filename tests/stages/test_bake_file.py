"""stages.bake_file: the default output path, BakeReport.up_to_date, compute_outputs, and bake_file's order
of work (inputs checked, then before_compute, then READING, each processor and WRITING) and report (what
ran, warnings, 'processor: message' lines, de-instanced roots), on small stages baked with 16-ray ambient
occlusion. The command's printing of the report is tests/cli/test_bake.py's."""

import os
from pathlib import Path

import pytest
from pxr import Sdf, Usd

import fake_processors as fakes
from stage_builders import add_quads, instanced_stage, new_stage
from usdbake.core.errors import StageError, UsageError
from usdbake.core.pipeline import Pipeline
from usdbake.core.records import Primvar
from usdbake.core.runtime import Runtime
from usdbake.kernels.tracer import Tracer
from usdbake.stages.bake_file import READING, WRITING, BakeReport, bake_file, compute_outputs, default_output
from usdbake.stages.extract import extract_scene
from usdbake.stages.inputs import empty_bake_message
from usdbake.stages.provenance import provenance_of

AO_FAST = {"ambient_occlusion": {"samples": 16}}


def pipeline(cache, names=("ambient_occlusion",), params=None) -> Pipeline:
    return Pipeline.build(list(names), AO_FAST if params is None else params,
                          runtime=Runtime(Tracer.from_scene, device="cpu"), cache_dir=cache)


def phases(heard: list) -> list:
    """(name, [first fraction, last fraction]) per run of reports of one name, checking that fractions
    in between never go back."""
    runs: list = []
    for name, fraction in heard:
        if runs and runs[-1][0] == name:
            assert fraction >= runs[-1][1][-1], (name, fraction)
            runs[-1][1].append(fraction)
        else:
            runs.append((name, [fraction]))
    return [(name, [fractions[0], fractions[-1]]) for name, fractions in runs]


# --- default_output and BakeReport ------------------------------------------------------------


@pytest.mark.parametrize("source, expected", [
    ("shots/in.usda", "shots/in.baked.usdc"),
    ("shots/a.b.usdc", "shots/a.b.baked.usdc"),  # the last suffix only
    ("in.usd", "in.baked.usdc"),
])
def test_the_default_output_is_beside_the_input(tmp_path, monkeypatch, source, expected):
    monkeypatch.chdir(tmp_path)
    assert default_output(source, source) == expected
    # the same file, its source spelt as the stage resolved it: the output is spelt that way too
    assert default_output(source, str(tmp_path / source)) == str(tmp_path / expected)


def test_rebaking_an_output_writes_back_into_it(tmp_path):
    # the input is a usdbake output whose source is another file: the output replaces the input itself
    assert default_output(str(tmp_path / "in.baked.usdc"), str(tmp_path / "in.usda")) == str(tmp_path / "in.baked.usdc")


def report_of(*actions: str) -> BakeReport:
    return BakeReport(input="in.usda", output="out.usda", seconds=0.0,
                      steps=[{"processor": f"p{i}", "action": action} for i, action in enumerate(actions)])


@pytest.mark.parametrize("actions, up_to_date", [
    (("cached",), True), (("cached", "skip"), True), (("cached", "cached"), True),
    (("skip",), False),  # nothing was served from the cache: nothing is up to date
    (("cached", "run"), False), (("run",), False), ((), False),
])
def test_up_to_date_means_every_step_that_applies_came_from_the_cache(actions, up_to_date):
    assert report_of(*actions).up_to_date is up_to_date


def test_a_report_starts_with_no_warnings_messages_or_distribution():
    report = report_of("run")
    assert (report.warnings, report.messages, report.deinstanced, report.distributed) == ([], [], 0, {})
    assert report_of("run").warnings is not report.warnings  # a list of its own


# --- compute_outputs --------------------------------------------------------------------------


def test_compute_outputs_runs_the_pipeline_and_returns_the_records_to_author(cache):
    stage = fakes.build_stage(Usd.Stage.CreateInMemory())
    heard = []
    scene, outputs = compute_outputs(stage, pipeline(cache), time_code=None, allow_missing=False, deinstance=False,
                                     on_progress=lambda name, fraction: heard.append((name, fraction)))
    assert scene.prim_paths == ("/World/Ground", "/World/Cube")
    assert phases(heard) == [(READING, [0.0, 1.0]), ("ambient_occlusion", [0.0, 1.0])]
    records = {(r.prim, r.name): r for r in outputs if isinstance(r, Primvar)}
    assert set(records) == {("/World/Ground", "bake:ao"), ("/World/Cube", "bake:ao")}
    assert len(records["/World/Ground", "bake:ao"].values) == fakes.GROUND_POINTS
    assert len(records["/World/Cube", "bake:ao"].values) == fakes.CUBE_POINTS


def test_compute_outputs_with_every_step_skipped_says_so(cache):
    stage = fakes.build_stage(Usd.Stage.CreateInMemory())
    run = pipeline(cache, names=("displacement_fields",), params={})
    with pytest.raises(UsageError) as raised:
        compute_outputs(stage, run, time_code=None, allow_missing=False, deinstance=False)
    assert str(raised.value) == empty_bake_message(run.steps)
    assert str(raised.value).startswith("nothing to bake: displacement_fields skipped (not applicable: ")


# --- bake_file --------------------------------------------------------------------------------


def test_bake_file_checks_then_calls_before_compute_then_reports_each_phase(tmp_path, stage_in, cache):
    events = []
    out = tmp_path / "baked" / "out.usda"  # a folder made on the way
    report = bake_file(stage_in, str(out), pipeline(cache),
                       on_progress=lambda name, fraction: events.append((name, fraction)),
                       before_compute=lambda: events.append("before_compute"))
    assert events[0] == "before_compute"
    assert phases(events[1:]) == [(READING, [0.0, 1.0]), ("ambient_occlusion", [0.0, 1.0]), (WRITING, [0.0, 1.0])]
    assert (report.input, report.output) == (stage_in, str(out))
    assert [(s["processor"], s["action"]) for s in report.steps] == [("ambient_occlusion", "run")]
    assert report.steps[0]["params"]["samples"] == 16 and report.steps[0]["rays"] > 0
    assert report.seconds >= report.steps[0]["seconds"] >= 0.0
    assert (report.warnings, report.messages, report.deinstanced, report.distributed) == ([], [], 0, {})
    assert not report.up_to_date
    layer = Sdf.Layer.OpenAsAnonymous(str(out))
    assert provenance_of(layer)["source"] == os.path.join("..", "in.usda")  # relative to the output's folder
    assert list(layer.subLayerPaths) == ["../in.usda"]


def test_a_second_bake_is_up_to_date(tmp_path, stage_in, cache):
    out = str(tmp_path / "out.usda")
    bake_file(stage_in, out, pipeline(cache))
    again = bake_file(stage_in, out, pipeline(cache))
    assert [s["action"] for s in again.steps] == ["cached"] and again.up_to_date


def test_bake_file_without_an_output_writes_beside_the_input(tmp_path, stage_in, cache):
    report = bake_file(stage_in, None, pipeline(cache))
    assert report.output == str(tmp_path / "in.baked.usdc")
    assert Path(report.output).exists()


def test_a_bad_output_is_refused_before_before_compute_and_any_progress(tmp_path, stage_in, cache, no_read):
    events = []
    with pytest.raises(UsageError, match=r"out\.txt: unsupported extension '\.txt'"):
        bake_file(stage_in, str(tmp_path / "out.txt"), pipeline(cache),
                  on_progress=lambda *heard: events.append(heard), before_compute=lambda: events.append("start"))
    assert events == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.usda"]


def test_a_missing_asset_is_refused_first_and_a_warning_when_allowed(tmp_path, cache):
    source = tmp_path / "in.usda"
    fakes.write_stage(source)
    layer = Sdf.Layer.FindOrOpen(str(source))
    layer.subLayerPaths.append("gone.usda")
    layer.Save()
    events = []
    with pytest.raises(StageError, match=r"sublayer gone\.usda not found; --allow-missing bakes without it$"):
        bake_file(str(source), str(tmp_path / "out.usda"), pipeline(cache),
                  before_compute=lambda: events.append("start"))
    assert events == [] and not (tmp_path / "out.usda").exists()
    report = bake_file(str(source), str(tmp_path / "out.usda"), pipeline(cache), allow_missing=True)
    assert report.warnings == [f"{layer.identifier}: sublayer gone.usda not found; baked without it"]


def test_instances_are_reported_as_messages_or_counted_when_deinstanced(tmp_path, cache):
    source = instanced_stage(tmp_path / "chairs.usda")
    kept = bake_file(source, str(tmp_path / "kept.usda"), pipeline(cache))
    assert kept.deinstanced == 0
    assert kept.messages == ["ambient_occlusion: 2 native instances: per-instance mean AO as constant "
                             "primvars:bake:ao and float userProperties:bake:ao on their roots "
                             "(--deinstance for per-vertex AO)"]
    flat = bake_file(source, str(tmp_path / "flat.usda"), pipeline(cache), deinstance=True)
    assert flat.deinstanced == 2 and flat.messages == []
    baked = Usd.Stage.Open(str(tmp_path / "flat.usda"))
    assert not baked.GetPrimAtPath("/World/A").IsInstance() and not baked.GetPrimAtPath("/World/B").IsInstance()


def test_the_time_code_reaches_the_stage_reading(tmp_path, cache):
    stage = new_stage()
    mesh = add_quads(stage, "/World/Floor")
    mesh.GetPointsAttr().Clear()
    mesh.GetPointsAttr().Set([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], 3.0)  # samples only
    stage.GetRootLayer().Export(str(tmp_path / "anim.usda"))
    with pytest.raises(StageError, match=r"points: has 1 time samples \(3\.\.3\) and no default value"):
        bake_file(str(tmp_path / "anim.usda"), str(tmp_path / "out.usda"), pipeline(cache))
    report = bake_file(str(tmp_path / "anim.usda"), str(tmp_path / "out.usda"), pipeline(cache), time_code=3.0)
    assert report.steps[0]["action"] == "run"
    assert extract_scene(Usd.Stage.Open(str(tmp_path / "anim.usda")), time=3.0).num_triangles == 2
