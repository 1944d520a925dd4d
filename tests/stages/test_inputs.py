"""stages.inputs, function by function: the stage a bake opens (a usdbake output bakes its source), the
human part of USD's errors and where a file stops being UTF-8, the output path check's accepted cases and
its return value, the writable-folder probe, device and cache option checks in both the command's and the
hook's spelling, and the message of a bake with nothing to write.

The refusals of bad output paths, devices and caches through ``usdbake bake`` are
tests/cli/test_cli_inputs.py's; files with bytes that are not UTF-8 through the command are
tests/catalogue/test_hostile_late_errors.py's."""

import os
from pathlib import Path

import pytest
from pxr import Sdf, Usd

import fake_processors as fakes
from usdbake.core import registry
from usdbake.core.errors import UsageError
from usdbake.core.pipeline import Step
from usdbake.stages.inputs import (check_cache_folder, check_device, check_output, check_writable_folder,
                                   empty_bake_message, not_utf8, open_source, undecodable, undecodable_asset,
                                   usd_reason)
from usdbake.stages.provenance import PROVENANCE_KEY


def write_bake_layer(path: Path, source: str) -> Path:
    """A layer usdbake could have written: provenance, and its source as first sublayer."""
    layer = Sdf.Layer.CreateNew(str(path))
    layer.customLayerData = {PROVENANCE_KEY: {"version": "0.0.test", "source": source}}
    layer.subLayerPaths.append(source)
    layer.Save()
    return path


def decode_error(data: bytes) -> UnicodeDecodeError:
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as error:
        return error
    raise AssertionError("the data is UTF-8")


class UnprintableError(Exception):
    """An error whose text cannot be made, as a Tf error quoting bytes that are not UTF-8."""

    def __str__(self):
        raise decode_error(b"\xe9")


# --- open_source ------------------------------------------------------------------------------


def test_an_input_opens_as_itself(tmp_path):
    stage_in = fakes.write_stage(tmp_path / "in.usda")
    source, stage = open_source(stage_in)
    assert Path(source) == Path(stage_in)
    assert stage.GetPrimAtPath("/World/Cube")


def test_a_bake_output_opens_its_source_through_every_bake_layer(tmp_path):
    stage_in = fakes.write_stage(tmp_path / "in.usda")
    write_bake_layer(tmp_path / "first.usda", "in.usda")
    (tmp_path / "baked").mkdir()
    second = write_bake_layer(tmp_path / "baked" / "second.usdc", "../first.usda")  # an output of an output
    source, stage = open_source(str(second))
    assert Path(source).resolve() == Path(stage_in).resolve()
    assert Path(stage.GetRootLayer().realPath).resolve() == Path(stage_in).resolve()


def test_open_source_refuses_a_missing_or_unparseable_file(tmp_path):
    with pytest.raises(UsageError) as raised:
        open_source(str(tmp_path / "missing.usda"))
    assert str(raised.value) == f"{tmp_path / 'missing.usda'}: no such file"
    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\ndef Xform \"X\" {\n")
    with pytest.raises(UsageError) as raised:
        open_source(str(bad))
    message = str(raised.value)
    assert message.startswith(f"{bad}: cannot be read as USD (") and message.endswith(")")
    assert "\n" not in message and "()" not in message


# --- USD's reasons and UTF-8 ------------------------------------------------------------------


@pytest.mark.parametrize("text, reason", [
    ("Failed : in SdfLayer::Open : 'Failed to open layer @x.usda@'", "Failed to open layer @x.usda@"),
    ('a : b : "quoted"\n  ', "quoted"),
    ("several\n lines : of\n\ttext", "of text"),  # whitespace collapsed before the split
    ("no separator at all", "no separator at all"),
])
def test_usd_reason_is_the_text_after_the_last_separator_unquoted(text, reason):
    assert usd_reason(Exception(text)) == reason


def test_usd_reason_of_an_unprintable_error_finds_the_bytes_in_the_layer(tmp_path):
    layer = tmp_path / "latin1.usda"
    layer.write_bytes(b'#usda 1.0\n(\n    doc = "caf\xe9"\n)\n')
    assert usd_reason(UnprintableError(), layer) == \
        'line 3: byte 0xe9 is not UTF-8, in: doc = "caf\\xe9"; a .usda layer is UTF-8 text'
    # a crate file (by its first bytes, whatever its name) or no path: nothing to quote from
    crate = tmp_path / "crate.usda"
    crate.write_bytes(b"PXR-USDC\xe9\x00")
    for path in (crate, None, tmp_path / "missing.usda"):
        assert usd_reason(UnprintableError(), path) == "USD's message about it is not UTF-8 text"


def test_not_utf8_is_empty_for_utf8_and_unreadable_files(tmp_path):
    good = tmp_path / "good.usda"
    good.write_text('#usda 1.0\n(\n    doc = "café ✓"\n)\n', encoding="utf-8")
    assert not_utf8(good) == ""
    assert not_utf8(tmp_path / "missing.usda") == ""
    assert not_utf8(tmp_path) == ""  # a folder cannot be read as bytes


@pytest.mark.parametrize("data, where", [
    (b"\xff first line", "line 1: byte 0xff is not UTF-8, in: \\xff first line"),
    (b"one\ntwo\n  th\xe9ree  \nfour\n", "line 3: byte 0xe9 is not UTF-8, in: th\\xe9ree"),  # stripped
    (b"one\nlast line with no newline \xc3", "line 2: byte 0xc3 is not UTF-8, in: last line with no newline \\xc3"),
    (b"ok \xc3\xa9 then \xf0\x9f\x98 cut", "line 1: byte 0xf0 0x9f 0x98 is not UTF-8, in: ok \u00e9 then "
                                           "\\xf0\\x9f\\x98 cut"),  # the good UTF-8 before it decodes
], ids=["first-byte", "third-line", "no-final-newline", "truncated-sequence"])
def test_undecodable_names_the_line_the_bytes_and_the_line_escaped(tmp_path, data, where):
    path = tmp_path / "layer.usda"
    path.write_bytes(data)
    assert not_utf8(path) == where
    assert undecodable(decode_error(data)) == where


def test_undecodable_shortens_a_long_line_to_the_width():
    line = b"x" * 100 + b"\xe9" + b"y" * 100
    where = undecodable(decode_error(b"first\n" + line + b"\nlast"), width=40)
    prefix = "line 2: byte 0xe9 is not UTF-8, in: "
    assert where == prefix + "x" * 37 + "..."
    assert len(where) == len(prefix) + 40


def test_undecodable_asset_names_the_first_text_asset_that_is_not_utf8(tmp_path):
    (tmp_path / "good.usda").write_text('#usda 1.0\ndef Xform "Good"\n{\n}\n')
    (tmp_path / "bad.usda").write_bytes(b'#usda 1.0\ndef Xform "B\xe9d"\n{\n}\n')
    root = tmp_path / "root.usda"
    root.write_text('#usda 1.0\n(\n    subLayers = [@good.usda@]\n)\n'
                    'def Xform "Prop" (\n    references = @bad.usda@</X>\n)\n{\n}\n')
    stage = Usd.Stage.Open(str(root))
    assert undecodable_asset(stage) == ('bad.usda cannot be read (line 2: byte 0xe9 is not UTF-8, in: def Xform '
                                        '"B\\xe9d"; a .usda layer is UTF-8 text)')
    assert undecodable_asset(Usd.Stage.Open(str(tmp_path / "good.usda"))) == ""


# --- check_output -----------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["out.usd", "out.usda", "out.usdc", "OUT.USDA", "new/deeper/out.usdc"])
def test_an_accepted_output_is_returned_resolved_and_nothing_is_written(tmp_path, monkeypatch, name):
    monkeypatch.chdir(tmp_path)
    stage_in = fakes.write_stage(tmp_path / "in.usda")
    out = check_output(name, stage_in)
    assert out == (tmp_path / name).resolve()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.usda"]  # no folder made, no probe file left


def test_an_earlier_usdbake_output_may_be_replaced_and_any_other_file_not(tmp_path):
    stage_in = fakes.write_stage(tmp_path / "in.usda")
    ours = write_bake_layer(tmp_path / "ours.usdc", "in.usda")
    assert check_output(str(ours), stage_in) == ours.resolve()
    theirs = tmp_path / "theirs.usda"
    theirs.write_text('#usda 1.0\n(\n    customLayerData = {\n        string usdbake = "forged"\n    }\n)\n')
    with pytest.raises(UsageError, match="exists and was not written by usdbake"):
        check_output(str(theirs), stage_in)


def test_the_used_layers_are_compared_by_real_path_and_anonymous_ones_are_ignored(tmp_path):
    stage_in = fakes.write_stage(tmp_path / "in.usda")
    stage = Usd.Stage.Open(stage_in)
    used = [*stage.GetUsedLayers(), Sdf.Layer.CreateAnonymous(".usda")]  # no real path: never the output
    assert check_output(str(tmp_path / "out.usda"), stage_in, used) == (tmp_path / "out.usda").resolve()
    # the input reached through another spelling of its path is still the input
    with pytest.raises(UsageError, match="refusing to overwrite the input layer"):
        check_output(str(tmp_path / "sub" / ".." / "in.usda"), stage_in, used)


# --- check_writable_folder --------------------------------------------------------------------


def test_a_folder_to_be_made_is_checked_at_its_nearest_existing_ancestor(tmp_path):
    check_writable_folder(tmp_path / "a" / "b" / "c", what="-o x")
    assert list(tmp_path.iterdir()) == []  # checked by trying, and the probe removed


def test_an_ancestor_that_is_a_file_is_named(tmp_path):
    (tmp_path / "plain").write_text("")
    with pytest.raises(UsageError) as raised:
        check_writable_folder(tmp_path / "plain" / "sub", what="out.usda")
    assert str(raised.value) == f"out.usda: {tmp_path / 'plain'} is a file, not a folder"


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes in read-only folders")
def test_a_folder_that_cannot_be_written_is_named_with_the_reason(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    try:
        with pytest.raises(UsageError) as raised:
            check_writable_folder(locked / "new", what="out.usda")
    finally:
        locked.chmod(0o700)
    assert str(raised.value) == f"out.usda: cannot write in {locked} (Permission denied)"


# --- device and cache options -----------------------------------------------------------------


@pytest.mark.parametrize("device", ["gpu", "CUDA:0", "cuda0", "cuda:", "cuda:-1", " cpu", 0, None])
def test_a_device_that_is_not_cpu_or_cuda_n_is_refused_in_the_callers_spelling(device):
    with pytest.raises(UsageError) as raised:
        check_device(device)
    assert str(raised.value) == f"--device {device}: expected cpu or cuda:N"
    with pytest.raises(UsageError) as raised:
        check_device(device, option="device=")  # the hook's keyword
    assert str(raised.value) == f"device={device}: expected cpu or cuda:N"


def test_cpu_is_accepted_without_asking_warp():
    check_device("cpu")


def test_a_cache_path_that_is_a_file_is_refused_and_a_missing_folder_is_not(tmp_path):
    blocker = tmp_path / "cache"
    blocker.write_text("")
    with pytest.raises(UsageError) as raised:
        check_cache_folder(blocker)
    assert str(raised.value) == f"--cache {blocker}: is a file, not a folder"
    with pytest.raises(UsageError) as raised:
        check_cache_folder(blocker, option="cache_dir=")
    assert str(raised.value) == f"cache_dir={blocker}: is a file, not a folder"
    check_cache_folder(tmp_path / "not" / "yet")  # made by the cache when it first stores
    check_cache_folder(tmp_path)
    assert not (tmp_path / "not").exists()


# --- empty_bake_message -----------------------------------------------------------------------


def step(name: str, action: str, reason: str = "") -> Step:
    cls = registry.get(name)
    return Step(name, cls(), cls.Params(), action=action, reason=reason)


def test_the_empty_bake_message_says_what_became_of_each_step():
    steps = [step("displacement_fields", "skip", "not applicable: no instanced prototypes"),
             step("instance_ao", "skip"),
             step("ambient_occlusion", "run"),
             step("radiosity", "cached")]
    assert empty_bake_message(steps) == (
        "nothing to bake: displacement_fields skipped (not applicable: no instanced prototypes); "
        "instance_ao skipped; ambient_occlusion authored nothing; radiosity authored nothing; "
        "no output was written")
    assert empty_bake_message([]) == "nothing to bake: no processors; no output was written"
