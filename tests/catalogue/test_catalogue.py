"""The catalogue of real-asset cases (issue: real assets come out whole): one test per case.

Each case bakes a production-shaped stage (``production_assets``: Y-up, centimetres, flat-shaded
geometry with unwelded creases, authored normals, faceVarying indexed UVs, GeomSubsets with two
materials, native instancing, PointInstancers with prototypes under the instancer, leftHanded
meshes, missing references and textures) through the command, and asserts either the exact
error line or a complete, valid output; every case also asserts that no input file changed by a
byte. docs/reliability.md lists the cases with what usdbake does in each.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, UsdShade, UsdValidation

from production_assets import (
    add_box,
    add_floor,
    instanced_board,
    material,
    new_stage,
    room_with_box,
    topology_mismatches,
)
from usdbake.cli.main import main

FAST = ["--set", "ambient_occlusion.samples=64"]
REFINE = ["--set", "sky_visibility.patch_count=32", "--set", "sky_visibility.tolerance=0.01",
          "--set", "sky_visibility.max_level=3"]


class Baker:
    """Runs the command in-process and checks the inputs stay byte-identical."""

    def __init__(self, folder: Path, capsys):
        self.folder, self.capsys = folder, capsys

    def __call__(self, *argv, inputs=()) -> tuple[int, str]:
        files = [Path(p) for p in inputs]
        before = {p: p.read_bytes() for p in files}
        self.capsys.readouterr()
        code = main([str(a) for a in argv])
        err = self.capsys.readouterr().err
        for path in files:
            assert path.read_bytes() == before[path], f"{path} changed"
        return code, err


@pytest.fixture
def bake(tmp_path, capsys):
    return Baker(tmp_path, capsys)


def last_line(err: str) -> str:
    return err.strip().splitlines()[-1]


def primvar(stage, path, name):
    return UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(path)).GetPrimvar(name)


def validator_findings(path) -> list[str]:
    """What every registered OpenUSD validator reports on the composed stage (names and messages)."""
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    errors = UsdValidation.ValidationContext(validators).Validate(Usd.Stage.Open(str(path)))
    return sorted(f"{error.GetName()}: {error.GetMessage()}" for error in errors)


# ---------------------------------------------------------------------------
# 1. Refinement carries every authored attribute; 5. per-vertex results follow it in one run


def test_refined_meshes_keep_uvs_normals_and_subsets(bake, tmp_path):
    source = room_with_box(tmp_path)
    out = tmp_path / "out.usda"
    code, err = bake("bake", source, "-o", out, "-p", "sky_visibility", "-p", "ambient_occlusion", *REFINE, *FAST,
                     inputs=[source])
    assert code == 0, err
    stage = Usd.Stage.Open(str(out))
    assert topology_mismatches(stage) == []
    floor = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Floor"))
    assert len(floor.GetFaceVertexCountsAttr().Get()) > 2  # refined
    for name in ("st", "normals"):  # faceVarying, the st carried as the affine map of position
        assert len(primvar(stage, "/World/Floor", name).Get()) == len(floor.GetFaceVertexIndicesAttr().Get())
    box = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Box"))
    assert primvar(stage, "/World/Box", "st").IsIndexed()
    assert len(box.GetNormalsAttr().Get()) == len(box.GetPointsAttr().Get())
    subsets = UsdGeom.Subset.GetAllGeomSubsets(box)
    faces = sorted(int(i) for s in subsets for i in s.GetIndicesAttr().Get())
    assert faces == list(range(len(box.GetFaceVertexCountsAttr().Get())))  # every face in one subset
    for subset in subsets:
        assert UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()[0]
    ao = primvar(stage, "/World/Floor", "bake:ao").Get()
    assert len(ao) == len(floor.GetPointsAttr().Get())  # per-vertex AO on the refined mesh, same run


def test_refined_output_adds_no_validator_findings(bake, tmp_path):
    source = room_with_box(tmp_path)
    out = tmp_path / "out.usda"
    code, err = bake("bake", source, "-o", out, "-p", "sky_visibility", *REFINE, inputs=[source])
    assert code == 0, err
    assert validator_findings(out) == validator_findings(source)


def test_uncarriable_data_is_refused_before_compute(bake, tmp_path):
    path = tmp_path / "ids.usda"
    stage = new_stage(path)
    mesh = add_floor(stage, "/World/Floor")
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("materialId", Sdf.ValueTypeNames.IntArray,
                                            UsdGeom.Tokens.faceVarying).Set([0, 1, 2, 3])
    stage.Save()
    code, err = bake("bake", path, "-o", tmp_path / "out.usda", "-p", "sky_visibility", inputs=[path])
    assert code == 2 and not (tmp_path / "out.usda").exists()
    assert last_line(err) == ("usdbake: error: /World/Floor.primvars:materialId: faceVarying int values cannot be "
                              "interpolated onto refined faces (no barycentric mean for int); mark the prim "
                              "bake:skip = true, or bake it without sky_visibility/daylight")


# ---------------------------------------------------------------------------
# 2. Creases: a vertex on an unwelded crease is not occluded by the other face through it


def test_unwelded_crease_box_is_not_self_occluded(bake, tmp_path):
    path = tmp_path / "box.usda"
    stage = new_stage(path)
    add_box(stage, "/World/Box")
    stage.Save()
    out = tmp_path / "out.usda"
    code, err = bake("bake", path, "-o", out, *FAST, inputs=[path])
    assert code == 0, err
    baked = Usd.Stage.Open(str(out))
    ao = np.asarray(primvar(baked, "/World/Box", "bake:ao").Get())
    assert len(ao) == 24 and np.all(ao == 1.0)  # a lone convex box: every ray from every corner escapes


# ---------------------------------------------------------------------------
# 3. Instanced receivers


def test_instances_get_per_instance_ao_and_the_bake_says_so(bake, tmp_path):
    source = instanced_board(tmp_path)
    out = tmp_path / "out.usda"
    code, err = bake("bake", source, "-o", out, *FAST, inputs=[source])
    assert code == 0, err
    stage = Usd.Stage.Open(str(out))
    assert primvar(stage, "/World/Pawns/Pawn_0", "bake:ao").GetInterpolation() == "constant"
    assert len(primvar(stage, "/World/Row", "bake:ao").Get()) == 4
    assert "per-instance mean AO" in err


def test_instances_can_be_deinstanced_for_per_vertex_ao(bake, tmp_path):
    source = instanced_board(tmp_path)
    out = tmp_path / "out.usda"
    code, err = bake("bake", source, "-o", out, *FAST, "--deinstance", inputs=[source])
    assert code == 0, err
    stage = Usd.Stage.Open(str(out))
    assert not stage.GetPrimAtPath("/World/Pawns/Pawn_0").IsInstance()
    assert len(primvar(stage, "/World/Pawns/Pawn_0/Base", "bake:ao").Get()) == 24
    assert "de-instanced 4 native instances" in err


def test_a_scene_of_instances_only_is_baked(bake, tmp_path):
    source = instanced_board(tmp_path, floor=False, name="only.usda")
    out = tmp_path / "out.usda"
    code, err = bake("bake", source, "-o", out, *FAST, inputs=[source])
    assert code == 0, err
    baked = Usd.Stage.Open(str(out))
    assert primvar(baked, "/World/Pawns/Pawn_3", "bake:ao").HasValue()


def test_deinstanced_instances_are_refined_and_baked_by_every_processor(bake, tmp_path):
    source = instanced_board(tmp_path, floor=False, name="only.usda")
    out = tmp_path / "out.usda"
    code, err = bake("bake", source, "-o", out, "--deinstance", "-p", "sky_visibility", "-p", "ambient_occlusion",
                     *REFINE, *FAST, inputs=[source])
    assert code == 0, err
    stage = Usd.Stage.Open(str(out))
    assert topology_mismatches(stage) == []
    base = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Pawns/Pawn_2/Base"))
    assert not stage.GetPrimAtPath("/World/Pawns/Pawn_2").IsInstance()
    assert len(primvar(stage, "/World/Pawns/Pawn_2/Base", "bake:ao").Get()) == len(base.GetPointsAttr().Get())
    assert len(primvar(stage, "/World/Pawns/Pawn_2/Base", "bake:skyExposure").Get()) == \
        len(base.GetFaceVertexCountsAttr().Get())
    assert "de-instanced 4 native instances" in err
    assert len(primvar(stage, "/World/Row", "bake:ao").Get()) == 4  # the PointInstancer keeps per-instance means


def test_identical_prototypes_share_one_displacement_field(bake, tmp_path):
    source = instanced_board(tmp_path)
    out = tmp_path / "out.usda"
    code, err = bake("bake", source, "-o", out, "-p", "displacement_fields", "--set", "displacement_fields.force=Pawn",
                     "--set", "displacement_fields.positional_samples=16",
                     "--set", "displacement_fields.direction_map_size=8", inputs=[source])
    assert code == 0, err
    stage = Usd.Stage.Open(str(out))
    field = stage.GetPrimAtPath("/World/Row/Prototypes/Pawn").GetAttribute("bake:field:file").Get()
    assert field is not None and Path(field.resolvedPath).is_file()


# ---------------------------------------------------------------------------
# 4. Sidecars: no output overwrites another's


def test_two_outputs_in_one_folder_keep_their_own_sidecars(bake, tmp_path):
    source = instanced_board(tmp_path)
    files = {}
    for name, samples in (("a", 16), ("b", 36)):
        out = tmp_path / f"{name}.usda"
        code, err = bake("bake", source, "-o", out, "-p", "displacement_fields", "--set",
                         "displacement_fields.force=Pawn", "--set", f"displacement_fields.positional_samples={samples}",
                         "--set", "displacement_fields.direction_map_size=8", inputs=[source])
        assert code == 0, err
        baked = Usd.Stage.Open(str(out))
        files[name] = baked.GetPrimAtPath("/World/Row/Prototypes/Pawn").GetAttribute("bake:field:file").Get().resolvedPath
    assert files["a"] != files["b"] and all(Path(f).is_file() for f in files.values())


# ---------------------------------------------------------------------------
# 6. Composition faults


def missing_reference_stage(folder: Path) -> Path:
    path = folder / "missing_ref.usda"
    stage = new_stage(path)
    add_floor(stage, "/World/Floor")
    UsdGeom.Xform.Define(stage, "/World/Prop").GetPrim().GetReferences().AddReference("./props/chair.usda")
    stage.Save()
    return path


def test_missing_reference_exits_2_naming_asset_and_layer(bake, tmp_path):
    source = missing_reference_stage(tmp_path)
    code, err = bake("bake", source, "-o", tmp_path / "out.usda", *FAST, inputs=[source])
    assert code == 2 and not (tmp_path / "out.usda").exists()
    assert last_line(err) == (f"usdbake: error: {source}: reference {tmp_path / 'props/chair.usda'} on /World/Prop "
                              f"not found; --allow-missing bakes without it")


def test_allow_missing_bakes_without_it_and_warns(bake, tmp_path):
    source = missing_reference_stage(tmp_path)
    code, err = bake("bake", source, "-o", tmp_path / "out.usda", *FAST, "--allow-missing", inputs=[source])
    assert code == 0, err
    assert (f"warning: {source}: reference {tmp_path / 'props/chair.usda'} on /World/Prop not found; "
            f"baked without it") in err


def test_missing_texture_warns_naming_it_and_the_fallback(bake, tmp_path):
    path = tmp_path / "missing_tex.usda"
    stage = new_stage(path)
    floor = add_floor(stage, "/World/Floor")
    UsdShade.MaterialBindingAPI.Apply(floor.GetPrim()).Bind(
        material(stage, "/World/Looks/Wood", (0.5, 0.5, 0.5), texture="./textures/wood.png"))
    stage.Save()
    code, err = bake("bake", path, "-o", tmp_path / "out.usda", *FAST, inputs=[path])
    assert code == 0, err
    assert ("warning: /World/Looks/Wood/Image.inputs:file: texture ./textures/wood.png not found; "
            "/World/Looks/Wood/Surface.inputs:diffuseColor falls back to (0.18, 0.18, 0.18), the UsdPreviewSurface "
            "default") in " ".join(err.split())


# ---------------------------------------------------------------------------
# 7. Inputs checked before any compute


@pytest.mark.parametrize("output, message", [
    ("x.txt", "x.txt: unsupported extension '.txt'; the output must be a .usd, .usda or .usdc layer"),
    ("noext", "noext: no extension; the output must be a .usd, .usda or .usdc layer"),
    ("x.usdz", "x.usdz: usdbake does not write .usdz packages (the bake layer sublayers its input and names its "
               "sidecar files); write .usd, .usda or .usdc"),
    ("{folder}", "{folder}: is a folder; give a layer file name ending in .usd, .usda or .usdc"),
    ("/proc/x.usda", "/proc/x.usda: cannot write in /proc (No such file or directory)"),
    ("{source}", "{source}: refusing to overwrite the input layer; choose another -o"),
])
def test_bad_outputs_are_refused_with_one_line(bake, tmp_path, monkeypatch, output, message):
    source = room_with_box(tmp_path)
    monkeypatch.chdir(tmp_path)
    fill = {"folder": str(tmp_path), "source": str(source)}
    code, err = bake("bake", source, "-o", output.format(**fill), inputs=[source])
    assert code == 2
    assert err.strip() == f"usdbake: error: {message.format(**fill)}"


def test_params_for_a_processor_not_in_the_run_are_an_error(bake, tmp_path):
    source = room_with_box(tmp_path)
    code, err = bake("bake", source, "-o", tmp_path / "o.usda", "--set", "radiosity.samples=4", inputs=[source])
    assert code == 2
    assert err.strip() == ("usdbake: error: --set radiosity.samples=4: radiosity is not part of this run "
                           "(ambient_occlusion); add -p radiosity")


def test_a_config_value_of_the_wrong_type_is_an_error(bake, tmp_path):
    source = room_with_box(tmp_path)
    config = tmp_path / "c.toml"
    config.write_text('processors = "ambient_occlusion"\n')
    code, err = bake("bake", source, "-o", tmp_path / "o.usda", "--config", config, inputs=[source, config])
    assert code == 2
    assert err.strip() == (f"usdbake: error: {config}: processors must be a list of names, e.g. processors = "
                           f"[\"ambient_occlusion\"] (got 'ambient_occlusion')")


def test_skipped_processors_write_nothing(bake, tmp_path):
    source = room_with_box(tmp_path)
    out = tmp_path / "o.usda"
    code, err = bake("bake", source, "-o", out, "-p", "displacement_fields", inputs=[source])
    assert code == 2 and not out.exists()
    assert last_line(err) == ("usdbake: error: nothing to bake: displacement_fields skipped (not applicable: no "
                              "instanced prototypes); no output was written")


# ---------------------------------------------------------------------------
# 8. The first hour


def test_help_prints_no_cuda_notice():
    done = subprocess.run([sys.executable, "-m", "usdbake.cli.main", "--help"], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0 and "usage: usdbake" in done.stdout
    assert "CUDA" not in done.stdout + done.stderr


# ---------------------------------------------------------------------------
# Hostile shapes: leftHanded meshes, Y-up centimetres


def test_left_handed_floor_bakes_like_its_right_handed_twin(bake, tmp_path):
    results = {}
    for orientation in ("rightHanded", "leftHanded"):
        path = tmp_path / f"{orientation}.usda"
        stage = new_stage(path)
        floor = add_floor(stage, "/World/Floor")
        if orientation == "leftHanded":  # same facing: reversed winding under the left-hand rule
            floor.GetFaceVertexIndicesAttr().Set([3, 2, 1, 0])
            floor.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
        add_box(stage, "/World/Box", offset=(-25.0, 0.0, -25.0))
        stage.Save()
        out = tmp_path / f"{orientation}_out.usda"
        code, err = bake("bake", path, "-o", out, *FAST, inputs=[path])
        assert code == 0, err
        baked = Usd.Stage.Open(str(out))
        results[orientation] = np.asarray(primvar(baked, "/World/Floor", "bake:ao").Get())
    np.testing.assert_array_equal(results["leftHanded"], results["rightHanded"])
    assert results["rightHanded"].min() > 0.9  # floor corners 2 m from a 50 cm box: nearly open


def test_y_up_centimetre_scene_sees_the_sky_above(bake, tmp_path):
    source = room_with_box(tmp_path)
    out = tmp_path / "out.usda"
    code, err = bake("bake", source, "-o", out, "-p", "sky_visibility", "--set", "sky_visibility.patch_count=64",
                     inputs=[source])
    assert code == 0, err
    stage = Usd.Stage.Open(str(out))
    exposure = np.asarray(primvar(stage, "/World/Box", "bake:skyExposure").Get())
    source_face = np.asarray(primvar(stage, "/World/Box", "bake:sourceFace").Get())
    top, bottom = exposure[source_face == 3], exposure[source_face == 2]  # the +y face and the one on the floor
    assert np.all(top > 0.99) and np.all(bottom == 0.0)
