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

A second group bakes ambient occlusion into a texture (``--target texture``) and checks what Blender
makes of it: the lightmap UV primvars as UV maps (names and values) and the AO texture wired into
UsdPreviewSurface ``inputs:occlusion`` (Blender 5.0.1 ignores that input; see the note above those tests).
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


def _blender_import(python: str, usd: Path, folder: Path, probe: str = BLENDER_SCRIPT,
                    name: str = "blender_import_probe.py") -> dict:
    """Import ``usd`` into an empty Blender scene with the ``probe`` script; returns its JSON plus the console
    text."""
    script = folder / name
    script.write_text(probe)
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
    return {"unbaked": source, "baked": _cli_bake(source, folder / "room_with_box.baked.usda", BAKE_ARGS)}


def _cli_bake(source: Path, baked: Path, args) -> Path:
    """``usdbake bake source -o baked`` with ``args`` in a subprocess (a cache next to it); fails the test with the
    command's output when it does not write the layer."""
    folder = baked.parent
    cmd = [*_usdbake_cli(), "bake", str(source), "-o", str(baked), "--cache", str(folder / "cache"), *args]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=BAKE_TIMEOUT_S, cwd=folder)
    assert done.returncode == 0 and baked.exists(), (
        f"usdbake bake failed (exit status {done.returncode}): {' '.join(cmd)}\n{done.stdout[-3000:]}\n"
        f"{done.stderr[-3000:]}")
    return baked


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


# --- the AO lightmap (texture target) in Blender ------------------------------------------------
#
# What Blender 5.0.1's USD importer does with a texture-target AO bake (measured, bpy 5.0.1):
#
# * UVs: every texCoord2f primvar becomes a UV map of the same name, colon included: the floor's
#   primvars:st is UV map "st", the wall's generated faceVarying primvars:bake:lightmapST is UV
#   map "bake:lightmapST" (no renaming, no "UVMap"), values as written.
# * inputs:occlusion is ignored. The importer converts diffuseColor, emissiveColor, specularColor,
#   metallic, roughness, clearcoat, clearcoatRoughness, opacity, ior and normal into Principled
#   BSDF inputs and nothing else (Principled BSDF has no occlusion socket). The floor's material
#   comes in as Principled BSDF -> Material Output only: no Image Texture node, no UV Map node,
#   no image datablock (bpy.data.images stays empty), so the AO PNG is not even loaded.
#   The LightmapAPI attributes (bake:lightmap:ao:file/uv/...) are not imported either (no custom
#   properties on the object, mesh or material).
# * The texture network itself is well-formed for Blender: wired into an input it knows
#   (diffuseColor, in a test-only layer over the bake), bakeAoTexture becomes an Image Texture
#   node on the AO PNG (absolute path, colour space Non-Color from sourceColorSpace "raw", the
#   PNG's size) whose Vector input is fed by a UV Map node on "st" (bakeLightmapUV's varname).
#
# test_ao_texture_occlusion_is_ignored_by_blender pins the second point, so that it fails (and this
# note gets updated) the day Blender starts reading inputs:occlusion.

AO_BAKE_ARGS = ["-p", "ambient_occlusion", "--target", "texture", "--set", "ambient_occlusion.samples=16"]
FLOOR_ST = [(0, 0), (0, 1), (1, 1), (1, 0)]

# Runs inside Blender's Python: argv = [usd file, json out]. Imports with the operator's defaults
# (import_materials, import_usd_preview, read_mesh_uvs are on by default) and describes every mesh
# object's UV maps and its materials' node trees.
AO_BLENDER_SCRIPT = r'''
import json
import sys

import bpy

usd_path, json_path = sys.argv[1], sys.argv[2]
bpy.ops.wm.read_factory_settings(use_empty=True)
result = bpy.ops.wm.usd_import(filepath=usd_path)


def links_from(tree, node):
    return [{"from_socket": link.from_socket.name, "to_node": link.to_node.bl_idname,
             "to_input": link.to_socket.name} for link in tree.links if link.from_node == node]


def links_into(tree, node):
    return [{"from_node": link.from_node.bl_idname, "from_socket": link.from_socket.name,
             "from_uv_map": getattr(link.from_node, "uv_map", None), "to_input": link.to_socket.name}
            for link in tree.links if link.to_node == node]


def material(mat):
    if mat is None:
        return None
    tree = mat.node_tree
    nodes, images = [], []
    for node in (tree.nodes if tree else []):
        nodes.append(node.bl_idname)
        if node.bl_idname == "ShaderNodeTexImage":
            image = node.image
            images.append({
                "filepath": bpy.path.abspath(image.filepath) if image else None,
                "colorspace": image.colorspace_settings.name if image else None,
                "size": list(image.size) if image else None,
                "outputs_to": links_from(tree, node),
                "inputs_from": links_into(tree, node),
            })
    return {"name": mat.name, "nodes": sorted(nodes), "image_nodes": images,
            "links": [[l.from_node.bl_idname, l.from_socket.name, l.to_node.bl_idname, l.to_socket.name]
                      for l in (tree.links if tree else [])],
            "custom_properties": sorted(mat.keys())}


objects = {}
for ob in bpy.data.objects:
    if ob.type != "MESH":
        continue
    me = ob.data
    objects[ob.name] = {
        "parent": ob.parent.name if ob.parent else None,
        "uv_maps": [uv.name for uv in me.uv_layers],
        "uvs": {uv.name: [[float(c) for c in d.vector] for d in uv.uv] for uv in me.uv_layers},
        "materials": [material(slot.material) for slot in ob.material_slots],
        "custom_properties": sorted(ob.keys()) + sorted(me.keys()),
    }

with open(json_path, "w") as f:
    json.dump({"blender": bpy.app.version_string, "operator_result": sorted(result),
               "images": [bpy.path.abspath(image.filepath) for image in bpy.data.images],
               "objects": objects}, f)
'''


def _ao_stage(folder: Path) -> Path:
    """The floor (st UVs, a UsdPreviewSurface) beside a tall wall (no UVs), written to folder/in.usda."""
    from pxr import Sdf
    from stage_builders import add_mesh, add_preview_material, bind, new_stage

    stage = new_stage(up_axis="Y", meters_per_unit=1.0)
    floor = add_mesh(stage, "/World/Floor", [(0.25, 0, 0), (0.25, 0, 1), (1.25, 0, 1), (1.25, 0, 0)], [4], [0, 1, 2, 3])
    st = UsdGeom.PrimvarsAPI(floor).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set(FLOOR_ST)
    add_mesh(stage, "/World/Wall", [(0, 0, -5), (0, 5, -5), (0, 5, 5), (0, 0, 5)], [4], [0, 1, 2, 3])
    bind(floor.GetPrim(), add_preview_material(stage, "/World/Looks/Floor", diffuse=(0.5, 0.5, 0.5)))
    path = folder / "in.usda"
    stage.GetRootLayer().Export(str(path))
    return path


def _control_layer(baked: Path) -> Path:
    """A test-only layer over the bake that also wires bakeAoTexture's rgb into diffuseColor, an input
    Blender's importer converts: it shows whether Blender can read our texture network at all."""
    from pxr import Sdf

    path = baked.with_name("control.usda")
    layer = Sdf.Layer.CreateNew(str(path))
    layer.subLayerPaths.append(baked.name)
    stage = Usd.Stage.Open(layer)
    surface = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Floor/Surface"))
    texture = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Floor/bakeAoTexture"))
    texture.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(texture.ConnectableAPI(), "rgb")
    layer.Save()
    return path


def _run_ao_script(python: str, usd: Path) -> dict:
    return _blender_import(python, usd, usd.parent, AO_BLENDER_SCRIPT, "blender_ao_probe.py")


@pytest.fixture(scope="module")
def ao_bake(blender_python, tmp_path_factory) -> dict:
    """The AO texture bake of _ao_stage, what the baked layer says, and Blender's JSON for the bake
    and for the control layer."""
    folder = tmp_path_factory.mktemp("blender_ao")
    source = _ao_stage(folder)
    baked = _cli_bake(source, folder / "out.usda", AO_BAKE_ARGS)

    stage = Usd.Stage.Open(str(baked))
    floor, wall = stage.GetPrimAtPath("/World/Floor"), stage.GetPrimAtPath("/World/Wall")
    ao_file = floor.GetAttribute("bake:lightmap:ao:file").Get()
    texture = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Floor/bakeAoTexture"))
    surface = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Floor/Surface"))
    assert ao_file is not None and texture and surface, "the bake did not write the floor's AO lightmap and shaders"
    (source_info,) = surface.GetInput("occlusion").GetConnectedSources()[0]
    assert source_info.source.GetPath() == texture.GetPath() and source_info.sourceName == "r"

    def uv(prim, name):
        return np.asarray(UsdGeom.PrimvarsAPI(prim).GetPrimvar(name).ComputeFlattened(), dtype=np.float64)

    floor_uv = floor.GetAttribute("bake:lightmap:ao:uv").Get()
    wall_uv = wall.GetAttribute("bake:lightmap:ao:uv").Get()
    return {
        "png": Path(ao_file.resolvedPath),
        "floor_uv": floor_uv, "floor_uvs": uv(floor, floor_uv),
        "wall_uv": wall_uv, "wall_uvs": uv(wall, wall_uv),
        "baked": _run_ao_script(blender_python, baked),
        "control": _run_ao_script(blender_python, _control_layer(baked)),
    }


def _floor(report: dict) -> dict:
    floor = report["objects"].get("Floor")
    assert floor is not None, f"no Floor mesh object in Blender: {sorted(report['objects'])}"
    return floor


def _ao_image_nodes(floor: dict, png: Path) -> list[dict]:
    return [node for mat in floor["materials"] if mat for node in mat["image_nodes"]
            if node["filepath"] and Path(node["filepath"]).name == png.name]


def test_ao_lightmap_uvs_import_under_the_primvar_names(ao_bake):
    report = ao_bake["baked"]
    assert report["operator_result"] == ["FINISHED"], report["operator_result"]
    reports = [line for line in report["console"].splitlines() if IMPORTER_REPORT.search(line)]
    assert not reports, "Blender's USD importer reported problems:\n" + "\n".join(reports)

    # The floor bakes on its own st (one tile, no overlap): Blender's UV map "st" holds what we wrote.
    floor = _floor(report)
    assert ao_bake["floor_uv"] == "st" and np.allclose(ao_bake["floor_uvs"], FLOOR_ST)
    assert floor["uv_maps"] == ["st"], f"Floor UV maps {floor['uv_maps']}"
    assert np.allclose(floor["uvs"]["st"], FLOOR_ST, atol=FLOAT32_STORAGE), floor["uvs"]["st"][:4]

    # The wall had no UVs: the bake generated primvars:bake:lightmapST, and Blender keeps the name,
    # colon included.
    wall = report["objects"].get("Wall")
    assert wall is not None and ao_bake["wall_uv"] == "bake:lightmapST"
    assert wall["uv_maps"] == ["bake:lightmapST"], f"Wall UV maps {wall['uv_maps']}"
    assert np.allclose(wall["uvs"]["bake:lightmapST"], ao_bake["wall_uvs"], atol=FLOAT32_STORAGE)


def test_ao_texture_occlusion_is_ignored_by_blender(ao_bake):
    """Blender (5.0.1) drops UsdPreviewSurface inputs:occlusion: the floor's material imports, but
    without the AO texture. If this fails, Blender now reads occlusion: update the note above."""
    report, png = ao_bake["baked"], ao_bake["png"]
    floor = _floor(report)
    assert [mat["name"] for mat in floor["materials"] if mat] == ["Floor"], floor["materials"]
    (material,) = floor["materials"]
    assert ["ShaderNodeBsdfPrincipled", "BSDF", "ShaderNodeOutputMaterial", "Surface"] in material["links"]
    assert _ao_image_nodes(floor, png) == [], (
        f"Blender {report['blender']} now imports the AO texture: {_ao_image_nodes(floor, png)}")
    assert not any(Path(path).name == png.name for path in report["images"]), report["images"]


def test_ao_texture_network_is_readable_when_wired_to_a_known_input(ao_bake):
    """The same UsdUVTexture + UsdPrimvarReader_float2 network, also wired into diffuseColor (a test-only
    layer): Blender loads the AO PNG as non-colour data, read through a UV Map node on the floor's st."""
    report, png = ao_bake["control"], ao_bake["png"]
    floor = _floor(report)
    nodes = _ao_image_nodes(floor, png)
    assert len(nodes) == 1, f"image nodes on the AO PNG: {nodes}; materials {floor['materials']}"
    (node,) = nodes
    assert Path(node["filepath"]).resolve() == png.resolve()
    assert node["colorspace"] == "Non-Color", node
    import OpenImageIO as oiio

    spec = oiio.ImageBuf(str(png)).spec()
    assert node["size"] == [spec.width, spec.height], (node["size"], spec.width, spec.height)
    base_color = {"from_socket": "Color", "to_node": "ShaderNodeBsdfPrincipled", "to_input": "Base Color"}
    assert base_color in node["outputs_to"], node["outputs_to"]
    assert [(link["from_node"], link["from_uv_map"], link["to_input"]) for link in node["inputs_from"]] == [
        ("ShaderNodeUVMap", ao_bake["floor_uv"], "Vector")], node["inputs_from"]
