"""The `usdbake` command, tested through its entry point usdbake.cli.main(argv).

User mistakes exit 2 with one line on stderr and no traceback; --json output
on stdout is machine-readable (nothing else may be printed there).
"""

import json
import subprocess
import sys
from pathlib import Path

import pytest

import fake_processors as fakes
from usdbake.cli.main import main
from usdbake import core

FAST = ["--set", "ambient_occlusion.samples=16"]


def run_cli(capsys, *argv):
    capsys.readouterr()
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_usage_error(code, out, err, *fragments):
    assert code == 2
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("usdbake: error:")
    assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in lines[0]


# ---------------------------------------------------------------------------
# Bad input: exit 2, one line


def test_missing_file(capsys, tmp_path, cache):
    code, out, err = run_cli(capsys, "bake", tmp_path / "missing.usda", "--cache", cache)
    assert_usage_error(code, out, err, "missing.usda", "no such file")


@pytest.mark.parametrize("text", ["this is not usd {{{\n", "#usda 1.0\n(\n  garbage = \n"],
                         ids=["garbage", "truncated-usda"])
def test_unparseable_layer(capsys, tmp_path, cache, text):
    bad = tmp_path / "bad.usda"
    bad.write_text(text)
    code, out, err = run_cli(capsys, "bake", bad, "-o", tmp_path / "out.usda", "--cache", cache)
    assert_usage_error(code, out, err, "bad.usda", "cannot be read as USD")
    assert "()" not in err  # the reason USD gave is kept, not lost to an empty pair of parentheses
    assert not (tmp_path / "out.usda").exists()


@pytest.mark.parametrize("argv, fragments", [
    (["-p", "nope"], ["unknown processor 'nope'", "ambient_occlusion"]),
    (["--set", "ambient_occlusion.nope=1"], ["unknown parameter 'nope'"]),
    (["--set", "ambient_occlusion.samples=-1"], ["samples", "minimum"]),
    (["--set", "ambient_occlusion.samples=abc"], ["samples='abc'", "not a valid int"]),
    (["--set", "ambient_occlusion.per_face=maybe"], ["per_face", "not a valid bool"]),
    (["--set", "ambient_occlusion.samples"], ["expected NAME.param=value"]),
    (["--set", "samples=16"], ["expected NAME.param=value"]),
    (["--set", "nope.samples=16"], ["unknown processor 'nope'"]),
    (["--bogus-flag"], ["unrecognized arguments"]),
    (["--threads", "0"], ["--threads", "'0'", "at least 1"]),
    (["--threads", "two"], ["--threads", "'two'", "at least 1"]),
])
def test_bad_options(capsys, stage_in, cache, tmp_path, argv, fragments):
    code, out, err = run_cli(capsys, "bake", stage_in, "-o", tmp_path / "out.usda", "--cache", cache, *argv)
    assert_usage_error(code, out, err, *fragments)
    assert not (tmp_path / "out.usda").exists()


@pytest.mark.parametrize("toml, fragments", [
    ("processors = [\n", ["not valid TOML"]),
    ("[ambient_occlusion]\nnope = 1\n", ["unknown parameter 'nope'"]),
    ("[ambient_occlusion]\nsamples = true\n", ["samples=True", "not a valid int"]),
    ("[ambient_occlusion]\nsamples = 0\n", ["samples", "minimum"]),
    ("[nope]\nsamples = 1\n", ["unknown processor 'nope'"]),
    ("ambient_occlusion = 3\n", ["must be a table"]),
], ids=["syntax", "unknown-param", "wrong-type", "out-of-range", "unknown-processor", "not-a-table"])
def test_bad_config(capsys, stage_in, cache, tmp_path, toml, fragments):
    config = tmp_path / "bake.toml"
    config.write_text(toml)
    code, out, err = run_cli(capsys, "bake", stage_in, "--config", config, "--cache", cache)
    assert_usage_error(code, out, err, *fragments)


def test_missing_config(capsys, stage_in, cache, tmp_path):
    code, out, err = run_cli(capsys, "bake", stage_in, "--config", tmp_path / "nope.toml", "--cache", cache)
    assert_usage_error(code, out, err, "nope.toml")


def test_inspect_rejects_a_layer_usdbake_did_not_write(capsys, stage_in):
    code, out, err = run_cli(capsys, "inspect", stage_in)
    assert_usage_error(code, out, err, "not a usdbake output")


def test_unknown_command(capsys):
    code, out, err = run_cli(capsys, "bakery")
    assert_usage_error(code, out, err, "invalid choice")


# ---------------------------------------------------------------------------
# Commands


def test_plan_lists_the_action_and_changes_after_a_bake(capsys, stage_in, cache, tmp_path):
    code, out, _ = run_cli(capsys, "plan", stage_in, "--cache", cache, "--json", *FAST)
    assert code == 0
    plan = {row["processor"]: row for row in json.loads(out)}
    assert set(plan) == set(core.registry.registry())  # without -p, plan reports every processor
    assert plan["ambient_occlusion"]["action"] == "run"
    assert plan["ambient_occlusion"]["params"]["samples"] == 16
    assert not Path(cache).exists() or not any(Path(cache).iterdir())  # planning runs nothing

    assert run_cli(capsys, "bake", stage_in, "-o", tmp_path / "out.usda", "--cache", cache, *FAST)[0] == 0
    code, out, _ = run_cli(capsys, "plan", stage_in, "-p", "ambient_occlusion", "--cache", cache, "--json", *FAST)
    assert [(row["processor"], row["action"]) for row in json.loads(out)] == [("ambient_occlusion", "cached")]

    code, out, err = run_cli(capsys, "plan", stage_in, "-p", "ambient_occlusion", "--cache", cache, *FAST)
    assert code == 0 and err == ""  # the table is the command's output: stdout
    assert "ambient_occlusion" in out and "up to date" in out


def test_list_json_has_each_param_with_default_and_doc(capsys):
    code, out, _ = run_cli(capsys, "list", "--json")
    assert code == 0
    rows = {row["name"]: row for row in json.loads(out)}
    ao = rows["ambient_occlusion"]
    assert ao["provides"] == ["AmbientOcclusionProduct"] and ao["summary"]
    params = {p["name"]: p for p in ao["params"]}
    assert set(params) == {"samples", "max_distance", "per_face", "connect_occlusion", "seed", "instances", "target",
                           "texel_density", "max_texture_size", "margin", "denoise"}
    assert params["samples"]["default"] == 256
    assert params["per_face"]["default"] is False
    assert all(p["doc"] for p in params.values())


def test_list_table(capsys):
    code, out, err = run_cli(capsys, "list")
    assert code == 0 and "ambient_occlusion" in out and "samples" in out and err == ""


def test_bake_json_stdout_is_pure_json(capsys, stage_in, cache, tmp_path):
    code, out, _ = run_cli(capsys, "bake", stage_in, "-o", tmp_path / "out.usda", "--cache", cache, "--json",
                           *FAST)
    assert code == 0
    report = json.loads(out)  # fails if Warp or anything else printed to stdout
    assert report["output"] == str(tmp_path / "out.usda")
    assert report["steps"][0]["processor"] == "ambient_occlusion"
    assert report["steps"][0]["rays"] > 0


def test_inspect_json_reports_the_ao_primvar(capsys, stage_in, cache, tmp_path):
    out_path = tmp_path / "out.usda"
    assert run_cli(capsys, "bake", stage_in, "-o", out_path, "--cache", cache, *FAST)[0] == 0
    code, out, _ = run_cli(capsys, "inspect", out_path, "--json")
    assert code == 0
    report = json.loads(out)
    rows = {row["path"]: row for row in report["properties"]}
    assert set(rows) == {"/World/Ground.primvars:bake:ao", "/World/Cube.primvars:bake:ao"}
    assert rows["/World/Ground.primvars:bake:ao"]["values"] == fakes.GROUND_POINTS
    assert rows["/World/Cube.primvars:bake:ao"]["values"] == fakes.CUBE_POINTS
    assert rows["/World/Cube.primvars:bake:ao"]["interpolation"] == "vertex"
    assert rows["/World/Cube.primvars:bake:ao"]["type"] == "float[]"
    assert report["sublayers"] == ["in.usda"]
    assert report["provenance"]["processors"]["ambient_occlusion"]["params"]["samples"] == 16

    code, out, err = run_cli(capsys, "inspect", out_path)
    assert code == 0 and "baked by usdbake" in out and "from in.usda" in out and err == ""


def test_config_toml_selects_processors_and_params(capsys, stage_in, cache, tmp_path):
    config = tmp_path / "bake.toml"
    config.write_text('processors = ["ambient_occlusion"]\n\n[ambient_occlusion]\nsamples = 16\nseed = 3\n')
    out_path = tmp_path / "out.usda"
    code, out, _ = run_cli(capsys, "bake", stage_in, "-o", out_path, "--config", config, "--cache", cache, "--json")
    assert code == 0
    steps = json.loads(out)["steps"]
    assert [s["processor"] for s in steps] == ["ambient_occlusion"]
    assert steps[0]["params"]["samples"] == 16 and steps[0]["params"]["seed"] == 3

    # --set wins over the config file.
    code, out, _ = run_cli(capsys, "bake", stage_in, "-o", out_path, "--config", config, "--cache", cache, "--json",
                           "--set", "ambient_occlusion.seed=4")
    assert code == 0 and json.loads(out)["steps"][0]["params"]["seed"] == 4


def test_console_script_runs(stage_in, cache, tmp_path):
    script = Path(sys.executable).parent / "usdbake"
    assert script.exists(), f"console script missing: {script}"
    done = subprocess.run([str(script), "list", "--json"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "ambient_occlusion" in {row["name"] for row in json.loads(done.stdout)}

    # In a fresh process Warp initializes during the bake: its banner must not reach stdout.
    done = subprocess.run([str(script), "bake", stage_in, "-o", str(tmp_path / "out.usda"), "--cache", cache,
                           "--json", *FAST], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["steps"][0]["action"] == "run"


def test_threads_reach_the_ray_core(capsys, stage_in, cache, tmp_path, monkeypatch):
    """--threads N is the thread count of the run's tracer every processor casts its rays with: the run's
    tracer factory builds it once, with N."""
    from usdbake.kernels.tracer import Tracer

    seen = []
    original = Tracer.from_scene

    def recording(scene, **kwargs):
        built = original(scene, **kwargs)
        seen.append(built.threads)
        return built

    monkeypatch.setattr(Tracer, "from_scene", recording)
    code, _, err = run_cli(capsys, "bake", stage_in, "-o", tmp_path / "out.usda", "--cache", cache, "--force",
                           "--threads", "3", *FAST)
    assert code == 0, err
    assert seen == [3]


def test_bench_runs_the_benchmarks_in_a_process_of_their_own(capfd):
    """``usdbake bench`` runs ``python -m usdbake.benchmarks`` (the library never imports the benchmarks) and
    returns its exit status."""
    assert main(["bench", "no_such_benchmark"]) == 2
    assert "unknown benchmark(s): no_such_benchmark" in capfd.readouterr().err
