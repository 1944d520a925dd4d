"""``usdbake bench``: the benchmarks (``python -m usdbake.benchmarks``) in a process of their own.

The library never imports the benchmarks; they are installed with a source checkout, and their plots need
the 'bench' extra.
"""

from __future__ import annotations

import subprocess
import sys
from importlib.util import find_spec

from rich.console import Console

from ..core.errors import UsageError

BENCHMARKS = "usdbake.benchmarks"


def add_parser(commands) -> None:
    bench = commands.add_parser("bench", help="run time-against-error benchmarks (from a source checkout)")
    bench.add_argument("names", nargs="*", metavar="NAME", help="benchmarks to run (default: all)")
    bench.add_argument("--quick", action="store_true", help="small sweeps (< 3 minutes in all)")
    bench.add_argument("--results", metavar="DIR", help="write results and report to DIR, not the checkout")


def cmd_bench(args, console: Console) -> int:
    """``python -m usdbake.benchmarks NAME ... [--quick] [--results DIR]``; its exit status."""
    if find_spec(BENCHMARKS) is None:
        raise UsageError(f"bench: {BENCHMARKS} is not installed (the benchmarks come with a source checkout)")
    argv = [*args.names, *(["--quick"] if args.quick else []), *(["--results", args.results] if args.results else [])]
    return subprocess.run([sys.executable, "-m", BENCHMARKS, *argv], check=False).returncode
