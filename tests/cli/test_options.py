"""cli.options called directly: the --threads/--workers type, the stage options and their defaults, how -p,
--set and --config combine (resolve_options), the run build_pipeline makes and what it refuses, and
params_of_run. Each user mistake through ``usdbake bake`` is tests/cli/test_cli.py's and
test_cli_inputs.py's; here the functions' results are checked field by field."""

import argparse
import io

import pytest
from rich.console import Console

from usdbake.core.errors import UsageError
from usdbake.core.pipeline import DEFAULT_PROCESSORS
from usdbake.cli.options import add_stage_options, build_pipeline, params_of_run, positive_count, resolve_options


def parse(*argv, many: bool = False) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="usdbake-test")
    add_stage_options(parser, many=many)
    return parser.parse_args([str(a) for a in argv])


def quiet_console() -> tuple[Console, io.StringIO]:
    text = io.StringIO()
    return Console(file=text, width=200, color_system=None), text


# --- positive_count ---------------------------------------------------------------------------


@pytest.mark.parametrize("text, value", [("1", 1), ("16", 16), (" 8 ", 8), ("007", 7)])
def test_a_whole_number_of_at_least_one_is_accepted(text, value):
    assert positive_count(text) == value


@pytest.mark.parametrize("text", ["0", "-2", "1.5", "two", "", "1e3"])
def test_anything_else_is_refused_quoting_it(text):
    with pytest.raises(argparse.ArgumentTypeError) as raised:
        positive_count(text)
    assert str(raised.value).startswith(f"{text!r}: expected a whole number")
    assert str(raised.value).endswith("at least 1")


# --- add_stage_options ------------------------------------------------------------------------


def test_the_defaults_of_the_stage_options(monkeypatch, tmp_path):
    monkeypatch.delenv("USDBAKE_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    args = parse("in.usda")
    assert args.input == "in.usda"
    assert (args.processors, args.set, args.config, args.device, args.threads) == (None, [], None, "cpu", None)
    assert args.cache == str(tmp_path / "xdg" / "usdbake")
    assert (args.force, args.time, args.json, args.allow_missing, args.deinstance) == (False, None, False, False,
                                                                                       False)


def test_the_cache_default_comes_from_usdbake_cache_first(monkeypatch, tmp_path):
    monkeypatch.setenv("USDBAKE_CACHE", str(tmp_path / "shared"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert parse("in.usda").cache == str(tmp_path / "shared")


def test_options_are_parsed_to_their_types_and_repeat():
    args = parse("a.usda", "b.usda", "-p", "radiosity", "--processor", "ambient_occlusion", "--set", "x.y=1",
                 "--set", "x.z=2", "--threads", "3", "--time", "12.5", "--force", "--json", "--allow-missing",
                 "--deinstance", "--device", "cuda:0", many=True)
    assert args.input == ["a.usda", "b.usda"]  # many: a list
    assert args.processors == ["radiosity", "ambient_occlusion"] and args.set == ["x.y=1", "x.z=2"]
    assert (args.threads, args.time, args.device) == (3, 12.5, "cuda:0")
    assert args.force and args.json and args.allow_missing and args.deinstance
    assert parse(many=True).input == []  # several stages, or none (--list)


# --- resolve_options --------------------------------------------------------------------------


def test_without_options_the_default_processors_run_and_no_params_are_set():
    args = parse("in.usda")
    assert resolve_options(args) == (list(DEFAULT_PROCESSORS), {})
    assert resolve_options(args, default=()) == ([], {})  # plan asks for no default
    assert args.config_tables == []


def test_set_items_are_split_once_stripped_and_kept_as_text():
    args = parse("in.usda", "--set", " ambient_occlusion . samples =16", "--set", "daylight.times=2024-06-21T12:00=x",
                 "--set", "ambient_occlusion.samples=32")
    names, params = resolve_options(args)
    # the last --set wins; the value is text for core.params to convert, '=' inside it kept
    assert params == {"ambient_occlusion": {"samples": "32"}, "daylight": {"times": "2024-06-21T12:00=x"}}
    assert names == list(DEFAULT_PROCESSORS)


@pytest.mark.parametrize("item", ["ambient_occlusion.samples", "samples=16", ".samples=1", "ao.=1", "=1"])
def test_a_set_item_without_a_name_a_dot_a_param_and_a_value_is_refused(item):
    with pytest.raises(UsageError) as raised:
        resolve_options(parse("in.usda", "--set", item))
    assert str(raised.value) == f"--set {item!r}: expected NAME.param=value"


def test_the_config_gives_processors_and_params_and_the_command_line_adds_to_them(tmp_path):
    config = tmp_path / "bake.toml"
    config.write_text('processors = ["ambient_occlusion"]\n\n[radiosity]\ngather_rays = 16\n\n'
                      '[ambient_occlusion]\nsamples = 64\nseed = 3\n')
    args = parse("in.usda", "--config", config, "-p", "radiosity", "--set", "ambient_occlusion.seed=9")
    names, params = resolve_options(args)
    assert names == ["ambient_occlusion", "radiosity"]  # the config's first, then -p
    # TOML values keep their types; --set (text) overrides the config's value
    assert params == {"radiosity": {"gather_rays": 16}, "ambient_occlusion": {"samples": 64, "seed": "9"}}
    assert args.config_tables == ["ambient_occlusion", "radiosity"]  # sorted, without the processors key


@pytest.mark.parametrize("data, message", [
    (b"[ambient_occlusion\n", "not valid TOML ("),
    (b"# caf\xe9\nprocessors = []\n", "not valid TOML (line 1: byte 0xe9 is not UTF-8, in: # caf\\xe9; TOML is UTF-8 "
                                      "text)"),
    (b'processors = ["ambient_occlusion", 3]\n', "processors must be a list of names"),
    (b"ambient_occlusion = 16\n", "[ambient_occlusion] must be a table of parameters"),
    (b'[displacement_fields]\nencoding = 8\n', "[displacement_fields] encoding=8 is not a valid str (write it in "
                                               "quotes)"),
], ids=["syntax", "not-utf8", "processors-not-names", "not-a-table", "text-param-a-number"])
def test_a_config_that_cannot_be_used_is_refused_naming_the_file(tmp_path, data, message):
    config = tmp_path / "bake.toml"
    config.write_bytes(data)
    with pytest.raises(UsageError) as raised:
        resolve_options(parse("in.usda", "--config", config))
    assert str(raised.value).startswith(f"{config}: ")
    assert message in str(raised.value)


def test_a_config_that_cannot_be_opened_names_the_reason(tmp_path):
    with pytest.raises(UsageError) as raised:
        resolve_options(parse("in.usda", "--config", tmp_path / "none.toml"))
    assert str(raised.value) == f"{tmp_path / 'none.toml'}: No such file or directory"
    with pytest.raises(UsageError) as raised:
        resolve_options(parse("in.usda", "--config", tmp_path))
    assert str(raised.value) == f"{tmp_path}: Is a directory"


# --- build_pipeline and params_of_run ---------------------------------------------------------


def test_the_pipeline_holds_the_named_steps_with_the_options_runtime(cache):
    args = parse("in.usda", "--threads", "2", "--force", "--cache", cache, "-p", "instance_ao",
                 "--set", "displacement_fields.direction_map_size=8")
    names, params = resolve_options(args)
    console, text = quiet_console()
    pipeline = build_pipeline(args, names, params, console)
    # instance_ao pulls in what it requires, whose params may be set; they are converted from text
    assert [step.name for step in pipeline.steps] == ["displacement_fields", "instance_ao"]
    assert pipeline.steps[0].params.direction_map_size == 8
    assert (pipeline.runtime.device, pipeline.runtime.threads, pipeline.force) == ("cpu", 2, True)
    assert text.getvalue() == ""


def test_set_for_a_processor_outside_the_run_names_the_item_and_the_fix(cache):
    args = parse("in.usda", "--cache", cache, "--set", "radiosity.gather_rays=8")
    names, params = resolve_options(args)
    with pytest.raises(UsageError) as raised:
        build_pipeline(args, ["ambient_occlusion"], params, quiet_console()[0])
    assert str(raised.value) == ("--set radiosity.gather_rays=8: radiosity is not part of this run "
                                 "(ambient_occlusion); add -p radiosity")


def test_a_config_table_outside_the_run_is_a_warning_and_left_out(tmp_path, cache):
    config = tmp_path / "studio.toml"
    config.write_text("[radiosity]\ngather_rays = 16\n\n[ambient_occlusion]\nsamples = 16\n")
    args = parse("in.usda", "--cache", cache, "--config", config, "-p", "ambient_occlusion")
    names, params = resolve_options(args)
    console, text = quiet_console()
    pipeline = build_pipeline(args, names, params, console)
    assert text.getvalue().splitlines() == [f"warning: {config}: [radiosity] is ignored: radiosity is not part of "
                                            f"this run (ambient_occlusion)"]
    assert pipeline.ignored_params == ("radiosity",)
    assert params_of_run(params, pipeline) == {"ambient_occlusion": {"samples": 16}}
    assert pipeline.steps[0].params.samples == 16


def test_a_config_table_named_by_set_too_is_an_error_not_a_warning(tmp_path, cache):
    config = tmp_path / "studio.toml"
    config.write_text("[radiosity]\ngather_rays = 16\n")
    args = parse("in.usda", "--cache", cache, "--config", config, "-p", "ambient_occlusion",
                 "--set", "radiosity.gather_rays=8")
    names, params = resolve_options(args)
    with pytest.raises(UsageError, match=r"^--set radiosity\.gather_rays=8: radiosity is not part of this run"):
        build_pipeline(args, names, params, quiet_console()[0])


@pytest.mark.parametrize("argv, message", [
    (["--device", "tpu"], "--device tpu: expected cpu or cuda:N"),
    (["--cache", "{file}"], "--cache {file}: is a file, not a folder"),
], ids=["device", "cache"])
def test_a_device_or_cache_that_cannot_be_used_is_refused(tmp_path, argv, message):
    blocker = tmp_path / "blocker"
    blocker.write_text("")
    argv = [a.format(file=blocker) for a in argv]
    args = parse("in.usda", *(["--cache", str(tmp_path / "cache")] if "--cache" not in argv else []), *argv)
    resolve_options(args)
    with pytest.raises(UsageError) as raised:
        build_pipeline(args, ["ambient_occlusion"], {}, quiet_console()[0])
    assert str(raised.value) == message.format(file=blocker)


def test_params_of_run_keeps_everything_when_nothing_was_left_out(cache):
    args = parse("in.usda", "--cache", cache, "--set", "ambient_occlusion.samples=16")
    names, params = resolve_options(args)
    pipeline = build_pipeline(args, names, params, quiet_console()[0])
    assert params_of_run(params, pipeline) == params
