"""Bad input that used to end in a late traceback (exit 1), answered before any compute (issue 27, item 8).

Each case goes through the command on a production-shaped stage (``production_assets``) and asserts
the exact line, the exit code, that no processor ran (their ``run`` is patched to fail if reached;
where the check is on the files themselves, reading the stage is forbidden too) and that every input
file is byte-identical afterwards:

* refinement (sky_visibility, daylight) of data OpenUSD holds invalid: a primvar or ``normals`` whose
  length does not fit its interpolation, indices outside the values or not ``int[]``, a value that is
  not an array, normals that are not 3-vectors. Exit 2, as for data refinement cannot carry, with the
  same remedies (fix it, ``bake:skip``, or bake without refinement);
* a ``displayColor`` OpenUSD gives no colour to: a warning naming it and the fallback albedo, as for a
  texture that cannot be used (exit 0: the bake is still right, with the albedo a renderer shows);
* bytes that are not UTF-8 in a layer (a string, a prim name, a comment; the input or an asset it
  asks for) or in the TOML config: exit 2, the line and the bytes printed with backslash escapes;
* an EPW weather file with a date that is not one (month 13, day 45, hour 99, not a number, 31 April,
  29 February of a common year): exit 2 naming the file, the line, the field and the value, for
  ``usdbake sky --weather`` and for ``annual_daylight.weather``.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from production_assets import add_box, add_floor, new_stage
from usdbake.cli.main import main
from usdbake.stages.extract import extract_scene

FAST = ["--set", "ambient_occlusion.samples=16"]
REFINE = ["-p", "sky_visibility", "--set", "sky_visibility.patch_count=32", "--set", "sky_visibility.tolerance=0.01",
          "--set", "sky_visibility.max_level=3"]
FIX = "fix it, mark the prim bake:skip = true, or bake it without sky_visibility/daylight"
FALLBACK = "using the fallback albedo (0.5, 0.5, 0.5)"


def forbidden(*args, **kwargs):
    raise AssertionError("the sky was made before the weather file was checked")


@pytest.fixture
def command(capfd):
    """Runs the command in-process; (exit code, stdout, stderr), every file in ``inputs`` unchanged.
    capfd: what USD prints from C++ (a Tf warning) counts as output too."""

    def run(*argv, inputs=()) -> tuple[int, str, str]:
        before = {Path(p): Path(p).read_bytes() for p in inputs}
        capfd.readouterr()
        code = main([str(a) for a in argv])
        out, err = capfd.readouterr()
        for path, data in before.items():
            assert path.read_bytes() == data, f"{path} changed"
        return code, out, err

    return run


def assert_refused(code: int, err: str, line: str) -> None:
    """Exit 2, no traceback, and one error line, the last (a progress line may come before it)."""
    assert code == 2, err
    assert "Traceback" not in err and "Warning" not in err, err
    lines = err.strip().splitlines()
    assert [text for text in lines if "error" in text] == [f"usdbake: error: {line}"], err
    assert lines[-1] == f"usdbake: error: {line}"


# ---------------------------------------------------------------------------
# Refinement: what OpenUSD holds invalid cannot be carried onto refined faces


def _replace(prim: Usd.Prim, name: str, type_name, value, interpolation: str | None = None) -> None:
    """Author ``name`` anew as ``type_name`` holding ``value``, in Sdf: the Usd API refuses a value of another
    type than a schema attribute's (normals, displayColor), and that is what a hand-written layer holds."""
    spec = prim.GetStage().GetRootLayer().GetPrimAtPath(prim.GetPath())
    if name in spec.properties:
        spec.RemoveProperty(spec.properties[name])
    attribute = Sdf.AttributeSpec(spec, name, type_name)
    attribute.default = value
    if interpolation:
        attribute.SetInfo("interpolation", interpolation)


def st_short(floor, box):
    UsdGeom.PrimvarsAPI(floor).GetPrimvar("st").Set(Vt.Vec2fArray([Gf.Vec2f(0, 0), Gf.Vec2f(1, 0), Gf.Vec2f(1, 1)]))


def st_not_an_array(floor, box):
    _replace(floor, "primvars:st", Sdf.ValueTypeNames.TexCoord2f, Gf.Vec2f(0, 0), "faceVarying")


def st_strings(floor, box):
    _replace(floor, "primvars:st", Sdf.ValueTypeNames.StringArray, Vt.StringArray(["a", "b", "c", "d"]), "faceVarying")


def st_at_one_time(floor, box):
    UsdGeom.PrimvarsAPI(floor).GetPrimvar("st").Set(Vt.Vec2fArray([Gf.Vec2f(0, 0)] * 3), 2.0)


def normals_short(floor, box):
    box.GetAttribute("normals").Set(Vt.Vec3fArray([Gf.Vec3f(0, 0, 1)] * 23))


def normals_floats(floor, box):
    _replace(box, "normals", Sdf.ValueTypeNames.FloatArray, Vt.FloatArray([1.0] * 24))


def normals_primvar_short(floor, box):
    UsdGeom.PrimvarsAPI(floor).GetPrimvar("normals").Set(Vt.Vec3fArray([Gf.Vec3f(0, 1, 0)] * 3))


def st_indices(values, type_name=Sdf.ValueTypeNames.IntArray):
    def edit(floor, box):
        _replace(box, "primvars:st:indices", type_name, values)
    return edit


def element_size(floor, box):
    UsdGeom.PrimvarsAPI(floor).CreatePrimvar("xz", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex,
                                             elementSize=2).Set(Vt.FloatArray([0.0, 1.0, 2.0, 3.0]))


def uniform_short(floor, box):
    UsdGeom.PrimvarsAPI(box).CreatePrimvar("faceId", Sdf.ValueTypeNames.IntArray,
                                           UsdGeom.Tokens.uniform).Set(Vt.IntArray([0, 1, 2, 3, 4]))


def unknown_interpolation(floor, box):
    _replace(floor, "primvars:temperature", Sdf.ValueTypeNames.FloatArray, Vt.FloatArray([1.0] * 4), "perVertex")


def velocities_short(floor, box):
    UsdGeom.Mesh(floor).CreateVelocitiesAttr(Vt.Vec3fArray([Gf.Vec3f(1, 0, 0)] * 3))


BOX_INDICES = [0, 1, 2, 3] * 6

REFINEMENT_CASES = {
    "st-short": (st_short, "/World/Floor.primvars:st: 3 faceVarying values for 4 face-vertices (one per "
                           "face-vertex); " + FIX),
    "st-not-an-array": (st_not_an_array, "/World/Floor.primvars:st: a single texCoord2f value, not an array "
                                         "(texCoord2f[]): faceVarying needs one per face-vertex; " + FIX),
    "st-strings": (st_strings, "/World/Floor.primvars:st: faceVarying string values cannot be interpolated onto "
                               "refined faces (no barycentric mean for string); mark the prim bake:skip = true, or "
                               "bake it without sky_visibility/daylight"),
    "st-short-at-one-time": (st_at_one_time, "/World/Floor.primvars:st: at time 2, 3 faceVarying values for 4 "
                                             "face-vertices (one per face-vertex); " + FIX),
    "normals-short": (normals_short, "/World/Box.normals: 23 vertex values for 24 points (one per point); " + FIX),
    "normals-floats": (normals_floats, "/World/Box.normals: float[] values; normals must be 3-vectors (normal3f[]); "
                                       + FIX),
    "primvars-normals-short": (normals_primvar_short, "/World/Floor.primvars:normals: 3 faceVarying values for 4 "
                                                      "face-vertices (one per face-vertex); " + FIX),
    "st-index-outside": (st_indices(Vt.IntArray([0, 1, 2, 9] + BOX_INDICES[4:])),
                         "/World/Box.primvars:st:indices: index 9 at position 3 is outside 0..3 (primvars:st holds "
                         "4 values); " + FIX),
    "st-index-negative": (st_indices(Vt.IntArray([0, 1, 2, -1] + BOX_INDICES[4:])),
                          "/World/Box.primvars:st:indices: index -1 at position 3 is outside 0..3 (primvars:st "
                          "holds 4 values); " + FIX),
    "st-indices-short": (st_indices(Vt.IntArray(BOX_INDICES[4:])),
                         "/World/Box.primvars:st:indices: 20 indices for 24 face-vertices (faceVarying: one per "
                         "face-vertex); " + FIX),
    "st-indices-floats": (st_indices(Vt.FloatArray(BOX_INDICES), Sdf.ValueTypeNames.FloatArray),
                          "/World/Box.primvars:st:indices: float[] values; primvar indices must be int[]; " + FIX),
    "element-size": (element_size, "/World/Floor.primvars:xz: 4 vertex values for 4 points (elementSize 2: 2 per "
                                   "point); " + FIX),
    "uniform-short": (uniform_short, "/World/Box.primvars:faceId: 5 uniform values for 6 faces (one per face); "
                                     + FIX),
    "unknown-interpolation": (unknown_interpolation, "/World/Floor.primvars:temperature: interpolation 'perVertex' is "
                                                     "not one of OpenUSD's (constant, uniform, varying, vertex, "
                                                     "faceVarying); " + FIX),
    "velocities-short": (velocities_short, "/World/Floor.velocities: 3 vertex values for 4 points (one per point); "
                                           + FIX),
}


def room(folder: Path, edit) -> Path:
    """A floor (faceVarying st and primvars:normals) and a flat-shaded box (vertex normals, indexed st), then
    ``edit(floor prim, box prim)``."""
    path = folder / "room.usda"
    stage = new_stage(path)
    floor = add_floor(stage, "/World/Floor").GetPrim()
    box = add_box(stage, "/World/Box", offset=(-25.0, 0.0, -25.0)).GetPrim()
    edit(floor, box)
    stage.Save()
    return path


@pytest.mark.parametrize("case", REFINEMENT_CASES)
def test_refinement_refuses_invalid_data_before_compute(command, tmp_path, no_compute, case):
    edit, line = REFINEMENT_CASES[case]
    source = room(tmp_path, edit)
    out = tmp_path / "out.usda"
    code, _, err = command("bake", source, "-o", out, *REFINE, inputs=[source])
    assert_refused(code, err, line)
    assert not out.exists()


def test_invalid_data_is_no_obstacle_where_nothing_is_refined(command, tmp_path):
    source = room(tmp_path, st_short)
    code, _, err = command("bake", source, "-o", tmp_path / "out.usda", *FAST, inputs=[source])
    assert code == 0, err


# ---------------------------------------------------------------------------
# displayColor: OpenUSD gives colour only to colours; anything else is the fallback albedo, with a warning


def display_color(type_name, value, interpolation=None, indices=None):
    def edit(floor, box):
        _replace(box, "primvars:displayColor", type_name, value, interpolation)
        if indices is not None:
            _replace(box, "primvars:displayColor:indices", indices[0], indices[1])
    return edit


TWO = Vt.Vec3fArray([Gf.Vec3f(1, 0, 0), Gf.Vec3f(0, 1, 0)])
COLOR3F = Sdf.ValueTypeNames.Color3fArray

DISPLAY_COLOR_CASES = {
    "string": (display_color(Sdf.ValueTypeNames.String, "red"), 'string "red" is not a colour (UsdGeom declares '
                                                                "displayColor color3f[])"),
    "token": (display_color(Sdf.ValueTypeNames.Token, "red"), 'token "red" is not a colour (UsdGeom declares '
                                                              "displayColor color3f[])"),
    "strings": (display_color(Sdf.ValueTypeNames.StringArray, Vt.StringArray(["red"])),
                'string[] ["red"] is not a colour (UsdGeom declares displayColor color3f[])'),
    "ints-of-wrong-length": (display_color(Sdf.ValueTypeNames.IntArray, Vt.IntArray([1, 2]), "uniform"),
                             "int[] [1, 2] is not a colour (UsdGeom declares displayColor color3f[])"),
    "three-ints": (display_color(Sdf.ValueTypeNames.IntArray, Vt.IntArray([1, 0, 0])),
                   "int[] [1, 0, 0] is not a colour (UsdGeom declares displayColor color3f[])"),
    "uniform-short": (display_color(COLOR3F, TWO, "uniform"),
                      "color3f[] [(1, 0, 0), (0, 1, 0)]: 2 uniform values for 6 faces"),
    "constant-two": (display_color(COLOR3F, TWO), "color3f[] [(1, 0, 0), (0, 1, 0)]: 2 constant values (one is "
                                                  "needed)"),
    "index-outside": (display_color(COLOR3F, TWO, "uniform", (Sdf.ValueTypeNames.IntArray, [0, 1, 0, 1, 0, 7])),
                      "index 7 in its indices (position 5) is outside its 2 values (0..1)"),
    "float-indices": (display_color(COLOR3F, TWO, "uniform", (Sdf.ValueTypeNames.FloatArray, [0, 1, 0, 1, 0, 1])),
                      "indices of type float[] (indices must be int[])"),
}


def box_albedo(path: Path) -> np.ndarray:
    scene = extract_scene(Usd.Stage.Open(str(path)))
    return scene.tri_albedo[scene.tri_prim == scene.prim_paths.index("/World/Box")]


@pytest.mark.parametrize("case", DISPLAY_COLOR_CASES)
def test_a_display_color_that_is_no_colour_warns_and_falls_back(tmp_path, case):
    edit, problem = DISPLAY_COLOR_CASES[case]
    source = room(tmp_path, edit)
    scene = extract_scene(Usd.Stage.Open(str(source)))
    assert list(scene.warnings) == [f"/World/Box.primvars:displayColor: {problem}; {FALLBACK}"]
    np.testing.assert_array_equal(box_albedo(source), np.full((12, 3), 0.5, np.float32))


def test_the_display_color_warning_through_the_command(command, tmp_path):
    source = room(tmp_path, display_color(Sdf.ValueTypeNames.String, "red"))
    out = tmp_path / "out.usda"
    code, _, err = command("bake", source, "-o", out, *FAST, inputs=[source])
    assert code == 0, err
    assert "Traceback" not in err
    assert (f'warning: /World/Box.primvars:displayColor: string "red" is not a colour (UsdGeom declares '
            f"displayColor color3f[]); {FALLBACK}") in err.splitlines()
    assert out.exists()


@pytest.mark.parametrize("type_name, value, expected", [
    (Sdf.ValueTypeNames.Color3f, Gf.Vec3f(1, 0, 0), (1, 0, 0)),  # one value, not an array
    (Sdf.ValueTypeNames.Color3dArray, Vt.Vec3dArray([Gf.Vec3d(0, 1, 0)]), (0, 1, 0)),  # another precision
    (Sdf.ValueTypeNames.Float3Array, Vt.Vec3fArray([Gf.Vec3f(0, 0, 1)]), (0, 0, 1)),
], ids=["color3f", "color3d[]", "float3[]"])
def test_colours_of_another_shape_or_precision_are_colours(tmp_path, type_name, value, expected):
    source = room(tmp_path, display_color(type_name, value))
    scene = extract_scene(Usd.Stage.Open(str(source)))
    assert list(scene.warnings) == []
    np.testing.assert_array_equal(box_albedo(source), np.tile(np.float32(expected), (12, 1)))


# ---------------------------------------------------------------------------
# Bytes that are not UTF-8


LAYER = '''#usda 1.0
(
    defaultPrim = "World"
)

def Xform "World"
{
    def Mesh "Floor" (
        doc = "DOC"
    )
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-1, 0, -1), (-1, 0, 1), (1, 0, 1), (1, 0, -1)]
    }
}
'''


def layer_bytes(*, doc: bytes = b"floor", name: bytes = b"Floor", comment: bytes = b"") -> bytes:
    text = LAYER.encode().replace(b'"DOC"', b'"' + doc + b'"').replace(b'Mesh "Floor"', b'Mesh "' + name + b'"')
    return text.replace(b'def Xform "World"', comment + b'def Xform "World"')


@pytest.mark.parametrize("data, where", [
    (layer_bytes(doc=b"caf\xe9 \xff"), 'line 9: byte 0xe9 is not UTF-8, in: doc = "caf\\xe9 \\xff"'),
    (layer_bytes(name=b"Fl\xe9or"), 'line 8: byte 0xe9 is not UTF-8, in: def Mesh "Fl\\xe9or" ('),
    (layer_bytes(comment=b"# caf\xe9\n"), "line 6: byte 0xe9 is not UTF-8, in: # caf\\xe9"),
], ids=["string", "prim-name", "comment"])
def test_a_layer_with_bytes_that_are_not_utf8_is_one_line(command, tmp_path, no_read, data, where):
    source = tmp_path / "latin1.usda"
    source.write_bytes(data)
    out = tmp_path / "out.usda"
    code, _, err = command("bake", source, "-o", out, *FAST, inputs=[source])
    assert_refused(code, err, f"{source}: cannot be read as USD ({where}; a .usda layer is UTF-8 text)")
    assert not out.exists()
    code, _, err = command("inspect", source, inputs=[source])
    assert_refused(code, err, f"{source}: cannot be read as USD ({where}; a .usda layer is UTF-8 text)")


@pytest.mark.parametrize("arc, at", [
    ("(\n    subLayers = [@asset.usda@]\n)\n", "/"),
    ('\ndef Xform "Prop" (\n    references = @asset.usda@</World>\n)\n{\n}\n', "/Prop"),
], ids=["sublayer", "reference"])
def test_an_asset_with_bytes_that_are_not_utf8_is_one_line(command, tmp_path, no_compute, arc, at):
    asset = tmp_path / "asset.usda"
    asset.write_bytes(layer_bytes(name=b"Fl\xe9or"))
    source = tmp_path / "root.usda"
    source.write_text("#usda 1.0\n" + arc)
    code, _, err = command("bake", source, "-o", tmp_path / "out.usda", *FAST, inputs=[source, asset])
    assert_refused(code, err, f'{source}: asset.usda cannot be read (line 8: byte 0xe9 is not UTF-8, in: def Mesh '
                              f'"Fl\\xe9or" (; a .usda layer is UTF-8 text), asked for at {at}; --allow-missing '
                              f"bakes without it")


def test_a_config_with_bytes_that_are_not_utf8_is_one_line(command, tmp_path, no_read):
    source = room(tmp_path, lambda floor, box: None)
    config = tmp_path / "studio.toml"
    config.write_bytes(b'processors = ["ambient_occlusion"]\n# r\xe9glages du studio\n[ambient_occlusion]\n'
                       b"samples = 16\n")
    code, _, err = command("bake", source, "-o", tmp_path / "out.usda", "--config", config, inputs=[source, config])
    assert_refused(code, err, f"{config}: not valid TOML (line 2: byte 0xe9 is not UTF-8, in: # r\\xe9glages du "
                              f"studio; TOML is UTF-8 text)")


# ---------------------------------------------------------------------------
# EPW weather files with dates that are not dates


EPW_FIELDS = 35


def write_epw(path: Path, row: int, field: int, value: str) -> Path:
    """An EPW of the Greensboro TMY3 year pvlib ships (NREL, public domain), with data row ``row`` (0-based)
    holding ``value`` in field ``field`` (0-based: year, month, day, hour). Skips the test without pvlib."""
    pvlib = pytest.importorskip("pvlib")
    with open(Path(pvlib.__file__).parent / "data" / "723170TYA.CSV", newline="") as handle:
        rows = list(csv.reader(handle))[2:]
    lines = ["LOCATION,Greensboro,NC,USA,TMY3,723170,36.10,-79.95,-5.0,273.0"] + [f"HEADER{k}" for k in range(7)]
    for index, tmy in enumerate(rows):
        month, day, year = tmy[0].split("/")
        fields = [year, str(int(month)), str(int(day)), str(int(tmy[1].split(":")[0])), "60", "A7"]
        fields += ["0"] * (EPW_FIELDS - len(fields))
        fields[14], fields[15] = tmy[7], tmy[10]
        if index == row:
            fields[field] = value
        lines.append(",".join(fields))
    path.write_text("\n".join(lines) + "\n")
    return path


EPW_CASES = {  # (data row, field, value, what the line says after 'line N: ')
    "month-13": (100, 1, "13", "field 2 (month) is 13, not a month (1..12)"),
    "day-45": (100, 2, "45", "field 3 (day) is 45, not a day of January (1..31)"),
    "hour-99": (100, 3, "99", "field 4 (hour) is 99, not an hour of the day (1..24, the hour ending at the stamp)"),
    "month-not-a-number": (100, 1, "Jan", "field 2 (month) is 'Jan', not a whole number"),
    "hour-not-whole": (100, 3, "12.5", "field 4 (hour) is '12.5', not a whole number"),
    "31-april": (24 * 100, 2, "31", "field 3 (day) is 31, not a day of April (1..30)"),
    "year-not-a-number": (100, 0, "", "field 1 (year) is '', not a whole number"),
}


@pytest.mark.parametrize("case", EPW_CASES)
def test_sky_refuses_an_epw_with_a_bad_date(command, tmp_path, monkeypatch, case):
    import usdbake.stages.sky_dome as sky_dome

    monkeypatch.setattr(sky_dome, "make_sky", forbidden)
    row, field, value, problem = EPW_CASES[case]
    epw = write_epw(tmp_path / "site.epw", row, field, value)
    source = room(tmp_path, lambda floor, box: None)
    out = tmp_path / "sky.usda"
    code, _, err = command("sky", source, "-o", out, "--weather", epw, inputs=[source, epw])
    assert_refused(code, err, f"{epw}, line {row + 9}: {problem}")
    assert not out.exists()


def test_29_february_of_a_common_year_is_not_a_date(command, tmp_path, monkeypatch):
    import usdbake.stages.sky_dome as sky_dome

    monkeypatch.setattr(sky_dome, "make_sky", forbidden)
    epw = write_epw(tmp_path / "site.epw", 24 * 58, 0, "1999")  # 28 February
    text = epw.read_text().splitlines()
    line = 8 + 24 * 58 + 1
    text[line - 1] = text[line - 1].replace(",2,28,", ",2,29,", 1)
    epw.write_text("\n".join(text) + "\n")
    source = room(tmp_path, lambda floor, box: None)
    code, _, err = command("sky", source, "-o", tmp_path / "sky.usda", "--weather", epw, inputs=[source, epw])
    assert_refused(code, err, f"{epw}, line {line}: field 3 (day) is 29, not a day of February 1999 (1..28)")


def test_annual_daylight_refuses_an_epw_with_a_bad_date(command, tmp_path, no_compute):
    epw = write_epw(tmp_path / "site.epw", 100, 1, "13")
    source = room(tmp_path, lambda floor, box: None)
    out = tmp_path / "out.usda"
    code, _, err = command("bake", source, "-o", out, "-p", "annual_daylight", "--set",
                           f"annual_daylight.weather={epw}", inputs=[source, epw])
    assert_refused(code, err, f"{epw}, line 109: field 2 (month) is 13, not a month (1..12)")
    assert not out.exists()
