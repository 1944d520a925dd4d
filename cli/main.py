"""The `usdbake` command: a thin layer over the library.

    usdbake bake IN [-o OUT] [-p NAME ...] [--set NAME.param=value ...] [--config FILE.toml]
                    [--device cpu|cuda:0] [--force] [--cache DIR] [--time T] [--json]
    usdbake plan IN [same options]     what would run, what would skip and why
    usdbake list [--json]              processors and their params
    usdbake inspect OUT [--json]       the baked data a layer holds
    usdbake sky, serve, preview, bench

Each command lives in a module of its own (bake.py: bake and plan; tables.py: list and inspect; sky.py,
serve.py, preview.py, bench.py), which adds its parser and runs it; this module parses, dispatches and
turns errors into exit codes: 0 success, 1 a processor failed, 2 bad input (one line, no traceback),
130 interrupted (Ctrl-C; nothing half-written). Every input is checked before any compute.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import warnings
from contextlib import contextmanager

from rich.console import Console
from rich.markup import escape

from ..core.errors import OutputError, UsageError
from ..core.pipeline import ProcessorFailed
from ..kernels.startup import start_warp_quietly
from . import bake, bench, preview, serve, sky, tables
from .console import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_USAGE, print_warning


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse exits 2 already; keep it to one line
        raise UsageError(message)


def make_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="usdbake", description="Precomputed lighting for OpenUSD stages.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    bake.add_parsers(commands)
    bench.add_parser(commands)
    tables.add_parsers(commands)
    sky.add_parser(commands)
    serve.add_parser(commands)
    preview.add_parser(commands)
    return parser


COMMANDS = {"bench": bench.cmd_bench, "bake": bake.cmd_bake, "plan": bake.cmd_plan, "list": tables.cmd_list,
            "inspect": tables.cmd_inspect, "preview": preview.cmd_preview, "sky": sky.cmd_sky, "serve": serve.cmd_serve}


def main(argv: list[str] | None = None) -> int:
    console = Console(stderr=True, soft_wrap=True)
    args = None
    try:
        args = make_parser().parse_args(argv)
        if hasattr(args, "device"):  # --help, list, inspect, sky, serve and bench never load Warp here
            start_warp_quietly(args.device)  # stdout stays clean for --json; no CUDA notice unless CUDA was asked for
        with _interrupts(console, args.command), warnings.catch_warnings():
            warnings.showwarning = lambda message, *_: print_warning(console, str(message))  # one line each
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


if __name__ == "__main__":
    sys.exit(main())
