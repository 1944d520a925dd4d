"""cli.tables: the summary table of bake and plan (columns, action labels, number formats), ``usdbake list``
(chosen processors, --json rows built from the registry, a table per processor) and ``usdbake inspect``
(header lines, sidecars, one row per property) called as functions; their parsers."""

import argparse
import io
import json

import pytest
from pxr import Gf, Sdf, Vt
from rich.console import Console

from usdbake.core import registry
from usdbake.core.errors import UsageError
from usdbake.core.params import TABLE_COLUMNS
from usdbake.cli.tables import _product_name, add_parsers, cmd_inspect, cmd_list, summary_table
from usdbake.stages.inspect import inspect_layer
from usdbake.stages.provenance import PROVENANCE_KEY


@pytest.fixture(autouse=True)
def wide_stdout(monkeypatch):
    """Tables on stdout wide enough that no cell wraps (rich reads COLUMNS when stdout is not a terminal)."""
    monkeypatch.setenv("COLUMNS", "400")


def cells(table) -> list[list[str]]:
    columns = [list(column.cells) for column in table.columns]
    return [list(row) for row in zip(*columns)]


def step_report(name, action, reason="", seconds=0.0, mrays=0.0) -> dict:
    return {"processor": name, "action": action, "reason": reason, "seconds": seconds, "mrays_per_s": mrays}


# --- summary_table ----------------------------------------------------------------------------


STEPS = [step_report("ambient_occlusion", "run", "forced", 1.23456, 12.345),
         step_report("radiosity", "cached", "up to date: fingerprint unchanged", 0.004, 0.0),
         step_report("instance_ao", "skip", "not applicable: no instanced prototypes")]


def test_the_bake_summary_has_times_and_throughput():
    table = summary_table(STEPS)
    assert table.title == "bake summary"
    assert [c.header for c in table.columns] == ["processor", "action", "reason", "time (s)", "Mrays/s"]
    assert [c.justify for c in table.columns] == ["left", "left", "left", "right", "right"]
    assert cells(table) == [
        ["ambient_occlusion", "ran", "forced", "1.23", "12.35"],
        ["radiosity", "up to date", "up to date: fingerprint unchanged", "0.00", ""],  # no rays: no throughput
        ["instance_ao", "skipped", "not applicable: no instanced prototypes", "0.00", ""],
    ]


def test_the_plan_has_what_will_happen_and_no_numbers():
    table = summary_table(STEPS, planned=True)
    assert table.title == "plan"
    assert [c.header for c in table.columns] == ["processor", "action", "reason"]
    assert [row[1] for row in cells(table)] == ["will run", "up to date", "skipped"]


def test_an_empty_run_is_an_empty_table():
    assert cells(summary_table([])) == [] and summary_table([]).row_count == 0


# --- list -------------------------------------------------------------------------------------


def test_product_names_are_class_names_and_strings_stay():
    class DisplacementFieldSet:
        pass

    assert _product_name(DisplacementFieldSet) == "DisplacementFieldSet"
    assert _product_name("bake:ao") == "bake:ao"


def test_list_json_holds_the_named_processors_in_the_order_asked(capsys):
    assert cmd_list(argparse.Namespace(names=["instance_ao", "ambient_occlusion"], json=True), None) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [row["name"] for row in rows] == ["instance_ao", "ambient_occlusion"]
    for row in rows:
        cls = registry.get(row["name"])
        assert row["summary"] == cls.summary
        assert row["requires"] == [product.__name__ for product in cls.requires]
        assert row["provides"] == [product.__name__ for product in cls.provides]
        assert [p["name"] for p in row["params"]] == [p["name"] for p in cls.Params.describe()]
    assert rows[0]["requires"] == ["DisplacementFieldSet"]  # instance_ao reads the displacement fields


def test_list_without_names_lists_every_processor_sorted(capsys):
    cmd_list(argparse.Namespace(names=[], json=True), None)
    assert [row["name"] for row in json.loads(capsys.readouterr().out)] == sorted(registry.registry())


def test_list_prints_one_table_per_processor_with_every_parameter(capsys):
    assert cmd_list(argparse.Namespace(names=["ambient_occlusion"], json=False), None) == 0
    out = capsys.readouterr().out
    cls = registry.get("ambient_occlusion")
    assert f"ambient_occlusion: {cls.summary}" in out
    header = next(line for line in out.splitlines() if "param" in line and "meaning" in line)
    assert [word for word in header.replace("┃", " ").replace("|", " ").split()] == list(TABLE_COLUMNS)
    for name, type_name, default, _, _ in cls.Params.table_rows():
        line = next((line for line in out.splitlines() if f" {name} " in line), "")
        assert type_name in line and default in line, name


def test_list_of_an_unknown_processor_names_the_known_ones():
    with pytest.raises(UsageError, match=r"unknown processor 'nope' \(known: .*ambient_occlusion"):
        cmd_list(argparse.Namespace(names=["nope"], json=True), None)


# --- inspect ----------------------------------------------------------------------------------


def bake_layer(path, provenance) -> str:
    layer = Sdf.Layer.CreateNew(str(path))
    layer.customLayerData = {PROVENANCE_KEY: provenance}
    prim = Sdf.PrimSpec(Sdf.PrimSpec(layer, "World", Sdf.SpecifierOver), "Floor", Sdf.SpecifierOver)
    spec = Sdf.AttributeSpec(prim, "primvars:bake:light", Sdf.ValueTypeNames.Color3fArray)
    spec.default = Vt.Vec3fArray([Gf.Vec3f(1, 1, 1)] * 36)
    spec.SetInfo("interpolation", "faceVarying")
    spec.SetInfo("elementSize", 3)
    layer.Save()
    return str(path)


def test_inspect_prints_who_baked_what_from_where_and_each_property(tmp_path, capsys):
    path = bake_layer(tmp_path / "out.usda", {"version": "9.8.7", "source": "shots/in.usda",
                                              "sidecars": Vt.StringArray(["out.a.png", "out.b.png"])})
    assert cmd_inspect(argparse.Namespace(output=path, json=False), None) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[:3] == [f"{path}: baked by usdbake 9.8.7 from shots/in.usda", "sidecar file: out.a.png",
                         "sidecar file: out.b.png"]
    row = next(line for line in lines if "/World/Floor.primvars:bake:light" in line)
    assert row.replace("│", " ").split() == ["/World/Floor.primvars:bake:light", "color3f[]", "faceVarying", "3",
                                            "36", "0"]


def test_inspect_marks_what_the_provenance_does_not_say(tmp_path, capsys):
    path = bake_layer(tmp_path / "out.usdc", {})
    cmd_inspect(argparse.Namespace(output=path, json=False), None)
    assert capsys.readouterr().out.splitlines()[0] == f"{path}: baked by usdbake ? from ?"


def test_inspect_json_is_the_librarys_report(tmp_path, capsys):
    path = bake_layer(tmp_path / "out.usda", {"version": "1", "sidecars": Vt.StringArray(["x.png"])})
    assert cmd_inspect(argparse.Namespace(output=path, json=True), None) == 0
    assert json.loads(capsys.readouterr().out) == inspect_layer(path)


# --- the parsers ------------------------------------------------------------------------------


def test_the_list_and_inspect_parsers():
    parser = argparse.ArgumentParser()
    add_parsers(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["list", "radiosity", "ambient_occlusion", "--json"])
    assert (args.command, args.names, args.json) == ("list", ["radiosity", "ambient_occlusion"], True)
    assert parser.parse_args(["list"]).names == []
    args = parser.parse_args(["inspect", "out.usda"])
    assert (args.command, args.output, args.json) == ("inspect", "out.usda", False)


def test_a_wide_table_goes_to_stdout_not_the_console_passed_in(capsys):
    console = Console(file=io.StringIO())
    cmd_list(argparse.Namespace(names=["ambient_occlusion"], json=False), console)
    assert console.file.getvalue() == "" and "ambient_occlusion" in capsys.readouterr().out
