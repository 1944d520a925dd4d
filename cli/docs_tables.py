"""The parameter tables in docs/, generated from each processor's ``Params``.

A page holds a processor's table between two markers::

    <!-- params: ambient_occlusion -->
    (generated: the table of AmbientOcclusion.Params)
    <!-- /params -->

``python -m usdbake.cli.docs_tables`` rewrites every such block in docs/*.md
with ``Params.markdown_table()``, the cells ``usdbake list`` prints. Each
built-in processor is named by exactly one block; one that no page names gets
a section of its own at the end of docs/processors.md, whose index block
(``<!-- processors -->`` ... ``<!-- /processors -->``) lists every processor
and the page holding its table. ``--check`` writes nothing and exits 1 when a
page would change (tests/test_docs_tables.py runs the same check, so a table
that drifts from its Params fails the tests).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from ..core import registry
from ..core.errors import UsageError
from ..core.processor import Processor

DOCS = Path(__file__).resolve().parent.parent / "docs"
"""docs/ of a source checkout (the repository root is the package)."""

CATCH_ALL = "processors.md"
"""The index page; it also holds every processor without a page of its own."""

CLOSE = "<!-- /params -->"
OPEN = re.compile(r"^<!-- params: *(?P<name>\S*?) *-->[ \t]*$", re.M)
CLOSING = re.compile(r"^<!-- /params -->[ \t]*$", re.M)
BLOCK = re.compile(r"^<!-- params: *(?P<name>\S*?) *-->[ \t]*$.*?^<!-- /params -->[ \t]*$", re.M | re.S)
INDEX = re.compile(r"^<!-- processors -->[ \t]*$.*?^<!-- /processors -->[ \t]*$", re.M | re.S)
"""Markers count only on lines of their own, so prose and examples may quote them inline."""

CATCH_ALL_TEXT = """# Processors

Every built-in processor, what it does, and the page with its parameters.
`usdbake list` prints the same tables; `python -m usdbake.cli.docs_tables`
writes them (see [architecture.md](architecture.md#docs-tables)).

<!-- processors -->
<!-- /processors -->

A processor that no other page names in a `<!-- params: NAME -->` block gets
a section below, written by the generator; move the block to a page of its
own when the processor gets one.
"""


class DocsError(UsageError):
    """A docs page whose parameter blocks cannot be rewritten (unknown name, no end marker, a duplicate)."""


def block(name: str, cls: type[Processor]) -> str:
    """The whole block for one processor, markers included, without a trailing newline."""
    source = f"{cls.__module__}.{cls.__name__}.Params"
    return (f"<!-- params: {name} -->\n"
            f"<!-- generated from {source} by `python -m usdbake.cli.docs_tables`: edit the Params, "
            f"not this table -->\n\n"
            f"{cls.Params.markdown_table()}\n\n"
            f"{CLOSE}")


def index(processors: dict[str, type[Processor]], pages: dict[str, str]) -> str:
    """The index block: processor, summary, and the page holding its parameters (``pages``: name -> file)."""
    lines = ["<!-- processors -->", "", "| processor | what it does | parameters |", "|---|---|---|"]
    for name, cls in processors.items():
        summary = " ".join(cls.summary.split()).replace("|", "\\|")
        lines.append(f"| `{name}` | {summary} | [{pages[name]}]({pages[name]}) |")
    return "\n".join([*lines, "", "<!-- /processors -->"])


def named_blocks(text: str, where: str = "<text>") -> list[str]:
    """Processor names of the blocks in ``text``, in order; DocsError if a block is not closed."""
    names = [match["name"] for match in BLOCK.finditer(text)]
    opened = [match["name"] for match in OPEN.finditer(text)]
    closed = len(CLOSING.findall(text))
    if opened != names or closed != len(names):
        raise DocsError(f"{where}: each '<!-- params: NAME -->' line needs a '{CLOSE}' line after it "
                        f"(opened {opened}, closed {closed})")
    return names


def rewrite(text: str, processors: dict[str, type[Processor]], where: str = "<text>") -> str:
    """``text`` with every parameter block regenerated from ``processors`` (name -> class)."""
    for name in named_blocks(text, where):
        if name not in processors:
            raise DocsError(f"{where}: no built-in processor {name!r} (known: {', '.join(sorted(processors))})")
    return BLOCK.sub(lambda match: block(match["name"], processors[match["name"]]), text)


def expected(docs: Path = DOCS, processors: dict[str, type[Processor]] | None = None, *,
             add_missing: bool = True) -> dict[Path, str]:
    """{page: the text the generator would write} for docs/*.md, the index page included (created
    when absent). ``add_missing``: give a processor that no page names a section on the index page
    (what the command does); without it such a processor is left out of the pages and the index (what
    the drift check compares, so a new processor is not drift). DocsError for unknown names, unclosed
    blocks and processors named twice."""
    processors = dict(registry.builtin()) if processors is None else processors
    if not docs.is_dir():
        raise DocsError(f"no docs folder at {docs} (the tables live in a source checkout)")
    pages = {path: path.read_text(encoding="utf-8") for path in sorted(docs.glob("*.md"))}
    catch_all = docs / CATCH_ALL
    pages.setdefault(catch_all, CATCH_ALL_TEXT)
    home: dict[str, str] = {}
    for path, text in pages.items():
        for name in named_blocks(text, path.name):
            if name in home:
                raise DocsError(f"{name!r} has parameter blocks in both {home[name]} and {path.name}; keep one")
            home[name] = path.name
    for name in processors if add_missing else ():
        if name not in home:  # a section of its own on the index page, filled in by rewrite() below
            pages[catch_all] = (pages[catch_all].rstrip("\n")
                                + f"\n\n## `{name}`\n\n{processors[name].summary}\n\n<!-- params: {name} -->\n{CLOSE}\n")
            home[name] = catch_all.name
    listing = index({name: cls for name, cls in processors.items() if name in home}, home)
    return {path: INDEX.sub(lambda match: listing, rewrite(text, processors, path.name))
            for path, text in pages.items()}


def stale(docs: Path = DOCS) -> list[Path]:
    """Pages whose text differs from what the generator would write for the processors they name."""
    return [path for path, text in expected(docs, add_missing=False).items() if _differs(path, text)]


def write(docs: Path = DOCS) -> list[Path]:
    """Regenerate every block; returns the pages that changed."""
    changed = []
    for path, text in expected(docs).items():
        if _differs(path, text):
            path.write_text(text, encoding="utf-8")
            changed.append(path)
    return changed


def _differs(path: Path, text: str) -> bool:
    return not path.exists() or path.read_text(encoding="utf-8") != text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m usdbake.cli.docs_tables",
                                     description="Regenerate the parameter tables in docs/*.md from Params.")
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 if a page is out of date")
    parser.add_argument("--docs", type=Path, default=DOCS, help=f"docs folder (default: {DOCS})")
    args = parser.parse_args(argv)
    try:
        changed = stale(args.docs) if args.check else write(args.docs)
    except DocsError as error:
        print(f"docs_tables: error: {error}", file=sys.stderr)
        return 2
    verb = "out of date" if args.check else "rewrote"
    for path in changed:
        print(f"{verb}: {path}")
    return 1 if args.check and changed else 0


if __name__ == "__main__":
    sys.exit(main())
