"""The parameter tables in docs/ are generated from each processor's Params (usdbake.cli.docs_tables).

The drift test fails when a table in docs/*.md differs from what
``python -m usdbake.cli.docs_tables`` would write; run it and commit the pages.
The rest checks the one renderer (Params.table_rows / markdown_table) that
feeds both the docs and ``usdbake list``, and the generator's errors.
"""

from __future__ import annotations

import math
import sys
import re
from dataclasses import dataclass

import pytest

from usdbake.cli import docs_tables
from usdbake.cli.main import main
from usdbake.core import Params, Processor, param, registry
from usdbake.core.params import TABLE_COLUMNS


@dataclass(frozen=True)
class ToyParams(Params):
    samples: int = param(64, "rays per point", low=1, high=4096)
    reach: float = param(math.inf, "farthest hit | stage units", low=0.0)
    mode: str = param("fast", "how to go", choices=("fast", "exact"))
    tag: str = param("", "free text")
    enabled: bool = param(True, "on or off")
    offset: float = param(0.5, "at most one", high=1.0)


class Toy(Processor):
    name = "toy"
    summary = "A processor for these tests."
    Params = ToyParams


def test_docs_tables_match_the_params():
    stale = docs_tables.stale()
    assert stale == [], (f"parameter tables out of date in {[p.name for p in stale]}: "
                         f"run `python -m usdbake.cli.docs_tables` and commit docs/")


def test_each_builtin_processor_has_at_most_one_block_and_the_generator_adds_the_missing():
    named = [name for path in sorted(docs_tables.DOCS.glob("*.md"))
             for name in docs_tables.named_blocks(path.read_text(encoding="utf-8"), path.name)]
    assert len(named) == len(set(named)) and set(named) <= set(registry.builtin())
    written = docs_tables.expected()  # what `python -m usdbake.cli.docs_tables` writes
    everywhere = [name for path, text in written.items() for name in docs_tables.named_blocks(text, path.name)]
    assert sorted(everywhere) == sorted(registry.builtin())


def test_table_rows_format_defaults_and_ranges_as_a_user_types_them():
    rows = {row[0]: row for row in ToyParams.table_rows()}
    assert rows["samples"] == ("samples", "int", "64", "[1, 4096]", "rays per point")
    assert rows["reach"][2:4] == ("inf", ">= 0.0")
    assert rows["mode"][2:4] == ("fast", "fast, exact")
    assert rows["tag"][2:4] == ("''", "")
    assert rows["enabled"][2:4] == ("true", "")
    assert rows["offset"][3] == "<= 1.0"


def test_markdown_table_has_one_row_per_param_and_escapes_pipes():
    lines = ToyParams.markdown_table().split("\n")
    assert lines[0] == "| " + " | ".join(TABLE_COLUMNS) + " |"
    assert len(lines) == 2 + len(ToyParams.describe())
    assert "| `mode` | str | `fast` | `fast`, `exact` | how to go |" in lines
    reach = next(line for line in lines if line.startswith("| `reach`"))
    assert "farthest hit \\| stage units" in reach
    assert all(line.replace("\\|", "").count("|") == len(TABLE_COLUMNS) + 1 for line in lines)


def test_list_prints_the_same_cells_as_the_docs(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "240")  # wide enough that no cell wraps, so each reads as one string
    capsys.readouterr()
    assert main(["list"]) == 0
    printed = capsys.readouterr().out
    for name, type_name, default, allowed, _ in registry.get("ambient_occlusion").Params.table_rows():
        assert name in printed and default in printed and allowed in printed


def test_rewrite_fills_blocks_and_keeps_the_text_around_them():
    text = "# Toy\n\nbefore\n\n<!-- params: toy -->\nstale table\n<!-- /params -->\n\nafter `<!-- params: x -->`\n"
    out = docs_tables.rewrite(text, {"toy": Toy})
    assert out.startswith("# Toy\n\nbefore\n\n<!-- params: toy -->\n")
    assert out.endswith("<!-- /params -->\n\nafter `<!-- params: x -->`\n")
    assert ToyParams.markdown_table() in out and "stale table" not in out
    assert docs_tables.rewrite(out, {"toy": Toy}) == out


@pytest.mark.parametrize("text, fragment", [
    ("<!-- params: nobody -->\n<!-- /params -->\n", "no built-in processor 'nobody'"),
    ("<!-- params: toy -->\nno end marker\n", "needs a '<!-- /params -->' line"),
    ("<!-- params: toy -->\n<!-- params: toy -->\n<!-- /params -->\n", "needs a '<!-- /params -->' line"),
])
def test_rewrite_refuses_broken_blocks(text, fragment):
    with pytest.raises(docs_tables.DocsError, match=re.escape(fragment)):
        docs_tables.rewrite(text, {"toy": Toy})


def test_a_processor_without_a_page_gets_a_section_on_the_index_page(tmp_path):
    (tmp_path / "a.md").write_text("# A\n")
    pages = docs_tables.expected(tmp_path, {"toy": Toy})
    index = pages[tmp_path / docs_tables.CATCH_ALL]
    assert "## `toy`" in index and ToyParams.markdown_table() in index
    assert "| `toy` | A processor for these tests. | [processors.md](processors.md) |" in index
    for path, text in pages.items():
        path.write_text(text)
    assert docs_tables.expected(tmp_path, {"toy": Toy}) == pages  # a second run changes nothing


def test_a_processor_named_on_two_pages_is_an_error(tmp_path):
    for page in ("a.md", "b.md"):
        (tmp_path / page).write_text("<!-- params: toy -->\n<!-- /params -->\n")
    with pytest.raises(docs_tables.DocsError, match="both a.md and b.md"):
        docs_tables.expected(tmp_path, {"toy": Toy})


def test_check_exits_1_on_a_stale_page_and_writes_nothing(tmp_path, capsys):
    page = tmp_path / "ao.md"
    page.write_text("<!-- params: ambient_occlusion -->\nold\n<!-- /params -->\n")
    before = {p.name: p.read_text() for p in tmp_path.iterdir()}
    assert docs_tables.main(["--check", "--docs", str(tmp_path)]) == 1
    assert {p.name: p.read_text() for p in tmp_path.iterdir()} == before
    assert docs_tables.main(["--docs", str(tmp_path)]) == 0
    assert "old" not in page.read_text() and (tmp_path / docs_tables.CATCH_ALL).exists()
    assert docs_tables.main(["--check", "--docs", str(tmp_path)]) == 0


def test_processor_docstrings_point_at_the_generated_tables_instead_of_copying_them():
    """A hand-copied parameter table in a module docstring drifts; each docstring names the generated ones."""
    for name, cls in registry.builtin().items():
        doc = sys.modules[cls.__module__].__doc__ or ""
        assert f"``usdbake list {name}``" in doc, f"{cls.__module__}: no pointer to `usdbake list {name}`"
        defaults = {row["name"]: (row["type"], str(row["default"])) for row in cls.Params.describe()}
        copied = [line for line in doc.splitlines()
                  if len(line.split()) >= 3 and tuple(line.split()[1:3]) == defaults.get(line.split()[0])]
        assert not copied, f"{cls.__module__} docstring repeats its Params: {copied[:2]}"
