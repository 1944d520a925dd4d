"""``usdbake bake`` (one stage here or in Dask chunks, several as a batch) and ``usdbake plan``."""

from __future__ import annotations

import json
import os
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from ..core import registry
from ..core.errors import UsageError
from ..stages.inputs import open_source
from .console import EXIT_FAILED, EXIT_OK, print_warning, table_console
from .options import add_stage_options, build_pipeline, params_of_run, positive_count, resolve_options
from .tables import summary_table


def add_parsers(commands) -> None:
    bake = commands.add_parser("bake", help="bake lighting into a new layer over the input")
    add_stage_options(bake, many=True)
    bake.add_argument("-o", "--output", help="output layer (default: IN.baked.usdc beside the input); for several "
                      "stages a folder (OUTDIR/ gets <stem>.baked.usdc each)")
    bake.add_argument("--list", metavar="FILE", dest="list_file",
                      help="stages to bake, one path or glob pattern per line (relative to FILE's folder)")
    bake.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                      help="Dask scheduler (default: $DASK_SCHEDULER_ADDRESS): several stages run one task each "
                           "there; one stage runs its receiver work there in chunks")
    bake.add_argument("--workers", type=positive_count, default=None, metavar="N",
                      help="processes baking stages at once without --scheduler (default: one per core)")
    bake.add_argument("--chunk-size", type=positive_count, default=None, metavar="N",
                      help="receivers (points, faces) per Dask task for one stage on --scheduler "
                           "(default: 4 tasks per worker)")
    plan = commands.add_parser("plan", help="show what would run, what would skip and why")
    add_stage_options(plan)


def cmd_plan(args, console: Console) -> int:
    from ..stages.composition import quiet_composition_warnings
    from ..stages.extract import extract_scene

    asked, params = resolve_options(args, default=())
    names = asked or sorted(registry.registry())  # plan without -p: every processor
    pipeline = build_pipeline(args, names, params, console, allow_conflicts=True)
    with quiet_composition_warnings():  # extract_scene reports each missing asset in one line
        _, stage = open_source(args.input)
    scene = extract_scene(stage, time=args.time, allow_missing=args.allow_missing, deinstance=args.deinstance)
    for warning in scene.warnings:
        print_warning(console, warning)
    for conflict in pipeline.conflicts() if asked else ():  # bake refuses these before any compute
        console.print(f"[yellow]conflict:[/yellow] {escape(conflict)}", highlight=False)
    steps = pipeline.plan(scene)
    if args.json:
        print(json.dumps([step.report() for step in steps], indent=2, default=str))
    else:
        table_console().print(summary_table([step.report() for step in steps], planned=True))
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
        pipeline = build_pipeline(args, names, params, console, chunks=chunks)
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
        print_warning(console, warning)
    if args.json:
        print(json.dumps({"output": report.output, "seconds": round(report.seconds, 3), "steps": report.steps,
                          **({"distributed": report.distributed} if report.distributed else {})},
                         indent=2, default=str))
        return
    console.print(summary_table(report.steps))
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
    params = params_of_run(params, build_pipeline(args, names, params, console))  # the checks, before any work
    batch_outputs(inputs, args.output)  # two stages writing one output: refused before any work
    if scheduler:
        connect(scheduler).close()  # an unreachable scheduler: one line, before any work
    where = f"Dask scheduler {scheduler}" if scheduler else \
        f"{max(1, min(args.workers or os.cpu_count() or 1, len(inputs)))} local processes"
    if not args.json:
        console.print(f"baking {len(inputs)} stages on {where}", highlight=False)
    with Progress(TextColumn("{task.description:<22}"), BarColumn(),
                  TextColumn("{task.completed:.0f}/{task.total:.0f}"), TimeElapsedColumn(), console=console,
                  transient=False, disable=args.json) as progress:
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
                            target=args.target,
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
