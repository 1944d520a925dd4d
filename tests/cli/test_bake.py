"""cli.bake through the command's entry point: which path a bake takes (one stage, a batch) and the option
combinations each refuses before any work, what one bake prints (warnings first, the summary, each
processor's messages, the de-instancing note, the 'wrote' line; or --json), what plan prints, and a batch's
--json report. Bad inputs in general are tests/cli/test_cli_inputs.py's; the batch's pool and cluster,
tests/farm/test_batch.py's."""

import json
from pathlib import Path

import pytest
from pxr import Sdf

import fake_processors as fakes
from stage_builders import instanced_stage
from usdbake.cli.main import main

FAST = ["--set", "ambient_occlusion.samples=16"]


def run(capsys, *argv) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def usage_line(code: int, out: str, err: str) -> str:
    """The one error line of a refused command (exit 2, nothing on stdout)."""
    assert code == 2 and out == "", err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


@pytest.fixture
def no_scheduler(monkeypatch):
    monkeypatch.delenv("DASK_SCHEDULER_ADDRESS", raising=False)


# --- option combinations, refused before any work ---------------------------------------------


def test_bake_without_a_stage_or_a_list_says_what_to_give(capsys, no_read):
    assert usage_line(*run(capsys, "bake")) == "usdbake: error: bake: give a stage to bake (or --list FILE)"


def test_one_stage_refuses_the_options_of_a_batch_or_a_cluster(capsys, stage_in, cache, no_read, no_scheduler):
    assert usage_line(*run(capsys, "bake", stage_in, "--workers", "2", "--cache", cache)) == \
        "usdbake: error: --workers is for several stages; one stage uses --threads"
    assert usage_line(*run(capsys, "bake", stage_in, "--chunk-size", "100", "--cache", cache)) == \
        "usdbake: error: --chunk-size is for --scheduler (receiver work in Dask tasks)"


def test_a_batch_refuses_a_file_as_its_folder_and_a_chunk_size(capsys, tmp_path, cache, no_read, no_scheduler):
    first, second = (fakes.write_stage(tmp_path / name) for name in ("a.usda", "b.usda"))
    blocker = tmp_path / "out.usda"
    blocker.write_text("")
    assert usage_line(*run(capsys, "bake", first, second, "-o", blocker, "--cache", cache)) == \
        f"usdbake: error: -o {blocker}: several stages bake into a folder, and this is a file"
    assert usage_line(*run(capsys, "bake", first, second, "--chunk-size", "8", "--cache", cache)) == \
        "usdbake: error: --chunk-size is for one stage; a batch runs one task per stage"
    # a folder name ending in / makes even one stage a batch
    assert usage_line(*run(capsys, "bake", first, "-o", f"{tmp_path / 'outdir'}/", "--chunk-size", "8",
                           "--cache", cache)) == \
        "usdbake: error: --chunk-size is for one stage; a batch runs one task per stage"


# --- what one bake prints ---------------------------------------------------------------------


def test_one_bake_prints_its_summary_then_where_it_wrote(capsys, stage_in, cache, tmp_path):
    out_path = tmp_path / "out.usda"
    code, out, err = run(capsys, "bake", stage_in, "-o", out_path, "--cache", cache, *FAST)
    assert code == 0 and out == ""  # the summary is the command's report: stderr, beside the progress bars
    lines = err.splitlines()
    assert any("bake summary" in line for line in lines)
    summary = lines.index(next(line for line in lines if "bake summary" in line))
    rows = [line.replace("│", " ").replace("|", " ").split() for line in lines[summary:]]
    assert ["ambient_occlusion", "ran"] in [row[:2] for row in rows]  # below the progress bars
    last = lines[-1].split()
    assert last[:4] == ["wrote", str(out_path), "in", last[3]] and last[4] == "s" and float(last[3]) >= 0


def test_one_bake_json_has_output_seconds_and_steps_and_nothing_else(capsys, stage_in, cache, tmp_path):
    code, out, err = run(capsys, "bake", stage_in, "-o", tmp_path / "out.usda", "--cache", cache, "--json", *FAST)
    assert code == 0
    report = json.loads(out)
    assert set(report) == {"output", "seconds", "steps"}  # no 'distributed' for an in-process bake
    assert report["output"] == str(tmp_path / "out.usda") and report["seconds"] >= 0
    assert [step["processor"] for step in report["steps"]] == ["ambient_occlusion"]
    assert "bake summary" not in err and "wrote" not in err


def test_processor_messages_and_the_deinstancing_note_are_printed(capsys, tmp_path, cache):
    source = instanced_stage(tmp_path / "chairs.usda")
    code, _, err = run(capsys, "bake", source, "-o", tmp_path / "kept.usda", "--cache", cache, *FAST)
    assert code == 0, err
    assert ("ambient_occlusion: 2 native instances: per-instance mean AO as constant primvars:bake:ao and float "
            "userProperties:bake:ao on their roots (--deinstance for per-vertex AO)") in err.splitlines()
    assert "de-instanced" not in err
    code, _, err = run(capsys, "bake", source, "-o", tmp_path / "flat.usda", "--cache", cache, "--deinstance", *FAST)
    assert code == 0, err
    assert ("de-instanced 2 native instances (instanceable = false in the bake layer) to hold per-vertex results"
            in err.splitlines())


def test_the_scenes_warnings_come_first_one_line_each(capsys, tmp_path, cache):
    source = tmp_path / "in.usda"
    fakes.write_stage(source)
    layer = Sdf.Layer.FindOrOpen(str(source))
    layer.subLayerPaths.append("gone.usda")
    layer.Save()
    code, out, err = run(capsys, "bake", source, "-o", tmp_path / "out.usda", "--cache", cache, "--allow-missing",
                         "--json", *FAST)
    assert code == 0 and json.loads(out)["steps"][0]["action"] == "run"
    assert err.splitlines() == [f"warning: {layer.identifier}: sublayer gone.usda not found; baked without it"]


# --- plan -------------------------------------------------------------------------------------


def test_plan_prints_the_scenes_warnings_and_the_conflicts_asked_for(capsys, tmp_path, cache):
    source = tmp_path / "in.usda"
    fakes.write_stage(source)
    layer = Sdf.Layer.FindOrOpen(str(source))
    layer.subLayerPaths.append("gone.usda")
    layer.Save()
    code, out, err = run(capsys, "plan", source, "--cache", cache, "--allow-missing", "-p", "ambient_occlusion",
                         "-p", "instance_ao")
    assert code == 0
    assert err.splitlines() == [
        f"warning: {layer.identifier}: sublayer gone.usda not found; baked without it",
        "conflict: ambient_occlusion and instance_ao both write primvars:bake:ao; run one of them"]
    rows = {line.replace("│", " ").split()[0]: line for line in out.splitlines()
            if line.replace("│", " ").split()[:1] in (["ambient_occlusion"], ["instance_ao"],
                                                       ["displacement_fields"])}
    assert "will run" in rows["ambient_occlusion"] and "skipped" in rows["instance_ao"]
    assert not (tmp_path / "in.baked.usdc").exists()


def test_plan_json_is_one_report_per_step(capsys, stage_in, cache):
    code, out, err = run(capsys, "plan", stage_in, "--cache", cache, "--json", "-p", "ambient_occlusion", *FAST)
    assert code == 0 and err == ""
    [step] = json.loads(out)
    assert (step["processor"], step["action"], step["params"]["samples"]) == ("ambient_occlusion", "run", 16)


# --- a batch ----------------------------------------------------------------------------------


def test_a_batch_json_reports_each_stage_and_exits_1_when_one_failed(capsys, tmp_path, cache, no_scheduler):
    good = fakes.write_stage(tmp_path / "good.usda")
    missing = tmp_path / "missing.usda"
    outdir = tmp_path / "out"
    code, out, err = run(capsys, "bake", good, missing, "-o", f"{outdir}/", "--workers", "1", "--cache", cache,
                         "--json", *FAST)
    assert code == 1
    good_row, missing_row = json.loads(out)
    assert (good_row["input"], good_row["status"], good_row["error"]) == (good, "baked", "")
    assert good_row["output"] == str(outdir / "good.baked.usdc") and Path(good_row["output"]).exists()
    assert [step["processor"] for step in good_row["steps"]] == ["ambient_occlusion"]
    assert (missing_row["input"], missing_row["status"], missing_row["steps"]) == (str(missing), "failed", [])
    assert "no such file" in missing_row["error"]
    assert "stages baked" not in err  # no table or count with --json
