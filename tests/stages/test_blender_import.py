"""A real third-party USD consumer reads usdbake's output: Blender's ``bpy`` imports the baked layer.

Opt-in and slow (``-m slow``). It needs Blender as a Python module (``pip install bpy``), which
only installs on the Python version that Blender release embeds (3.11 for Blender 4.1 to 5.0)
and ships its own USD libraries, so it lives in a virtualenv of its own, e.g.::

    python3.11 -m venv /tmp/bpyvenv && /tmp/bpyvenv/bin/pip install bpy
    USDBAKE_BLENDER_PYTHON=/tmp/bpyvenv/bin/python python -m pytest -m slow \
        tests/stages/test_blender_import.py -rs

Without ``USDBAKE_BLENDER_PYTHON`` the test interpreter itself is used when it can import bpy;
otherwise the tests skip and say why.

usdbake bakes in this process's environment (the ``usdbake`` CLI); Blender runs in a subprocess
under ``python -I`` (no PYTHONPATH, no user site, nothing from this venv), imports the .usda with
``bpy.ops.wm.usd_import`` and writes JSON describing every imported mesh object. The assertions
compare that JSON with the composed USD stage read here with ``pxr``: counts, attribute domains and
lengths, and values. Values matter because Blender's generic-primvar reader does not warn when a
vertex/uniform primvar's length does not fit its topology: it leaves the attribute all zeros. Only
UV and colour primvars get a console warning ("... count inconsistent with interpolation type"),
which is checked too.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdShade

import production_assets
from tolerances import FLOAT32_STORAGE

pytestmark = pytest.mark.slow

ENV_VAR = "USDBAKE_BLENDER_PYTHON"

BAKE_ARGS = [
    "-p", "sky_visibility", "-p", "ambient_occlusion",
    "--set", "sky_visibility.patch_count=64", "--set", "sky_visibility.tolerance=0.01",
    "--set", "sky_visibility.max_level=3", "--set", "ambient_occlusion.samples=64",
]

BAKE_TIMEOUT_S = 600
BLENDER_TIMEOUT_S = 300
PROBE_TIMEOUT_S = 120

COUNT_WARNING = re.compile(r"count inconsistent with interpolation", re.IGNORECASE)
IMPORTER_REPORT = re.compile(r"^(Warning|Error)\b.*USD Import", re.IGNORECASE)

# Runs inside Blender's Python: argv = [usd file, json out]. Options differ across Blender
# versions, so only those the installed operator knows are passed (and reported in the JSON).
BLENDER_SCRIPT = r'''
import json
import sys

import bpy

usd_path, json_path = sys.argv[1], sys.argv[2]
bpy.ops.wm.read_factory_settings(use_empty=True)

known = {p.identifier for p in bpy.ops.wm.usd_import.get_rna_type().properties}
wanted = {
    "import_meshes": True,
    "import_materials": True,
    "import_usd_preview": True,     # UsdPreviewSurface -> Principled BSDF
    "read_mesh_uvs": True,
    "read_mesh_colors": True,
    "read_mesh_attributes": True,   # generic primvars -> attributes (Blender 3.5+)
    "import_all_attributes": True,  # spelling in some releases
    "attr_import_mode": "ALL",      # spelling in some releases
    "validate_meshes": False,       # import the topology as written; do not let Blender repair it
}
options = {key: value for key, value in wanted.items() if key in known}
result = bpy.ops.wm.usd_import(filepath=usd_path, **options)

VALUE_PROP = {"FLOAT": "value", "INT": "value", "INT8": "value", "BOOLEAN": "value",
              "FLOAT2": "vector", "FLOAT_VECTOR": "vector", "FLOAT_COLOR": "color",
              "BYTE_COLOR": "color"}


def plain(value):
    try:
        return [float(v) for v in value]
    except TypeError:
        return value


objects = {}
for ob in bpy.data.objects:
    if ob.type != "MESH":
        continue
    me = ob.data
    attributes, values = {}, {}
    for attr in me.attributes:
        attributes[attr.name] = {"domain": attr.domain, "data_type": attr.data_type,
                                 "length": len(attr.data)}
        prop = VALUE_PROP.get(attr.data_type)
        if prop and not attr.name.startswith("."):
            values[attr.name] = [plain(getattr(item, prop)) for item in attr.data]
    objects[ob.name] = {
        "vertices": len(me.vertices),
        "polygons": len(me.polygons),
        "loops": len(me.loops),
        "uv_layers": [uv.name for uv in me.uv_layers],
        "attributes": attributes,
        "material_slots": [slot.material.name if slot.material else "" for slot in ob.material_slots],
        "material_index": [p.material_index for p in me.polygons],
        "corner_verts": [loop.vertex_index for loop in me.loops],
        "values": values,
    }

with open(json_path, "w") as f:
    json.dump({"blender": bpy.app.version_string, "operator_result": sorted(result),
               "import_options": options, "objects": objects}, f)
'''


# --- the Blender interpreter -------------------------------------------------------------------

def _clean_env(tmp: Path) -> dict:
    """This process's environment without what would leak the test venv into Blender's Python;
    Blender's user folders point into ``tmp`` so nothing of the user's profile is read or written."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP", "PYTHONUSERBASE", "VIRTUAL_ENV")}
    env["BLENDER_USER_RESOURCES"] = str(tmp / "blender_user")
    return env


def _probe(python: str, tmp: Path) -> tuple[bool, str]:
    try:
        done = subprocess.run([python, "-I", "-c", "import bpy; print(bpy.app.version_string)"],
                              capture_output=True, text=True, timeout=PROBE_TIMEOUT_S, env=_clean_env(tmp))
    except (OSError, subprocess.TimeoutExpired) as exc:
        return False, f"{type(exc).__name__}: {exc}"
    if done.returncode != 0:
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        return False, " | ".join(tail) or f"exit status {done.returncode}"
    return True, done.stdout.strip().splitlines()[-1] if done.stdout.strip() else "?"


@pytest.fixture(scope="module")
def blender_python(tmp_path_factory) -> str:
    """An interpreter that can ``import bpy``: $USDBAKE_BLENDER_PYTHON, else this one; skips otherwise."""
    tmp = tmp_path_factory.mktemp("blender_probe")
    configured = os.environ.get(ENV_VAR)
    if configured:
        if not (Path(configured).is_file() and os.access(configured, os.X_OK)):
            pytest.skip(f"{ENV_VAR}={configured} is not an executable file")
        ok, detail = _probe(configured, tmp)
        if not ok:
            pytest.skip(f"{ENV_VAR}={configured} cannot import bpy: {detail}")
        return configured
    if importlib.util.find_spec("bpy") is None:
        pytest.skip(f"Blender's bpy module is not importable here and {ENV_VAR} is unset "
                    f"(pip install bpy into a Python 3.11 venv and set {ENV_VAR} to its python)")
    ok, detail = _probe(sys.executable, tmp)
    if not ok:
        pytest.skip(f"bpy is installed in {sys.executable} but does not import: {detail}")
    return sys.executable


def _blender_import(python: str, usd: Path, folder: Path) -> dict:
    """Import ``usd`` into an empty Blender scene; returns the script's JSON plus the console text."""
    script = folder / "blender_import_probe.py"
    script.write_text(BLENDER_SCRIPT)
    out = folder / f"{usd.stem}.blender.json"
    try:
        done = subprocess.run([python, "-I", str(script), str(usd), str(out)], capture_output=True,
                              text=True, timeout=BLENDER_TIMEOUT_S, cwd=folder, env=_clean_env(folder))
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"Blender import of {usd} did not finish in {BLENDER_TIMEOUT_S} s:\n{exc.stdout}\n{exc.stderr}")
    console = f"{done.stdout}\n{done.stderr}"
    assert done.returncode == 0 and out.exists(), (
        f"Blender failed to import {usd} (exit status {done.returncode}):\n{console[-4000:]}")
    report = json.loads(out.read_text())
    report["console"] = console
    return report


# --- the stages --------------------------------------------------------------------------------

def _usdbake_cli() -> list[str]:
    script = Path(sys.executable).parent / "usdbake"
    return [str(script)] if script.exists() else [sys.executable, "-m", "usdbake.cli.main"]


@pytest.fixture(scope="module")
def stages(tmp_path_factory) -> dict[str, Path]:
    """room_with_box written and baked with the CLI: {"unbaked": input .usda, "baked": output .usda}."""
    folder = tmp_path_factory.mktemp("blender_stages")
    source = production_assets.room_with_box(folder)
    baked = folder / "room_with_box.baked.usda"
    cmd = [*_usdbake_cli(), "bake", str(source), "-o", str(baked), "--cache", str(folder / "cache"), *BAKE_ARGS]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=BAKE_TIMEOUT_S, cwd=folder)
    assert done.returncode == 0 and baked.exists(), (
        f"usdbake bake failed (exit status {done.returncode}): {' '.join(cmd)}\n{done.stdout[-3000:]}\n"
        f"{done.stderr[-3000:]}")
    return {"unbaked": source, "baked": baked}


@pytest.fixture(scope="module")
def imported(blender_python, stages, tmp_path_factory) -> dict[str, dict]:
    """Blender's JSON for each stage, one fresh Blender process per file."""
    return {kind: _blender_import(blender_python, path, tmp_path_factory.mktemp(f"blender_{kind}"))
            for kind, path in stages.items()}


def _summary(report: dict) -> str:
    """The JSON without the per-element values, for assertion messages."""
    brief = {k: v for k, v in report.items() if k not in ("objects", "console")}
    brief["objects"] = {
        name: {k: v for k, v in ob.items() if k not in ("values", "material_index", "corner_verts")}
        for name, ob in report["objects"].items()}
    return json.dumps(brief, indent=1)


def _usd_meshes(path: Path) -> dict[str, dict]:
    """What Blender should show for each mesh of the composed stage, keyed by prim name."""
    stage = Usd.Stage.Open(str(path))
    meshes = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
        primvars = {}
        for primvar in UsdGeom.PrimvarsAPI(prim).GetPrimvarsWithValues():
            primvars[primvar.GetPrimvarName()] = {
                "interpolation": primvar.GetInterpolation(),
                "element_size": primvar.GetElementSize(),
                "type": str(primvar.GetTypeName()),
                "values": np.asarray(primvar.ComputeFlattened()),
            }
        face_material = [None] * len(counts)
        for subset in UsdGeom.Subset.GetAllGeomSubsets(mesh):
            bound, _ = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()
            for face in subset.GetIndicesAttr().Get():
                face_material[face] = bound.GetPrim().GetName() if bound else None
        meshes[prim.GetName()] = {
            "path": str(prim.GetPath()),
            "points": len(mesh.GetPointsAttr().Get()),
            "faces": len(counts),
            "corners": int(counts.sum()),
            "face_vertex_indices": np.asarray(mesh.GetFaceVertexIndicesAttr().Get()),
            "orientation": mesh.GetOrientationAttr().Get(),
            "primvars": primvars,
            "face_material": face_material,
        }
    return meshes


# Where Blender's USD importer puts a generic primvar of each interpolation.
DOMAIN = {"vertex": "POINT", "varying": "POINT", "constant": "POINT", "uniform": "FACE", "faceVarying": "CORNER"}


# --- the tests ---------------------------------------------------------------------------------

def test_blender_reports_no_primvar_count_mismatch(imported):
    for kind, report in imported.items():
        lines = report["console"].splitlines()
        mismatches = [line for line in lines if COUNT_WARNING.search(line)]
        assert not mismatches, (f"Blender says a primvar of the {kind} stage does not fit its topology:\n"
                                + "\n".join(mismatches) + f"\n{_summary(report)}")
        reports = [line for line in lines if IMPORTER_REPORT.search(line)]
        assert not reports, f"Blender's USD importer reported problems with the {kind} stage:\n" + "\n".join(reports)
        assert report["operator_result"] == ["FINISHED"], f"{kind}: usd_import returned {report['operator_result']}"


@pytest.mark.parametrize("kind", ["unbaked", "baked"])
def test_meshes_import_with_their_topology_uvs_and_materials(imported, stages, kind):
    report = imported[kind]
    expected = _usd_meshes(stages[kind])
    assert set(report["objects"]) == set(expected), (
        f"{kind}: Blender mesh objects {sorted(report['objects'])}, USD meshes {sorted(expected)}\n{_summary(report)}")
    for name, usd in expected.items():
        ob = report["objects"][name]
        where = f"{kind} {usd['path']}"
        got = (ob["vertices"], ob["polygons"], ob["loops"])
        assert got == (usd["points"], usd["faces"], usd["corners"]), (
            f"{where}: Blender has (vertices, polygons, loops) {got}, USD has "
            f"{(usd['points'], usd['faces'], usd['corners'])}")
        assert usd["orientation"] == "rightHanded"  # corner order is then kept as written
        assert ob["corner_verts"] == usd["face_vertex_indices"].tolist(), f"{where}: face-vertex indices changed"

        # One UV layer, from primvars:st (Blender keeps the primvar's name; some releases say UVMap).
        assert len(ob["uv_layers"]) == 1 and ob["uv_layers"][0] in ("st", "UVMap"), (
            f"{where}: UV layers {ob['uv_layers']}, expected one from primvars:st")
        uv_name = ob["uv_layers"][0]
        uv = ob["attributes"].get(uv_name)
        assert uv == {"domain": "CORNER", "data_type": "FLOAT2", "length": usd["corners"]}, (
            f"{where}: UV attribute {uv_name!r} is {uv}")
        st = usd["primvars"]["st"]["values"]
        assert np.allclose(np.asarray(ob["values"][uv_name]), st, atol=FLOAT32_STORAGE), (
            f"{where}: UVs in Blender differ from the flattened primvars:st")

        # Material slots, and each polygon's slot is its GeomSubset's material.
        materials = sorted({m for m in usd["face_material"] if m})
        assert sorted(ob["material_slots"]) == materials, (
            f"{where}: material slots {ob['material_slots']}, USD binds {materials}")
        if materials:
            per_face = [ob["material_slots"][i] for i in ob["material_index"]]
            wrong = [i for i, (b, u) in enumerate(zip(per_face, usd["face_material"])) if b != u]
            assert not wrong, (f"{where}: {len(wrong)} polygons on the wrong material, first "
                               f"{[(i, per_face[i], usd['face_material'][i]) for i in wrong[:5]]}")

        if "displayColor" in usd["primvars"]:  # uniform displayColor: Blender spreads it to corners
            color = ob["attributes"].get("displayColor")
            assert color is not None and color["domain"] == "CORNER" and color["length"] == usd["corners"], (
                f"{where}: displayColor attribute is {color}")


def test_baked_primvars_become_attributes_with_their_values(imported, stages):
    report = imported["baked"]
    expected = _usd_meshes(stages["baked"])
    for name, usd in expected.items():
        ob = report["objects"][name]
        baked = {pv: info for pv, info in usd["primvars"].items() if pv.startswith("bake:")}
        assert "bake:ao" in baked and baked["bake:ao"]["interpolation"] == "vertex", (
            f"{usd['path']}: the baked layer has no vertex primvars:bake:ao ({sorted(baked)})")
        for pv, info in baked.items():
            where = f"baked {usd['path']}.primvars:{pv} ({info['interpolation']}, {info['type']})"
            attr = ob["attributes"].get(pv)
            assert attr is not None, f"{where}: no Blender attribute {pv!r}; Blender has {sorted(ob['attributes'])}"
            domain = DOMAIN[info["interpolation"]]
            length = {"POINT": ob["vertices"], "FACE": ob["polygons"], "CORNER": ob["loops"]}[domain]
            assert (attr["domain"], attr["length"]) == (domain, length), (
                f"{where}: Blender attribute is {attr}, expected domain {domain} with {length} elements")
            if pv == "bake:ao":
                assert attr["data_type"] == "FLOAT", f"{where}: Blender attribute is {attr}"
                assert attr["length"] == ob["vertices"]
            if info["element_size"] != 1 or pv not in ob["values"]:
                # Blender has no per-element arrays: an elementSize > 1 primvar (skyVisibility's
                # patch bytes) arrives as an attribute of the right domain holding no data.
                continue
            usd_values = info["values"].astype(np.float64)
            if info["type"].startswith("uchar") and attr["data_type"] == "INT8":
                usd_values = usd_values.astype(np.uint8).astype(np.int8).astype(np.float64)
            got = np.asarray(ob["values"][pv], dtype=np.float64)
            assert got.shape == usd_values.shape and np.allclose(got, usd_values, atol=FLOAT32_STORAGE), (
                f"{where}: Blender's values differ from the layer's (Blender leaves an attribute zero "
                f"when the primvar's length does not fit): Blender {got[:8]}..., USD {usd_values[:8]}...")
        ao = np.asarray(ob["values"]["bake:ao"])
        assert ao.min() >= 0.0 and ao.max() <= 1.0 and ao.max() > 0.0, f"baked {usd['path']}: AO {ao.min()}..{ao.max()}"


def test_refinement_adds_floor_polygons_but_keeps_uvs_and_materials(imported):
    unbaked, baked = imported["unbaked"]["objects"], imported["baked"]["objects"]
    assert set(baked) == set(unbaked), f"objects: baked {sorted(baked)}, unbaked {sorted(unbaked)}"
    assert baked["Floor"]["polygons"] > unbaked["Floor"]["polygons"], (
        f"the floor was not refined: {baked['Floor']['polygons']} polygons baked, "
        f"{unbaked['Floor']['polygons']} unbaked")
    for name in unbaked:
        assert baked[name]["uv_layers"] == unbaked[name]["uv_layers"], (
            f"{name}: UV layers baked {baked[name]['uv_layers']}, unbaked {unbaked[name]['uv_layers']}")
        assert baked[name]["material_slots"] == unbaked[name]["material_slots"], (
            f"{name}: material slots baked {baked[name]['material_slots']}, "
            f"unbaked {unbaked[name]['material_slots']}")
    assert sorted(baked["Box"]["material_slots"]) == ["Blue", "Red"], baked["Box"]["material_slots"]
