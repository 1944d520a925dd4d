"""What every command shares on its way out: exit codes, the stdout console for tables, warning lines."""

from __future__ import annotations

from rich.console import Console
from rich.markup import escape

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130


def table_console() -> Console:
    """Where the tables of list, plan and inspect go: stdout (``usdbake list | grep weather``); progress,
    warnings and errors go to the stderr console ``main`` makes."""
    return Console(soft_wrap=True)


def print_warning(console: Console, message: str) -> None:
    """One ``warning:`` line on the stderr console."""
    console.print(f"[yellow]warning:[/yellow] {escape(message)}", highlight=False)
