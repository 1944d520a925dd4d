"""Every input of `usdbake bake`, `plan` and `inspect` is checked before any compute: one line on
stderr naming the problem, exit 2, no traceback, no file written and the input byte-identical.
Ctrl-C exits 130 with nothing half-written."""

import hashlib
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from pxr import Sdf, Usd

import fake_processors as fakes
import usdbake
from usdbake import core
from usdbake.cli.main import main
from usdbake.processors.occlusion.ambient_occlusion import AmbientOcclusion

FAST = ["--set", "ambient_occlusion.samples=16"]


def digest(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def run_cli(capsys, *argv):
    capsys.readouterr()
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_error(code, out, err, expected: str):
    """Exit 2 and exactly one line on stderr: 'usdbake: error: <expected>'."""
    assert code == 2
    assert out == ""
    assert "Traceback" not in err
    assert err.strip().splitlines() == [f"usdbake: error: {expected}"], err


# ---------------------------------------------------------------------------
# The output path


ACCEPTED = ".usd, .usda or .usdc"


@pytest.mark.parametrize("name, expected", [
    ("x.txt", "{out}: unsupported extension '.txt'; the output must be a " + ACCEPTED + " layer"),
    ("x", "{out}: no extension; the output must be a " + ACCEPTED + " layer"),
    ("x.usdz", "{out}: usdbake does not write .usdz packages (the bake layer sublayers its input and names "
               "its sidecar files); write " + ACCEPTED),
    ("folder", "{out}: is a folder; give a layer file name ending in " + ACCEPTED),
    ("a_file/out.usda", "{out}: {tmp}/a_file is a file, not a folder"),
    ("in.usda", "{out}: refusing to overwrite the input layer; choose another -o"),
    ("sub.usda", "{out}: refusing to overwrite sub.usda, a layer the input uses; choose another -o"),
    ("notes.usda", "{out}: exists and was not written by usdbake; refusing to replace it (remove it or "
                   "choose another -o)"),
    ("garbage.usdc", "{out}: exists and was not written by usdbake; refusing to replace it (remove it or "
                     "choose another -o)"),
], ids=["txt", "no-extension", "usdz", "folder", "parent-is-a-file", "the-input", "a-sublayer-of-the-input",
        "not-a-bake-layer", "garbage"])
def test_bad_output_is_refused_before_compute(capsys, tmp_path, cache, no_read, name, expected):
    sub = tmp_path / "sub.usda"
    sub.write_text("#usda 1.0\n")
    stage_in = fakes.write_stage(tmp_path / "in.usda")
    layer = Sdf.Layer.FindOrOpen(stage_in)
    layer.subLayerPaths.append("sub.usda")
    layer.Save()
    (tmp_path / "folder").mkdir()
    (tmp_path / "a_file").write_text("not a folder")
    (tmp_path / "notes.usda").write_text("#usda 1.0\n(\n    doc = \"someone's layer\"\n)\n")
    (tmp_path / "garbage.usdc").write_bytes(b"\x00garbage")
    before = {p.name: digest(p) for p in tmp_path.iterdir() if p.is_file()}
    out = tmp_path / name

    code, stdout, err = run_cli(capsys, "bake", stage_in, "-o", out, "--cache", cache, *FAST)
    assert_error(code, stdout, err, expected.format(out=out, tmp=tmp_path))
    assert {p.name: digest(p) for p in tmp_path.iterdir() if p.is_file()} == before
    assert not Path(cache).exists()


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc (a folder no one can write in)")
def test_output_in_a_folder_that_cannot_be_written(capsys, stage_in, cache, no_read):
    before = digest(stage_in)
    code, out, err = run_cli(capsys, "bake", stage_in, "-o", "/proc/usdbake/out.usda", "--cache", cache, *FAST)
    assert code == 2
    assert err.strip().splitlines()[0].startswith("usdbake: error: /proc/usdbake/out.usda: cannot write in /proc (")
    assert digest(stage_in) == before


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes in read-only folders")
def test_output_in_a_read_only_folder(capsys, tmp_path, stage_in, cache, no_read):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        code, out, err = run_cli(capsys, "bake", stage_in, "-o", locked / "out.usda", "--cache", cache, *FAST)
    finally:
        locked.chmod(0o700)
    assert_error(code, out, err, f"{locked / 'out.usda'}: cannot write in {locked} (Permission denied)")


def test_accepted_output_types_and_a_missing_folder_are_written(capsys, tmp_path, stage_in, cache):
    before = digest(stage_in)
    for name in ("out.usd", "out.USDA", "new/folder/out.usdc"):
        code, _, err = run_cli(capsys, "bake", stage_in, "-o", tmp_path / name, "--cache", cache, *FAST)
        assert code == 0, err
        assert Usd.Stage.Open(str(tmp_path / name)).GetPrimAtPath("/World/Cube").HasAttribute("primvars:bake:ao")
    assert digest(stage_in) == before


# ---------------------------------------------------------------------------
# Options


def test_set_for_a_processor_that_is_not_run(capsys, stage_in, cache, no_read):
    code, out, err = run_cli(capsys, "bake", stage_in, "--cache", cache, *FAST,
                             "--set", "radiosity.gather_rays=16")
    assert_error(code, out, err, "--set radiosity.gather_rays=16: radiosity is not part of this run "
                                 "(ambient_occlusion); add -p radiosity")
    code, out, err = run_cli(capsys, "plan", stage_in, "-p", "ambient_occlusion", "--cache", cache,
                             "--set", "radiosity.gather_rays=16")
    assert_error(code, out, err, "--set radiosity.gather_rays=16: radiosity is not part of this run "
                                 "(ambient_occlusion); add -p radiosity")


def test_set_for_a_dependency_of_the_run_is_accepted(capsys, stage_in, cache):
    """instance_ao requires displacement_fields: its params belong to the run (it skips here: no prototypes)."""
    code, out, err = run_cli(capsys, "plan", stage_in, "-p", "instance_ao", "--cache", cache,
                             "--set", "displacement_fields.direction_map_size=8")
    assert code == 0, err


@pytest.mark.parametrize("toml, expected", [
    ('processors = "ambient_occlusion"\n',
     "processors must be a list of names, e.g. processors = [\"ambient_occlusion\"] (got 'ambient_occlusion')"),
    ("processors = [1]\n", "processors must be a list of names, e.g. processors = [\"ambient_occlusion\"] "
                           "(got [1])"),
    ("[displacement_fields]\nencoding = 8\n", "[displacement_fields] encoding=8 is not a valid str (write it in "
                                              "quotes)"),
    ("[ambient_occlusion]\nsamples = 1.5\n", "samples=1.5 is not a valid int"),
    ("[ambient_occlusion]\nper_face = \"maybe\"\n", "per_face='maybe' is not a valid bool"),
], ids=["processors-a-string", "processors-not-names", "str-param-a-number", "int-param-a-float",
        "bool-param-a-word"])
def test_wrongly_typed_config(capsys, stage_in, cache, tmp_path, no_read, toml, expected):
    config = tmp_path / "bake.toml"
    config.write_text(toml)
    before = digest(stage_in)
    code, out, err = run_cli(capsys, "bake", stage_in, "--config", config, "--cache", cache)
    prefix = f"{config}: " if "processors" in toml or "encoding" in toml else ""
    assert_error(code, out, err, prefix + expected)
    assert digest(stage_in) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bake.toml", "in.usda"]


def test_config_table_for_a_processor_not_run_is_a_warning(capsys, stage_in, cache, tmp_path):
    config = tmp_path / "studio.toml"
    config.write_text("[radiosity]\ngather_rays = 16\n\n[ambient_occlusion]\nsamples = 16\n")
    code, out, err = run_cli(capsys, "plan", stage_in, "-p", "ambient_occlusion", "--config", config,
                             "--cache", cache)
    assert code == 0
    assert f"warning: {config}: [radiosity] is ignored: radiosity is not part of this run (ambient_occlusion)" \
        in err.splitlines()


@pytest.mark.parametrize("device, expected", [
    ("gpu", "--device gpu: expected cpu or cuda:N"),
    ("cuda:99", "--device cuda:99: no such Warp device here (available: "),
])
def test_bad_device(capsys, stage_in, cache, no_read, device, expected):
    code, out, err = run_cli(capsys, "bake", stage_in, "--device", device, "--cache", cache, *FAST)
    assert code == 2 and out == "" and "Traceback" not in err
    line = [text for text in err.strip().splitlines() if text.startswith("usdbake:")]
    assert len(line) == 1 and line[0].startswith(f"usdbake: error: {expected}")
    assert not (Path(stage_in).parent / "in.baked.usdc").exists()


def test_cache_that_is_a_file(capsys, stage_in, cache, tmp_path, no_read):
    blocker = tmp_path / "cache_file"
    blocker.write_text("")
    code, out, err = run_cli(capsys, "bake", stage_in, "--cache", blocker, *FAST)
    assert_error(code, out, err, f"--cache {blocker}: is a file, not a folder")


# ---------------------------------------------------------------------------
# Nothing to bake: no layer is written (the command and the hook agree)


NOTHING = ("nothing to bake: displacement_fields skipped (not applicable: no instanced prototypes); "
           "no output was written")


def test_bake_where_every_processor_skips_writes_nothing(capsys, tmp_path, stage_in, cache):
    before = digest(stage_in)
    code, out, err = run_cli(capsys, "bake", stage_in, "-p", "displacement_fields", "--cache", cache, "--json")
    assert_error(code, out, err, NOTHING)
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_file()) == ["in.usda"]
    assert digest(stage_in) == before

    code, out, err = run_cli(capsys, "plan", stage_in, "-p", "displacement_fields", "--cache", cache)
    assert code == 0
    assert err.strip().splitlines()[-1] == \
        "nothing to bake: every processor would be skipped; bake would write no output"


def test_bake_where_every_processor_skips_keeps_the_previous_output(capsys, tmp_path, stage_in, cache):
    out = tmp_path / "out.usda"
    assert run_cli(capsys, "bake", stage_in, "-o", out, "--cache", cache, *FAST)[0] == 0
    before = digest(out)
    code, stdout, err = run_cli(capsys, "bake", stage_in, "-o", out, "-p", "displacement_fields", "--cache",
                                cache, "--json")
    assert_error(code, stdout, err, NOTHING)
    assert digest(out) == before


def test_a_skipped_processor_writes_nothing_beside_one_that_ran(capsys, tmp_path, stage_in, cache):
    out = tmp_path / "out.usda"
    code, _, err = run_cli(capsys, "bake", stage_in, "-o", out, "-p", "ambient_occlusion", "-p",
                           "displacement_fields", "--cache", cache, *FAST)
    assert code == 0, err
    layer = Sdf.Layer.OpenAsAnonymous(str(out))
    authored = []
    layer.Traverse(Sdf.Path.absoluteRootPath, lambda path: authored.append(str(path)) if path.IsPropertyPath()
                   else None)
    assert sorted(authored) == ["/World/Cube.primvars:bake:ao", "/World/Ground.primvars:bake:ao"]
    processors = dict(layer.customLayerData)["usdbake"]["processors"]
    assert processors["displacement_fields"]["action"] == "skip"
    assert processors["displacement_fields"]["reason"] == "not applicable: no instanced prototypes"
    assert list(dict(layer.customLayerData)["usdbake"]["sidecars"]) == []
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_file()) == ["in.usda", "out.usda"]


def test_hook_where_every_processor_skips_raises_and_authors_nothing(cache):
    stage = fakes.build_stage(Usd.Stage.CreateInMemory())
    with pytest.raises(core.UsageError) as raised:
        usdbake.bake(stage, ["displacement_fields"], cache_dir=cache)
    assert str(raised.value) == NOTHING
    assert list(stage.GetSessionLayer().subLayerPaths) == []


def test_hook_params_for_a_processor_not_run_raise(cache):
    stage = fakes.build_stage(Usd.Stage.CreateInMemory())
    with pytest.raises(core.ParamError) as raised:
        usdbake.bake(stage, ["ambient_occlusion"], {"radiosity": {"gather_rays": 4}}, cache_dir=cache)
    assert str(raised.value) == ("params for 'radiosity', which is not part of this run (ambient_occlusion); "
                                 "add it to the processors")


# ---------------------------------------------------------------------------
# inspect


def test_inspect_a_garbage_file(capsys, tmp_path):
    bad = tmp_path / "bad.usda"
    bad.write_text("this is not usd {{{\n")
    before = digest(bad)
    code, out, err = run_cli(capsys, "inspect", bad)
    assert_error(code, out, err, f"{bad}: cannot be read as USD (<{bad}> is not a valid usda layer)")
    assert digest(bad) == before


@pytest.mark.parametrize("name, expected", [
    ("missing.usda", "{path}: no such file"),
    ("folder", "{path}: is a folder, not a layer"),
    ("notes.txt", "{path}: cannot be read as USD (Cannot determine file format for @{path}@)"),
])
def test_inspect_a_path_that_is_not_a_layer(capsys, tmp_path, name, expected):
    (tmp_path / "folder").mkdir()
    (tmp_path / "notes.txt").write_text("notes")
    path = tmp_path / name
    code, out, err = run_cli(capsys, "inspect", path, "--json")
    assert_error(code, out, err, expected.format(path=path))


# ---------------------------------------------------------------------------
# Ctrl-C


def test_interrupt_during_compute_exits_130_and_leaves_the_output(capsys, tmp_path, stage_in, cache, monkeypatch):
    out = tmp_path / "out.usda"
    assert run_cli(capsys, "bake", stage_in, "-o", out, "--cache", cache, *FAST)[0] == 0
    before = {p.name: digest(p) for p in tmp_path.iterdir() if p.is_file()}

    def interrupted(self, ctx):
        raise KeyboardInterrupt

    monkeypatch.setattr(AmbientOcclusion, "run", interrupted)
    code, stdout, err = run_cli(capsys, "bake", stage_in, "-o", out, "--cache", cache, "--force", "--json", *FAST)
    assert code == 130 and stdout == ""
    assert err.strip().splitlines() == ["usdbake: interrupted; no output was written"]
    assert {p.name: digest(p) for p in tmp_path.iterdir() if p.is_file()} == before


SLOW_BAKE = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from usdbake.cli.main import main
    from usdbake.processors.occlusion.ambient_occlusion import AmbientOcclusion

    def slow(self, ctx):
        Path(sys.argv[1]).write_text("running")
        time.sleep(120)

    AmbientOcclusion.run = slow
    sys.exit(main(sys.argv[2:]))
""")


def start_scripted_bake(tmp_path, script_text: str, stage_in, out, cache) -> tuple[subprocess.Popen, Path]:
    """Run ``script_text`` (a patched ``usdbake bake``) as its own process: (process, its state-marker file)."""
    script, marker = tmp_path / "scripted_bake.py", tmp_path / "state.txt"
    script.write_text(script_text)
    process = subprocess.Popen([sys.executable, str(script), str(marker), "bake", str(stage_in), "-o", str(out),
                                "--cache", cache, "--force", "--json", *FAST],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return process, marker


def wait_for_state(process: subprocess.Popen, marker: Path, state: str) -> None:
    """Until the scripted bake writes ``state`` to its marker (AssertionError after 120 s or if it ends)."""
    deadline = time.monotonic() + 120
    while process.poll() is None and time.monotonic() < deadline:
        if marker.exists() and marker.read_text() == state:
            return
        time.sleep(0.05)
    raise AssertionError(f"never reached {state!r}: {process.communicate(timeout=10)}")


def test_sigint_during_a_bake_exits_130_with_nothing_half_written(capsys, tmp_path, stage_in, cache):
    """A real Ctrl-C (SIGINT) to a running `usdbake bake` process."""
    out = tmp_path / "out.usda"
    assert run_cli(capsys, "bake", stage_in, "-o", out, "--cache", cache, *FAST)[0] == 0
    before = {p.name: digest(p) for p in tmp_path.iterdir() if p.is_file()}
    process, marker = start_scripted_bake(tmp_path, SLOW_BAKE, stage_in, out, cache)
    try:
        wait_for_state(process, marker, "running")
        process.send_signal(signal.SIGINT)
        stdout, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, stderr
    assert stdout == "" and "Traceback" not in stderr
    assert stderr.strip().splitlines()[-1] == "usdbake: interrupted; no output was written"
    marker.unlink()
    (tmp_path / "scripted_bake.py").unlink()
    assert {p.name: digest(p) for p in tmp_path.iterdir() if p.is_file()} == before


DRAINING_BAKE = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from usdbake.cli.main import main
    from usdbake.processors.occlusion.ambient_occlusion import AmbientOcclusion

    def draining(self, ctx):
        # Stands in for CPU kernel launches that cannot be stopped midway: the first Ctrl-C is
        # caught while the launches under way still run.
        Path(sys.argv[1]).write_text("running")
        try:
            time.sleep(120)
        except KeyboardInterrupt:
            Path(sys.argv[1]).write_text("draining")
            time.sleep(120)

    AmbientOcclusion.run = draining
    sys.exit(main(sys.argv[2:]))
""")


def test_second_sigint_stops_at_once_with_nothing_half_written(capsys, tmp_path, stage_in, cache):
    out = tmp_path / "out.usda"
    assert run_cli(capsys, "bake", stage_in, "-o", out, "--cache", cache, *FAST)[0] == 0
    before = {p.name: digest(p) for p in tmp_path.iterdir() if p.is_file()}
    process, marker = start_scripted_bake(tmp_path, DRAINING_BAKE, stage_in, out, cache)
    try:
        wait_for_state(process, marker, "running")
        process.send_signal(signal.SIGINT)
        wait_for_state(process, marker, "draining")
        started = time.monotonic()
        process.send_signal(signal.SIGINT)
        stdout, stderr = process.communicate(timeout=60)
        assert time.monotonic() - started < 30  # not the 120 s the "launches" would take
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, stderr
    assert stdout == "" and "Traceback" not in stderr
    assert stderr.strip().splitlines()[-2:] == [
        "usdbake: interrupting once the work under way returns (Ctrl-C again to stop now)",
        "usdbake: interrupted; no output was written"]
    marker.unlink()
    (tmp_path / "scripted_bake.py").unlink()
    assert {p.name: digest(p) for p in tmp_path.iterdir() if p.is_file()} == before
