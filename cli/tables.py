"""The commands that print tables: ``usdbake list`` (processors and their parameters) and ``usdbake
inspect`` (the baked data a layer holds), and the summary table of bake and plan."""

from __future__ import annotations

import json

from rich.console import Console
from rich.table import Table

from ..core import registry
from ..core.params import TABLE_COLUMNS
from .console import EXIT_OK, table_console


def add_parsers(commands) -> None:
    listing = commands.add_parser("list", help="list processors and their parameters")
    listing.add_argument("names", nargs="*", metavar="NAME", help="processors to list (default: all)")
    listing.add_argument("--json", action="store_true")
    inspect = commands.add_parser("inspect", help="show the baked data a layer holds")
    inspect.add_argument("output")
    inspect.add_argument("--json", action="store_true")


def summary_table(steps: list[dict], *, planned: bool = False) -> Table:
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
    processors = [(name, registry.get(name)) for name in args.names] if args.names else \
        sorted(registry.registry().items())
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
    for lightmap in report["lightmaps"]:
        size = lightmap.get("error") or (f"{lightmap['width']} x {lightmap['height']}, {lightmap['channels']} "
                                         f"channel(s), {lightmap['format']}")
        if lightmap.get("times"):
            size += f"; one file per time code, {lightmap['times']} in all, the first shown"
        out.print(f"lightmap: {lightmap['path']} -> {lightmap['file']} ({size})", highlight=False)
    table = Table()
    table.add_column("property", overflow="fold", ratio=1)  # long prim paths wrap instead of being cut
    for column in ("type", "interpolation", "elementSize", "values", "time samples"):
        table.add_column(column, no_wrap=True)
    for row in report["properties"]:
        table.add_row(row["path"], row["type"], row["interpolation"], str(row["element_size"]),
                      str(row["values"]), str(row["time_samples"]))
    out.print(table)
    return EXIT_OK
