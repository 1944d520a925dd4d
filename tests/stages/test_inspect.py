"""stages.inspect.inspect_layer on layers written here with Sdf: one row per authored attribute (sorted by
path, relationships left out) with its type, interpolation, element size, value count and time-sample
count; the provenance as plain Python; and one clear UsageError for anything that is not a bake layer."""

import json

import pytest
from pxr import Gf, Sdf, Vt

from usdbake.core.errors import UsageError
from usdbake.stages.inspect import inspect_layer
from usdbake.stages.provenance import PROVENANCE_KEY

PROVENANCE = {"version": "0.0.test", "source": "in.usda", "device": "cpu",
              "sidecars": Vt.StringArray(["out.field.0.png", "out.field.1.png"]),
              "processors": {"ambient_occlusion": {"action": "run", "messages": Vt.StringArray(["one", "two"]),
                                                   "params": {"samples": 16, "per_face": False}}}}


def attribute(layer: Sdf.Layer, prim: Sdf.PrimSpec, name: str, type_name, default=None, *, interpolation=None,
              element_size=None, samples=None) -> Sdf.AttributeSpec:
    spec = Sdf.AttributeSpec(prim, name, type_name)
    if default is not None:
        spec.default = default
    if interpolation is not None:
        spec.SetInfo("interpolation", interpolation)
    if element_size is not None:
        spec.SetInfo("elementSize", element_size)
    for time, value in (samples or {}).items():
        layer.SetTimeSample(spec.path, time, value)
    return spec


def write_bake_layer(path, provenance=PROVENANCE) -> str:
    """A bake layer over in.usda: vertex AO on the ground (16 values), a faceVarying colour with elementSize
    2 on the cube (12 tuples), a scalar, a time-sampled primvar without a default, a string and a
    relationship (not an attribute: no row)."""
    layer = Sdf.Layer.CreateNew(str(path))
    layer.subLayerPaths.append("in.usda")
    layer.customLayerData = {PROVENANCE_KEY: provenance}
    world = Sdf.PrimSpec(layer, "World", Sdf.SpecifierOver)
    ground = Sdf.PrimSpec(world, "Ground", Sdf.SpecifierOver)
    cube = Sdf.PrimSpec(world, "Cube", Sdf.SpecifierOver)
    attribute(layer, ground, "primvars:bake:ao", Sdf.ValueTypeNames.FloatArray, Vt.FloatArray([0.5] * 16),
              interpolation="vertex")
    attribute(layer, cube, "primvars:bake:light", Sdf.ValueTypeNames.Color3fArray,
              Vt.Vec3fArray([Gf.Vec3f(1, 0, 0)] * 12), interpolation="faceVarying", element_size=2)
    attribute(layer, cube, "bake:exposure", Sdf.ValueTypeNames.Float, 0.25)
    attribute(layer, cube, "primvars:bake:sun", Sdf.ValueTypeNames.FloatArray, interpolation="uniform",
              samples={1.0: Vt.FloatArray([1.0] * 6), 2.0: Vt.FloatArray([0.0] * 6), 3.0: Vt.FloatArray([0.5] * 6)})
    attribute(layer, cube, "bake:note", Sdf.ValueTypeNames.String, "a long string of many characters")
    Sdf.RelationshipSpec(cube, "material:binding").targetPathList.explicitItems = [Sdf.Path("/World/Looks/Grey")]
    assert layer.Save()
    return str(path)


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])
def test_every_authored_attribute_is_a_row_sorted_by_path(tmp_path, suffix):
    path = write_bake_layer(tmp_path / f"out{suffix}")
    report = inspect_layer(path)
    rows = report["properties"]
    assert [row["path"] for row in rows] == sorted(row["path"] for row in rows)
    by_path = {row["path"]: row for row in rows}
    assert by_path == {
        "/World/Cube.bake:exposure": {"path": "/World/Cube.bake:exposure", "type": "float", "interpolation": "",
                                      "element_size": 1, "values": 1, "time_samples": 0},
        "/World/Cube.bake:note": {"path": "/World/Cube.bake:note", "type": "string", "interpolation": "",
                                  "element_size": 1, "values": 1, "time_samples": 0},  # one value, not its length
        "/World/Cube.primvars:bake:light": {"path": "/World/Cube.primvars:bake:light", "type": "color3f[]",
                                            "interpolation": "faceVarying", "element_size": 2, "values": 12,
                                            "time_samples": 0},
        "/World/Cube.primvars:bake:sun": {"path": "/World/Cube.primvars:bake:sun", "type": "float[]",
                                          "interpolation": "uniform", "element_size": 1, "values": 0,
                                          "time_samples": 3},
        "/World/Ground.primvars:bake:ao": {"path": "/World/Ground.primvars:bake:ao", "type": "float[]",
                                           "interpolation": "vertex", "element_size": 1, "values": 16,
                                           "time_samples": 0},
    }
    assert report["sublayers"] == ["in.usda"]


def test_the_provenance_is_plain_python_that_json_writes(tmp_path):
    report = inspect_layer(write_bake_layer(tmp_path / "out.usda"))
    provenance = report["provenance"]
    # Vt string arrays (sidecars, messages) come back as lists, nested dictionaries as dicts
    assert provenance["sidecars"] == ["out.field.0.png", "out.field.1.png"]
    assert type(provenance["sidecars"]) is list
    assert provenance["processors"]["ambient_occlusion"]["messages"] == ["one", "two"]
    assert provenance["processors"]["ambient_occlusion"]["params"] == {"samples": 16, "per_face": False}
    assert json.loads(json.dumps(report)) == report  # no default= needed: nothing but plain types


def test_a_bake_layer_with_no_attributes_has_no_rows(tmp_path):
    path = tmp_path / "empty.usda"
    layer = Sdf.Layer.CreateNew(str(path))
    layer.customLayerData = {PROVENANCE_KEY: {"version": "1"}}
    layer.Save()
    assert inspect_layer(str(path)) == {"provenance": {"version": "1"}, "properties": [], "sublayers": [],
                                        "lightmaps": []}


def test_refusals_name_the_path_and_the_problem(tmp_path):
    (tmp_path / "folder").mkdir()
    plain = tmp_path / "plain.usda"
    plain.write_text("#usda 1.0\n(\n    customLayerData = {\n        string usdbake = \"0.3\"\n    }\n)\n")
    garbage = tmp_path / "garbage.usdc"
    garbage.write_bytes(b"\x00\x01 not a crate file")
    cases = [
        (tmp_path / "missing.usda", f"{tmp_path / 'missing.usda'}: no such file"),
        (tmp_path / "folder", f"{tmp_path / 'folder'}: is a folder, not a layer"),
        # a string under the key is not usdbake's provenance
        (plain, f"{plain}: not a usdbake output (no 'usdbake' in customLayerData)"),
    ]
    for path, message in cases:
        with pytest.raises(UsageError) as raised:
            inspect_layer(str(path))
        assert str(raised.value) == message
    with pytest.raises(UsageError) as raised:
        inspect_layer(str(garbage))
    assert str(raised.value).startswith(f"{garbage}: cannot be read as USD (")
    assert "\n" not in str(raised.value) and not str(raised.value).endswith("()")
