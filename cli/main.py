"""The `usdbake` command: a thin layer over the library.

    usdbake bake IN [-o OUT] [-p NAME ...] [--set NAME.param=value ...] [--config FILE.toml]
                    [--device cpu|cuda:0] [--force] [--cache DIR] [--time T] [--json]
    usdbake plan IN [same options]     what would run, what would skip and why
    usdbake list [--json]              processors and their params
    usdbake inspect OUT [--json]       the baked data a layer holds

Exit codes: 0 success, 1 a processor failed, 2 bad input (one line, no traceback),
130 interrupted (Ctrl-C; nothing half-written). Every input is checked before any compute.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import signal
import sys
import threading
import tomllib
import warnings
from contextlib import contextmanager
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from .. import init_warp
from ..core import registry
from ..core.errors import OutputError, UsageError
from ..core.params import TABLE_COLUMNS
from ..core.pipeline import DEFAULT_PROCESSORS, Pipeline, ProcessorFailed
from ..stages.inputs import check_cache_folder, check_device, open_source, undecodable

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse exits 2 already; keep it to one line
        raise UsageError(message)


def _number(low: float, high: float):
    """An argparse type: a finite number in [low, high] (NaN, inf and out-of-range values are one-line errors).
    Irradiance bounds: the solar constant is 1361 W/m^2, so no measured DNI exceeds 1500 nor DHI 1000."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not low <= value <= high:  # False for NaN too
            raise argparse.ArgumentTypeError(f"{text} is outside {low:g}..{high:g}")
        return value
    return parse


def _instant(text: str) -> str:
    """An argparse type: an ISO 8601 date-time (``2026-06-21T12:00``), checked here rather than after the stage
    is read."""
    from ..stages.sky_dome import check_sky_time

    try:
        check_sky_time(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return text


def make_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="usdbake", description="Precomputed lighting for OpenUSD stages.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    def stage_options(sub, many=False):
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
        sub.add_argument("--device", default="cpu", help="Warp device: cpu (default) or cuda:N")
        sub.add_argument("--threads", type=_thread_count, default=None, metavar="N",
                         help="CPU threads for ray casting (default: all cores)")
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

    bake = commands.add_parser("bake", help="bake lighting into a new layer over the input")
    stage_options(bake, many=True)
    bake.add_argument("-o", "--output", help="output layer (default: IN.baked.usdc beside the input); for several "
                      "stages a folder (OUTDIR/ gets <stem>.baked.usdc each)")
    bake.add_argument("--list", metavar="FILE", dest="list_file",
                      help="stages to bake, one path or glob pattern per line (relative to FILE's folder)")
    bake.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                      help="Dask scheduler (default: $DASK_SCHEDULER_ADDRESS): several stages run one task each "
                           "there; one stage runs its receiver work there in chunks")
    bake.add_argument("--workers", type=_thread_count, default=None, metavar="N",
                      help="processes baking stages at once without --scheduler (default: one per core)")
    bake.add_argument("--chunk-size", type=_thread_count, default=None, metavar="N",
                      help="receivers (points, faces) per Dask task for one stage on --scheduler "
                           "(default: 4 tasks per worker)")
    plan = commands.add_parser("plan", help="show what would run, what would skip and why")
    stage_options(plan)
    bench = commands.add_parser("bench", help="run time-against-error benchmarks (from a source checkout)")
    bench.add_argument("names", nargs="*", metavar="NAME", help="benchmarks to run (default: all)")
    bench.add_argument("--quick", action="store_true", help="small sweeps (< 3 minutes in all)")
    bench.add_argument("--results", metavar="DIR", help="write results and report to DIR, not the checkout")
    listing = commands.add_parser("list", help="list processors and their parameters")
    listing.add_argument("names", nargs="*", metavar="NAME", help="processors to list (default: all)")
    listing.add_argument("--json", action="store_true")
    inspect = commands.add_parser("inspect", help="show the baked data a layer holds")
    inspect.add_argument("output")
    inspect.add_argument("--json", action="store_true")
    sky = commands.add_parser("sky", help="write a layer over the input with a sky model as a DomeLight and a sun "
                              "DistantLight, so radiosity, probes and grids are daylit")
    sky.add_argument("input")
    sky.add_argument("-o", "--output", required=True, help="the sky layer (.usd, .usda or .usdc); a lat-long "
                     ".exr is written beside it")
    sky.add_argument("--weather", help="typical-year weather file (.epw, TMY3 .csv): the place, and the Perez "
                     "sky of the hour holding --time (its year ignored)")
    sky.add_argument("--model", choices=("preetham", "perez", "overcast"),
                     help="sky model (default: perez with --weather, else preetham)")
    sky.add_argument("--time", default="2026-06-21T12:00", type=_instant, help="ISO 8601 local standard time")
    sky.add_argument("--latitude", type=_number(-90, 90), help=f"degrees north (default {SKY_SITE[0]}, or the "
                     "weather file's)")
    sky.add_argument("--longitude", type=_number(-180, 180), help=f"degrees east (default {SKY_SITE[1]}, or the "
                     "weather file's)")
    sky.add_argument("--timezone", type=_number(-12, 14), help=f"hours east of UTC (default {SKY_SITE[2]:g}, or "
                     "the weather file's)")
    sky.add_argument("--north", type=_number(-360, 360), default=0.0, help="degrees from the stage's default north")
    sky.add_argument("--turbidity", type=_number(1, 64), default=3.0, help="Preetham turbidity")
    sky.add_argument("--dni", type=_number(0, 1500), help="Perez: direct normal irradiance, W/m^2 (default 600, "
                     "or the weather file's)")
    sky.add_argument("--dhi", type=_number(0, 1000), help="Perez: diffuse horizontal irradiance, W/m^2 (default "
                     "150, or the weather file's)")
    sky.add_argument("--ground-albedo", type=_number(0, 1), default=0.2, help="the grey ground below the horizon")
    serve = commands.add_parser("serve", help="serve a baked stage's progressive mesh and irradiance-grid streams "
                                "over HTTP (range requests, ETags)")
    serve.add_argument("input", help="a baked stage (usdbake bake -p progressive_mesh and/or -p irradiance_grid)")
    serve.add_argument("--host", default="127.0.0.1", help="address to listen on (default: this machine only)")
    serve.add_argument("--port", type=int, default=8642)
    serve.add_argument("--max-clients", type=int, default=64, help="stream requests handled at once; more get 503")
    serve.add_argument("--max-per-peer", type=int, default=8, help="stream requests one address may hold once half "
                       "of --max-clients are taken")
    preview = commands.add_parser("preview", help="render a (baked) stage to an image: AO, daylight, irradiance")
    preview.add_argument("input", help="stage to render, e.g. a usdbake output")
    preview.add_argument("-o", "--output", required=True, help="image to write (.png, or .exr for float data)")
    view = preview.add_mutually_exclusive_group()
    view.add_argument("--camera", metavar="PATH", help="UsdGeom.Camera prim to look through")
    view.add_argument("--auto-camera", action="store_true", help="three-quarter view framing the stage (default)")
    preview.add_argument("--orbit", nargs=2, type=float, metavar=("AZ", "EL"),
                         help="auto camera azimuth and elevation in degrees (default: best of four views)")
    preview.add_argument("--channel", metavar="NAME", help="baked primvar to show: ao, daylight, irradiance, "
                         "A+B, NAME[k], or a full primvars:... name (default: albedo only)")
    preview.add_argument("--time", type=float, default=None, help="time code (default: default time)")
    preview.add_argument("--size", default="640x480", metavar="WxH", help="image size (default 640x480)")
    preview.add_argument("--exposure", type=float, default=None, metavar="EV",
                         help="exposure in stops for shaded channels (default: automatic)")
    preview.add_argument("--style", default="auto", choices=("auto", "falsecolor", "shaded"),
                         help="false colour for scalars, shading for colours (auto) or forced")
    preview.add_argument("--range", nargs=2, type=float, metavar=("LO", "HI"), help="false-colour scale range")
    preview.add_argument("--no-legend", action="store_true", help="no legend bar beside false colour")
    preview.add_argument("--wire", action="store_true", help="overlay the edges of the authored polygons")
    preview.add_argument("--probes", action="store_true", help="draw LightProbeCloud probes as spheres")
    preview.add_argument("--grid", action="store_true", help="draw IrradianceVectorGrid vertices as spheres")
    preview.add_argument("--compare", metavar="A.png", help="write [A | this | difference] and print the RMS")
    preview.add_argument("--device", default="cpu", help="Warp device: cpu (default) or cuda:N")
    preview.add_argument("--json", action="store_true", help="machine-readable report on stdout")
    return parser


def main(argv: list[str] | None = None) -> int:
    console = Console(stderr=True, soft_wrap=True)
    args = None
    try:
        args = make_parser().parse_args(argv)
        if hasattr(args, "device") or args.command == "bench":  # --help, list and inspect never load Warp
            _quiet_warp(getattr(args, "device", "cpu"))
        with _interrupts(console, args.command), warnings.catch_warnings():
            warnings.showwarning = lambda message, *_: console.print(  # one line each (a CacheWarning, ...)
                f"[yellow]warning:[/yellow] {escape(str(message))}", highlight=False)
            return COMMANDS[args.command](args, console)
    except KeyboardInterrupt:  # save_atomically removed its temporary files on the way out
        console.print(f"[red]{_interrupted_line(getattr(args, 'command', ''))}[/red]", highlight=False)
        return EXIT_INTERRUPTED
    except UsageError as error:
        console.print(f"[red]usdbake: error:[/red] {escape(str(error))}", highlight=False)
        return EXIT_USAGE
    except ProcessorFailed as error:
        console.print(f"[red]usdbake: {escape(str(error))}[/red]; no output was written", highlight=False)
        return EXIT_FAILED
    except OutputError as error:
        console.print(f"[red]usdbake: error:[/red] {escape(str(error))}", highlight=False)
        return EXIT_FAILED


def table_console() -> Console:
    """Where the tables of list, plan and inspect go: stdout (``usdbake list | grep weather``); progress,
    warnings and errors go to the stderr console ``main`` makes."""
    return Console(soft_wrap=True)


def _quiet_warp(device: str) -> None:
    """Keep stdout clean for --json (Warp logs info messages such as module load times to stdout;
    our own progress goes to stderr) and start Warp with no CUDA notice unless CUDA was asked for."""
    import warp as wp

    if hasattr(wp, "LOG_WARNING"):
        wp.config.log_level = wp.LOG_WARNING
    else:  # Warp < 1.14: config.quiet
        wp.config.quiet = True
    init_warp(device)


def _interrupted_line(command: str) -> str:
    return "usdbake: interrupted" + ("; no output was written" if command == "bake" else "")


@contextmanager
def _interrupts(console: Console, command: str):
    """Ctrl-C once: KeyboardInterrupt, which stops the command once the kernel launches under way
    return (a CPU launch cannot be stopped midway) and removes the bake's temporary files. Ctrl-C
    again: exit 130 at once; outputs are only ever renamed into place whole, and the temporary
    files a hard exit leaves are removed by the next bake into the same output. Left alone when
    SIGINT is ignored (a background job) or off the main thread (a host application's thread)."""
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        yield
        return
    pressed = 0

    def on_sigint(signum, frame):
        nonlocal pressed
        pressed += 1
        if pressed == 1:
            console.print("usdbake: interrupting once the work under way returns (Ctrl-C again to stop now)",
                          highlight=False)
            raise KeyboardInterrupt
        console.print(f"[red]{_interrupted_line(command)}[/red]", highlight=False)
        sys.stderr.flush()
        os._exit(EXIT_INTERRUPTED)

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _default_cache() -> str:
    return str(Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "usdbake")


# ---------------------------------------------------------------------------
# Options -> (processors, params)


def resolve_options(args, default=DEFAULT_PROCESSORS) -> tuple[list[str], dict[str, dict]]:
    processors: list[str] = []
    params: dict[str, dict] = {}
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


def check_run_options(args, pipeline: Pipeline, console: Console) -> None:
    """Refuse, before any compute, options that could only fail or be ignored later: --set for a
    processor that is not part of the run, a Warp device that does not exist, a cache folder that
    cannot be written. Config tables for processors not run are a warning (a shared config file
    may hold settings for every processor)."""
    running = [step.name for step in pipeline.steps]
    for item in args.set:
        name = item.partition("=")[0].partition(".")[0].strip()
        if name not in running:
            raise UsageError(f"--set {item}: {name} is not part of this run ({', '.join(running)}); "
                             f"add -p {name}")
    for name in getattr(args, "config_tables", []):
        if name not in running:
            message = f"{args.config}: [{name}] is ignored: {name} is not part of this run ({', '.join(running)})"
            console.print(f"[yellow]warning:[/yellow] {escape(message)}", highlight=False)
    check_device(args.device)
    if args.cache:
        check_cache_folder(args.cache)


def _thread_count(text: str) -> int:
    """--threads N: a whole number of at least 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number of threads, at least 1")
    return value


# ---------------------------------------------------------------------------
# Commands


def cmd_plan(args, console: Console) -> int:
    from ..stages.composition import quiet_composition_warnings
    from ..stages.extract import extract_scene

    asked, params = resolve_options(args, default=())
    names = asked or sorted(registry.registry())  # plan without -p: every processor
    pipeline = Pipeline.build(names, params, device=args.device, cache_dir=args.cache, force=args.force,
                              threads=args.threads, allow_conflicts=True)
    check_run_options(args, pipeline, console)
    with quiet_composition_warnings():  # extract_scene reports each missing asset in one line
        _, stage = open_source(args.input)
    scene = extract_scene(stage, time=args.time, allow_missing=args.allow_missing, deinstance=args.deinstance)
    for warning in scene.warnings:
        console.print(f"[yellow]warning:[/yellow] {escape(warning)}", highlight=False)
    for conflict in pipeline.conflicts() if asked else ():  # bake refuses these before any compute
        console.print(f"[yellow]conflict:[/yellow] {escape(conflict)}", highlight=False)
    steps = pipeline.plan(scene)
    if args.json:
        print(json.dumps([step.report() for step in steps], indent=2, default=str))
    else:
        table_console().print(_summary_table([step.report() for step in steps], planned=True))
        if all(step.action == "skip" for step in steps):
            console.print("nothing to bake: every processor would be skipped; bake would write no output",
                          highlight=False)
    return EXIT_OK


def cmd_bake(args, console: Console) -> int:
    from ..farm.batch import expand_inputs
    from ..farm.cluster import scheduler_address

    if not args.input and not args.list_file:
        raise UsageError("bake: give a stage to bake (or --list FILE)")
    inputs = expand_inputs(args.input, args.list_file)
    scheduler = scheduler_address(args.scheduler)
    into_folder = bool(args.output) and args.output.endswith(("/", os.sep))  # -o OUTDIR/ (a bare folder name
    # for one stage stays the "is a folder" error: a typo must not turn into a batch)
    if len(inputs) > 1 or args.list_file or into_folder:
        return _bake_batch(args, inputs, scheduler, console)
    if args.workers is not None:
        raise UsageError("--workers is for several stages; one stage uses --threads")
    return _bake_one(args, inputs[0], scheduler, console)


def _bake_one(args, input_path: str, scheduler: str | None, console: Console) -> int:
    """One stage, here; with a scheduler its receiver work runs there in chunks (usdbake.farm.chunks)."""
    from ..farm.chunks import DaskChunks
    from ..farm.cluster import connect
    from ..stages.bake_file import bake_file

    if args.chunk_size is not None and not scheduler:
        raise UsageError("--chunk-size is for --scheduler (receiver work in Dask tasks)")
    names, params = resolve_options(args)
    client = connect(scheduler) if scheduler else None  # an unreachable scheduler: one line, before any work
    try:
        chunks = DaskChunks(client, chunk_size=args.chunk_size) if client else None
        pipeline = Pipeline.build(names, params, device=args.device, cache_dir=args.cache, force=args.force,
                                  threads=args.threads, chunks=chunks)
        check_run_options(args, pipeline, console)
        progress = Progress(TextColumn("{task.description:<22}"), BarColumn(), TextColumn("{task.percentage:>5.1f}%"),
                            TimeElapsedColumn(), console=console, transient=False, disable=args.json)
        tasks: dict = {}

        def on_progress(name: str, fraction: float) -> None:
            if name not in tasks:  # a bar per phase and processor, from its first report
                tasks[name] = progress.add_task(name, total=1.0)
            progress.update(tasks[name], completed=fraction)

        started: list[bool] = []

        def start_progress() -> None:  # once the input is checked: a bad input prints its one line alone
            progress.start()
            started.append(True)

        try:
            report = bake_file(input_path, args.output, pipeline, time_code=args.time,
                               allow_missing=args.allow_missing, deinstance=args.deinstance,
                               on_progress=on_progress, before_compute=start_progress)
        finally:
            if started:
                progress.stop()
        where = chunks.description if chunks else ""
    finally:
        if client is not None:
            client.close()
    _print_bake(args, report, where, console)
    return EXIT_OK


def _print_bake(args, report, where: str, console: Console) -> None:
    """The bake's warnings, then its summary table and messages (or --json)."""
    for warning in report.warnings:
        console.print(f"[yellow]warning:[/yellow] {escape(warning)}", highlight=False)
    if args.json:
        print(json.dumps({"output": report.output, "seconds": round(report.seconds, 3), "steps": report.steps,
                          **({"distributed": report.distributed} if report.distributed else {})},
                         indent=2, default=str))
        return
    console.print(_summary_table(report.steps))
    for message in report.messages:
        console.print(message, highlight=False)
    if report.deinstanced:
        console.print(f"de-instanced {report.deinstanced} native instances (instanceable = false in the bake layer) "
                      f"to hold per-vertex results", highlight=False)
    if report.distributed:
        sent = report.distributed
        console.print(f"on {where}: {sent['tasks']} tasks, {sent['item_bytes'] / 2**20:.1f} MB of receivers sent, "
                      f"{sent['result_bytes'] / 2**20:.1f} MB of results back, scene "
                      f"{sent['scene_bytes'] / 2**20:.1f} MB to each worker", highlight=False)
    console.print(f"wrote {report.output} in {report.seconds:.2f} s", highlight=False)


def _bake_batch(args, inputs: list[str], scheduler: str | None, console: Console) -> int:
    """Several stages, one task each (usdbake.farm.batch); exit 1 when some failed."""
    from ..farm.batch import bake_many, batch_outputs
    from ..farm.cluster import connect

    if args.output and Path(args.output).exists() and not Path(args.output).is_dir():
        raise UsageError(f"-o {args.output}: several stages bake into a folder, and this is a file")
    if args.chunk_size is not None:
        raise UsageError("--chunk-size is for one stage; a batch runs one task per stage")
    names, params = resolve_options(args)
    pipeline = Pipeline.build(names, params, device=args.device, cache_dir=args.cache, force=args.force,
                              threads=args.threads)
    check_run_options(args, pipeline, console)
    batch_outputs(inputs, args.output)  # two stages writing one output: refused before any work
    if scheduler:
        connect(scheduler).close()  # an unreachable scheduler: one line, before any work
    where = f"Dask scheduler {scheduler}" if scheduler else \
        f"{max(1, min(args.workers or os.cpu_count() or 1, len(inputs)))} local processes"
    if not args.json:
        console.print(f"baking {len(inputs)} stages on {where}", highlight=False)
    with Progress(TextColumn("{task.description:<22}"), BarColumn(), TextColumn("{task.completed:.0f}/{task.total:.0f}"),
                  TimeElapsedColumn(), console=console, transient=False, disable=args.json) as progress:
        overall = progress.add_task(f"{len(inputs)} stages", total=len(inputs))

        def on_outcome(outcome) -> None:
            progress.advance(overall)
            colour = "red" if outcome.status == "failed" else "green"
            finished = f" -> {escape(outcome.output)} ({outcome.seconds:.2f} s)" if outcome.report else ""
            progress.console.print(f"[{colour}]{outcome.status}[/{colour}] {escape(outcome.input)}{finished}",
                                   highlight=False)

        results = bake_many(inputs, args.output, processors=names, params=params, device=args.device,
                            cache_dir=args.cache, force=args.force, threads=args.threads, time=args.time,
                            allow_missing=args.allow_missing, deinstance=args.deinstance, scheduler=scheduler,
                            workers=args.workers, on_outcome=None if args.json else on_outcome)
    failed = [outcome for outcome in results if outcome.status == "failed"]
    if args.json:
        print(json.dumps([{"input": o.input, "output": o.output, "status": o.status, "error": o.error,
                           "seconds": round(o.seconds, 3), "steps": o.report.steps if o.report else []}
                          for o in results], indent=2, default=str))
        return EXIT_FAILED if failed else EXIT_OK
    table = Table(title="batch summary")
    for column in ("stage", "status", "time (s)", "output or error"):
        table.add_column(column, overflow="fold", justify="right" if column == "time (s)" else "left")
    for o in results:
        table.add_row(o.input, o.status, f"{o.seconds:.2f}" if o.report else "", o.output if o.report else o.error)
    console.print(table)
    console.print(f"{len(results) - len(failed)} of {len(results)} stages baked"
                  + (f", {len(failed)} failed" if failed else ""), highlight=False)
    return EXIT_FAILED if failed else EXIT_OK


def _summary_table(steps: list[dict], *, planned: bool = False) -> Table:
    """Processor, action and reason (``Step.report()`` rows); after a bake also time and ray throughput."""
    table = Table(title="plan" if planned else "bake summary")
    columns = ("processor", "action", "reason") if planned else \
        ("processor", "action", "reason", "time (s)", "Mrays/s")
    for column in columns:
        table.add_column(column, justify="right" if column in ("time (s)", "Mrays/s") else "left")
    labels = {"run": "will run" if planned else "ran", "cached": "up to date", "skip": "skipped"}
    for step in steps:
        row = [step["processor"], labels[step["action"]], step["reason"]]
        if not planned:
            row += [f"{step['seconds']:.2f}", f"{step['mrays_per_s']:.2f}" if step["mrays_per_s"] else ""]
        table.add_row(*row)
    return table


def cmd_list(args, console: Console) -> int:
    """Every processor and its parameters: ``Params.describe()`` rows for --json, ``Params.table_rows()``
    (the same cells as the docs' generated tables) for people."""
    names = getattr(args, "names", None)  # `usdbake list [NAME ...]`, once the parser takes names
    processors = [(name, registry.get(name)) for name in names] if names else sorted(registry.registry().items())
    if args.json:
        rows = [{"name": name, "summary": cls.summary, "requires": [_product_name(p) for p in cls.requires],
                 "provides": [_product_name(p) for p in cls.provides], "params": cls.Params.describe()}
                for name, cls in processors]
        print(json.dumps(rows, indent=2, default=str))
        return EXIT_OK
    for name, cls in processors:
        table = Table(title=f"{name}: {cls.summary}", title_justify="left")
        for column in TABLE_COLUMNS:
            table.add_column(column, overflow="fold")  # a long default (a time interval) wraps, never cut
        for cells in cls.Params.table_rows():
            table.add_row(*cells)
        table_console().print(table)
    return EXIT_OK


def _product_name(product) -> str:
    """A product as --json names it: a product type by its class name, a plain string as it is."""
    return product if isinstance(product, str) else getattr(product, "__name__", str(product))


def cmd_inspect(args, console: Console) -> int:
    from ..stages.inspect import inspect_layer

    report = inspect_layer(args.output)
    if args.json:
        print(json.dumps(report, indent=2, default=str))
        return EXIT_OK
    out = table_console()
    out.print(f"{args.output}: baked by usdbake {report['provenance'].get('version', '?')} "
              f"from {report['provenance'].get('source', '?')}", highlight=False)
    for sidecar in report["provenance"].get("sidecars", []):
        out.print(f"sidecar file: {sidecar}", highlight=False)
    table = Table()
    table.add_column("property", overflow="fold", ratio=1)  # long prim paths wrap instead of being cut
    for column in ("type", "interpolation", "elementSize", "values", "time samples"):
        table.add_column(column, no_wrap=True)
    for row in report["properties"]:
        table.add_row(row["path"], row["type"], row["interpolation"], str(row["element_size"]),
                      str(row["values"]), str(row["time_samples"]))
    out.print(table)
    return EXIT_OK


def cmd_preview(args, console: Console) -> int:
    from ..preview.compose import parse_size, preview

    report = preview(args.input, args.output, camera=args.camera, channel=args.channel, time=args.time,
                     size=parse_size(args.size), exposure=args.exposure, style=args.style,
                     value_range=tuple(args.range) if args.range else None, legend=not args.no_legend,
                     wire=args.wire, probes=args.probes, grid=args.grid, compare=args.compare,
                     orbit=tuple(args.orbit) if args.orbit else None, device=args.device)
    report.pop("image", None)
    if args.json:
        print(json.dumps(report, indent=2, default=str))
        return EXIT_OK
    for message in report["messages"]:
        console.print(f"[yellow]note:[/yellow] {message}", highlight=False)
    if "rms" in report:
        print(f"RMS difference: {report['rms']:.6f}")
    console.print(f"wrote {args.output} ({report['mode']}, camera {report['camera']}) in "
                  f"{report['seconds']:.2f} s", highlight=False)
    return EXIT_OK


def cmd_bench(args, console: Console) -> int:
    """Run usdbake.benchmarks (installed with the package; its plots need the 'bench' extra)."""
    from ..benchmarks.__main__ import main as bench_main

    argv = [*args.names, *(["--quick"] if args.quick else []), *(["--results", args.results] if args.results else [])]
    return bench_main(argv)


SKY_SITE = (41.98, 2.82, 1.0)
"""``usdbake sky``'s place without --weather or --latitude/--longitude/--timezone (Girona)."""


def cmd_sky(args, console: Console) -> int:
    from ..stages.sky_dome import make_sky, weather_hour

    site = dict(zip(("latitude", "longitude", "timezone"), SKY_SITE))
    irradiance = {"direct_normal": 600.0, "diffuse_horizontal": 150.0}
    model = args.model or ("perez" if args.weather else "preetham")
    hour = ""
    if args.weather:
        site, irradiance, hour = weather_hour(args.weather, args.time)
        if model != "perez":
            raise UsageError(f"--model {model} --weather {args.weather}: a weather file gives a Perez sky "
                             f"(its direct and diffuse irradiance); drop --model or use --model perez")
    for key in site:
        given = getattr(args, key)
        if given is not None:
            if args.weather and abs(given - site[key]) > 1e-6:
                raise UsageError(f"--{key} {given:g} disagrees with {args.weather}'s {site[key]:g}: the weather "
                                 f"file gives the place; drop --{key}")
            site[key] = given
    for key, option in (("direct_normal", "dni"), ("diffuse_horizontal", "dhi")):
        if getattr(args, option) is not None:
            if args.weather:
                raise UsageError(f"--{option} with --weather: the weather file gives the irradiance; drop --{option}")
            irradiance[key] = getattr(args, option)
    if not -90.0 <= site["latitude"] <= 90.0:
        raise UsageError(f"--latitude {site['latitude']}: outside -90..90")
    if not -12.0 <= site["timezone"] <= 14.0:
        raise UsageError(f"--timezone {site['timezone']}: not a time zone (-12..14 hours)")
    source, _ = open_source(args.input)
    written, sky = make_sky(source, args.output, model, args.time, **site, north=args.north,
                            turbidity=args.turbidity, **irradiance, ground_albedo=args.ground_albedo)
    sun = float(sky.sun_irradiance[1]) if sky.sun_world is not None else 0.0
    print(f"wrote {written[0]} and {written[1]}: {hour}diffuse horizontal {sky.diffuse_horizontal:.1f} W/m^2, "
          f"sun {sun:.1f} W/m^2 normal")
    return EXIT_OK


def cmd_serve(args, console: Console) -> int:
    from ..stages.serve import Limits, serve

    if args.max_clients < 1:
        raise UsageError(f"--max-clients {args.max_clients}: at least 1")
    if not 0 <= args.port <= 65535:
        raise UsageError(f"--port {args.port}: not a TCP port (0..65535)")
    if args.max_per_peer < 1:
        raise UsageError(f"--max-per-peer {args.max_per_peer}: at least 1")
    serve(args.input, host=args.host, port=args.port,
          limits=Limits(max_clients=args.max_clients, max_per_peer=args.max_per_peer),
          log=lambda line: console.print(line, highlight=False))
    return EXIT_OK


COMMANDS = {"bench": cmd_bench, "bake": cmd_bake, "plan": cmd_plan, "list": cmd_list, "inspect": cmd_inspect,
            "preview": cmd_preview, "sky": cmd_sky, "serve": cmd_serve}

if __name__ == "__main__":
    sys.exit(main())
