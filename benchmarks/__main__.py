"""python -m usdbake.benchmarks [NAME ...] [--quick] [--report-only]"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import time
from pathlib import Path

from . import harness, report


def available() -> dict[str, object]:
    """bench_<name>.py modules in this folder, by NAME."""
    modules = {}
    for info in pkgutil.iter_modules([str(harness.ROOT)]):
        if info.name.startswith("bench_"):
            module = importlib.import_module(f"{__package__}.{info.name}")
            modules[module.NAME] = module
    return modules


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m usdbake.benchmarks", description=__doc__)
    parser.add_argument("names", nargs="*", help="benchmarks to run (default: all)")
    parser.add_argument("--quick", action="store_true", help="small sweeps for CI (< 3 minutes in all)")
    parser.add_argument("--report-only", action="store_true", help="only regenerate docs/benchmarks.md")
    parser.add_argument("--results", metavar="DIR", help="write results and the report to DIR instead of "
                        "benchmarks/results and docs/ (CI smoke runs use this so committed figures stay)")
    args = parser.parse_args(argv)
    if args.quick and not args.results:  # quick sweeps never overwrite the committed full results
        args.results = str(harness.RESULTS / "quick")
    if args.results:
        harness.RESULTS = Path(args.results)
        report.DOCS = Path(args.results)
    modules = available()
    unknown = [n for n in args.names if n not in modules]
    if unknown:
        print(f"unknown benchmark(s): {', '.join(unknown)} (known: {', '.join(sorted(modules))})", file=sys.stderr)
        return 2
    if not args.report_only:
        for name in args.names or sorted(modules):
            started = time.perf_counter()
            data = modules[name].run(quick=args.quick)
            data["quick"] = args.quick
            path = harness.save(data)
            print(f"{name}: {time.perf_counter() - started:.1f} s -> {path}")
            for key, value in data["figures"].items():
                print(f"  {key}: {value}")
    print(f"wrote {report.write()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
