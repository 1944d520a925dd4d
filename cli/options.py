"""The options of the stage commands (bake, plan): the parser's arguments, processors and params from
-p, --set and --config, and the run they make (``build_pipeline``), checked before any compute."""

from __future__ import annotations

import argparse
import dataclasses
import os
import tomllib
from pathlib import Path

from rich.console import Console

from ..core import registry
from ..core.errors import UsageError
from ..core.pipeline import DEFAULT_PROCESSORS, ParamsOutsideRun, Pipeline
from ..core.runtime import Runtime
from ..stages.inputs import check_cache_folder, check_device, undecodable
from .console import print_warning


def positive_count(text: str) -> int:
    """An argparse type for --threads, --workers and --chunk-size: a whole number of at least 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number of threads, at least 1")
    return value


def add_stage_options(sub: argparse.ArgumentParser, *, many: bool = False) -> None:
    """The input and the run's options, shared by bake and plan."""
    if many:
        sub.add_argument("input", nargs="*", help="input stages (.usd, .usda, .usdc; glob patterns too); a "
                         "usdbake output bakes its source; several stages bake as a batch, one task each")
    else:
        sub.add_argument("input", help="input stage (.usd, .usda, .usdc); a usdbake output bakes its source")
    sub.add_argument("-p", "--processor", action="append", dest="processors", metavar="NAME",
                     help=f"processor to run (repeatable; default: {', '.join(DEFAULT_PROCESSORS)})")
    sub.add_argument("--set", action="append", default=[], metavar="NAME.param=value",
                     help="set a processor parameter (repeatable)")
    sub.add_argument("--config", metavar="FILE.toml", help="processors and params from a TOML file")
    sub.add_argument("--target", choices=("vertex", "texture", "both"), default=None,
                     help="where per-surface results go: vertex primvars (each processor's default), lightmap "
                          "textures on the asset's UVs (no mesh changed), or both; a processor's own "
                          "--set NAME.target=... wins")
    sub.add_argument("--device", default="cpu", help="Warp device: cpu (default) or cuda:N")
    sub.add_argument("--threads", type=positive_count, default=None, metavar="N",
                     help="CPU threads for ray casting (default: every core)")
    sub.add_argument("--cache", metavar="DIR", default=os.environ.get("USDBAKE_CACHE", _default_cache()),
                     help="result cache folder (default: $USDBAKE_CACHE or ~/.cache/usdbake)")
    sub.add_argument("--force", action="store_true", help="re-run even when results are up to date")
    sub.add_argument("--time", type=float, default=None, help="time code to read (default: default time)")
    sub.add_argument("--json", action="store_true", help="machine-readable output on stdout")
    sub.add_argument("--allow-missing", action="store_true",
                     help="bake without missing sublayers, references and payloads (a warning each)")
    sub.add_argument("--deinstance", action="store_true",
                     help="bake natively instanced meshes as ordinary ones, per vertex (the bake layer sets "
                          "instanceable = false on their instances)")


def _default_cache() -> str:
    return str(Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "usdbake")


def resolve_options(args, default=DEFAULT_PROCESSORS) -> tuple[list[str], dict[str, dict]]:
    """(processor names, {processor: {param: value}}) from --config, then --set and -p; the config's tables
    are kept in ``args.config_tables``."""
    processors: list[str] = []
    params: dict[str, dict] = {}
    args.config_tables = []
    if args.config:
        try:
            with open(args.config, "rb") as handle:
                config = tomllib.load(handle)
        except OSError as error:
            raise UsageError(f"{args.config}: {error.strerror}") from None
        except tomllib.TOMLDecodeError as error:
            raise UsageError(f"{args.config}: not valid TOML ({error})") from None
        except UnicodeDecodeError as error:  # tomllib decodes the file as UTF-8 before it parses
            raise UsageError(f"{args.config}: not valid TOML ({undecodable(error)}; TOML is UTF-8 text)") from None
        listed = config.pop("processors", [])
        if not isinstance(listed, list) or not all(isinstance(name, str) for name in listed):
            raise UsageError(f"{args.config}: processors must be a list of names, e.g. "
                             f"processors = [\"ambient_occlusion\"] (got {listed!r})")
        processors += listed
        for name, values in config.items():
            if not isinstance(values, dict):
                raise UsageError(f"{args.config}: [{name}] must be a table of parameters")
            _check_config_types(args.config, name, values)
            params.setdefault(name, {}).update(values)
        args.config_tables = sorted(config)
    for item in args.set:
        key, sep, value = item.partition("=")
        name, dot, param_name = key.partition(".")
        if not sep or not dot or not name or not param_name:
            raise UsageError(f"--set {item!r}: expected NAME.param=value")
        params.setdefault(name.strip(), {})[param_name.strip()] = value
    processors += args.processors or []
    return processors or list(default), params


def _check_config_types(config: str, name: str, values: dict) -> None:
    """TOML values must have their parameter's type; core.params checks bool, int and float, and a
    text parameter given a number or a list is refused here (it would fail inside the processor)."""
    fields = {f.name: f for f in dataclasses.fields(registry.get(name).Params)}
    for key, value in values.items():
        field = fields.get(key)
        if field is not None and isinstance(field.default, str) and not isinstance(value, str):
            raise UsageError(f"{config}: [{name}] {key}={value!r} is not a valid str (write it in quotes)")


def _set_target(item: str) -> str:
    """The processor a ``--set NAME.param=value`` item names."""
    return item.partition("=")[0].partition(".")[0].strip()


def build_pipeline(args, names: list[str], params: dict[str, dict], console: Console, *, chunks=None,
                   allow_conflicts: bool = False) -> Pipeline:
    """The command's run: the pipeline of ``names`` with the one run-time object of ``args`` (device,
    threads, chunk runner). Refused before any compute (``Pipeline.build`` checks the params): --set for a
    processor that is not part of the run, a Warp device that does not exist, a cache folder that cannot
    be written. Config tables for processors not run are a warning and left out (a shared config file may
    hold settings for every processor)."""
    from ..kernels.tracer import Tracer  # here, not at import: `usdbake --help` loads no Warp

    named_by_set = {_set_target(item) for item in args.set}
    runtime = Runtime(Tracer.from_scene, device=args.device, threads=args.threads, chunks=chunks)
    try:
        pipeline = Pipeline.build(names, params, runtime=runtime, cache_dir=args.cache, force=args.force,
                                  target=args.target,
                                  allow_conflicts=allow_conflicts,
                                  ignorable=[name for name in args.config_tables if name not in named_by_set])
    except ParamsOutsideRun as error:
        item = next(item for item in args.set if _set_target(item) == error.processor)
        raise UsageError(f"--set {item}: {error.processor} is not part of this run ({', '.join(error.running)}); "
                         f"add -p {error.processor}") from None
    running = ", ".join(step.name for step in pipeline.steps)
    for name in pipeline.ignored_params:
        print_warning(console, f"{args.config}: [{name}] is ignored: {name} is not part of this run ({running})")
    check_device(args.device)
    if args.cache:
        check_cache_folder(args.cache)
    return pipeline


def params_of_run(params: dict[str, dict], pipeline: Pipeline) -> dict[str, dict]:
    """``params`` without the config tables the run left out (``Pipeline.ignored_params``)."""
    return {name: values for name, values in params.items() if name not in pipeline.ignored_params}
