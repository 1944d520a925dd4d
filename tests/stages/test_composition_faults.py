"""Composition faults and unreadable textures (issue 12, item 6).

A missing sublayer, reference or payload stops `usdbake bake` and `plan` (exit 2, one line naming
the asset path and the layer that asks for it) and the hook (StageError, same text) unless missing
assets are allowed; then each is one warning line and the bake goes on without that geometry. A
texture that cannot be read is a warning naming the texture, the shader input and the fallback used.
Input files stay byte-identical in every case.
"""

import warnings
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdShade

import fake_processors as fakes
import usdbake
from stage_builders import add_preview_material, add_quads, bind, new_stage
from tolerances import FLOAT32_STORAGE
from usdbake.cli.main import main
from usdbake.core.errors import StageError
from usdbake.stages.composition import composition_faults
from usdbake.stages.extract import extract_scene
from usdbake.stages.hook import last_warnings

FAST = ["--set", "ambient_occlusion.samples=16"]
AO_FAST = {"ambient_occlusion": {"samples": 16}}

# What each fault adds to the root layer: (layer metadata, prim), and the line that names it.
FAULTS = {
    "sublayer": ("subLayers = [@gone_sublayer.usda@]", "",
                 "sublayer gone_sublayer.usda not found"),
    "reference": ("", 'def Xform "Chair" (\n        prepend references = @gone_reference.usda@\n    )\n    {\n    }',
                  "reference gone_reference.usda on /World/Chair not found"),
    "payload": ("", 'def Xform "Table" (\n        prepend payload = @gone_payload.usda@\n    )\n    {\n    }',
                "payload gone_payload.usda on /World/Table not found"),
}


def write_root(folder: Path, faults=(), extra_prims: str = "") -> Path:
    """folder/root.usda: /World/Set references the ground + cube of folder/set.usda, plus ``faults``."""
    fakes.write_stage(folder / "set.usda")
    metadata = "\n    ".join(FAULTS[fault][0] for fault in faults if FAULTS[fault][0])
    prims = "\n    ".join([FAULTS[fault][1] for fault in faults if FAULTS[fault][1]] + [extra_prims])
    root = folder / "root.usda"
    root.write_text(f"""#usda 1.0
(
    defaultPrim = "World"
    upAxis = "Y"
    {metadata}
)

def Xform "World"
{{
    def Xform "Set" (
        prepend references = @set.usda@
    )
    {{
    }}
    {prims}
}}
""")
    return root


def snapshot(folder: Path) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in sorted(folder.iterdir()) if path.is_file()}


def run_cli(capsys, *argv):
    capsys.readouterr()
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# --- bake and plan refuse a missing asset -----------------------------------------------------


@pytest.mark.parametrize("command", ["bake", "plan"])
@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_a_missing_asset_exits_2_naming_it_and_the_layer_asking(capsys, tmp_path, cache, command, fault):
    root = write_root(tmp_path, [fault])
    before = snapshot(tmp_path)
    output = ["-o", tmp_path / "out.usda"] if command == "bake" else []
    code, out, err = run_cli(capsys, command, root, *output, "--cache", cache, *FAST)

    assert code == 2
    assert out == ""
    assert err == f"usdbake: error: {root}: {FAULTS[fault][2]}; --allow-missing bakes without it\n"
    assert snapshot(tmp_path) == before  # no output, inputs byte-identical


def test_several_missing_assets_name_the_first_and_count_the_rest(capsys, tmp_path, cache):
    root = write_root(tmp_path, ["payload", "reference", "sublayer"])
    code, out, err = run_cli(capsys, "bake", root, "-o", tmp_path / "out.usda", "--cache", cache, *FAST)

    assert code == 2
    assert err == (f"usdbake: error: {root}: sublayer gone_sublayer.usda not found (and 2 more); "
                   "--allow-missing bakes without them\n")
    assert not (tmp_path / "out.usda").exists()


def test_allow_missing_warns_once_per_asset_and_bakes_the_rest(capsys, tmp_path, cache):
    root = write_root(tmp_path, ["payload", "reference", "sublayer"])
    before = snapshot(tmp_path)
    out_path = tmp_path / "out.usda"
    code, out, err = run_cli(capsys, "bake", root, "-o", out_path, "--allow-missing", "--cache", cache, *FAST)

    assert code == 0, err
    warning_lines = [line for line in err.splitlines() if line.startswith("warning:")]
    # Sublayers first, then references and payloads by prim path.
    assert warning_lines == [
        f"warning: {root}: sublayer gone_sublayer.usda not found; baked without it",
        f"warning: {root}: reference gone_reference.usda on /World/Chair not found; baked without it",
        f"warning: {root}: payload gone_payload.usda on /World/Table not found; baked without it",
    ]
    baked = Usd.Stage.Open(str(out_path))
    for path in ("/World/Set/Ground", "/World/Set/Cube"):
        assert baked.GetPrimAtPath(path).GetAttribute("primvars:bake:ao").Get() is not None, path
    after = snapshot(tmp_path)
    assert {name: after[name] for name in before} == before


def test_plan_with_allow_missing_warns_and_plans(capsys, tmp_path, cache):
    root = write_root(tmp_path, ["reference"])
    before = snapshot(tmp_path)
    code, out, err = run_cli(capsys, "plan", root, "--allow-missing", "-p", "ambient_occlusion", "--json",
                             "--cache", cache)

    assert code == 0, err
    assert err == f"warning: {root}: reference gone_reference.usda on /World/Chair not found; baked without it\n"
    assert '"ambient_occlusion"' in out
    assert snapshot(tmp_path) == before


# --- the hook ---------------------------------------------------------------------------------


def test_hook_raises_stage_error_with_the_same_text(tmp_path, cache):
    root = write_root(tmp_path, ["reference"])
    before = snapshot(tmp_path)
    stage = Usd.Stage.Open(str(root))
    with pytest.raises(StageError) as raised:
        usdbake.bake(stage, params=AO_FAST, cache_dir=cache)

    assert str(raised.value) == (f"{root}: reference gone_reference.usda on /World/Chair not found; "
                                 "--allow-missing bakes without it")
    assert list(stage.GetSessionLayer().subLayerPaths) == []  # nothing authored
    assert snapshot(tmp_path) == before


def test_hook_with_allow_missing_reports_the_warnings(tmp_path, cache):
    root = write_root(tmp_path, ["payload", "sublayer"])
    before = snapshot(tmp_path)
    stage = Usd.Stage.Open(str(root))
    expected = [f"{root}: sublayer gone_sublayer.usda not found; baked without it",
                f"{root}: payload gone_payload.usda on /World/Table not found; baked without it"]
    with pytest.warns(UserWarning) as issued:
        layer = usdbake.bake(stage, params=AO_FAST, cache_dir=cache, allow_missing=True)

    assert last_warnings(layer) == expected
    assert [str(w.message) for w in issued] == [f"usdbake: {message}" for message in expected]
    assert stage.GetPrimAtPath("/World/Set/Ground").GetAttribute("primvars:bake:ao").Get() is not None
    assert snapshot(tmp_path) == before


def test_hook_report_of_a_clean_bake_has_no_warnings(tmp_path, cache):
    stage = Usd.Stage.Open(str(write_root(tmp_path)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        layer = usdbake.bake(stage, params=AO_FAST, cache_dir=cache)
    assert last_warnings(layer) == []


# --- what counts as a fault -------------------------------------------------------------------


def test_unreadable_assets_and_missing_targets_are_faults_too(tmp_path):
    (tmp_path / "broken.usda").write_text('#usda 1.0\ndef Xform "X" {\n')
    (tmp_path / "no_default.usda").write_text('#usda 1.0\ndef Xform "X"\n{\n}\n')
    root = write_root(tmp_path, extra_prims="""def Xform "Broken" (
        prepend references = @broken.usda@
    )
    {
    }
    def Xform "NoDefault" (
        prepend references = @no_default.usda@
    )
    {
    }
    def Xform "NoPrim" (
        prepend references = @set.usda@</Nope>
    )
    {
    }""")
    messages = [fault.message() for fault in composition_faults(Usd.Stage.Open(str(root)))]

    broken, no_default, set_layer = (tmp_path / name for name in ("broken.usda", "no_default.usda", "set.usda"))
    assert messages[1:] == [f"{root}: reference {no_default} on /World/NoDefault has no defaultPrim",
                            f"{root}: reference {set_layer}</Nope> on /World/NoPrim not found"]
    # The parser's own words follow in parentheses; their wording is USD's.
    assert messages[0].startswith(f"{root}: reference {broken} on /World/Broken cannot be read ({broken}:")
    assert messages[0].endswith(")") and "\n" not in messages[0]


def test_unloaded_payloads_and_sound_stages_have_no_faults(tmp_path):
    root = write_root(tmp_path, ["payload"])
    assert composition_faults(Usd.Stage.Open(str(root), Usd.Stage.LoadNone)) == []
    assert composition_faults(Usd.Stage.Open(str(write_root(tmp_path)))) == []


# --- textures ---------------------------------------------------------------------------------

MISSING_TEXTURE = ("/World/Looks/Wood/Texture.inputs:file: texture textures/wood.png not found; "
                   "/World/Looks/Wood/Surface.inputs:diffuseColor falls back to (0.18, 0.18, 0.18), "
                   "the UsdPreviewSurface default")


def textured_stage(texture: str, *, fallback=None) -> Usd.Stage:
    """An in-memory stage: one quad bound to a UsdPreviewSurface whose diffuseColor reads ``texture``."""
    stage = new_stage()
    material = add_preview_material(stage, "/World/Looks/Wood", texture=texture)
    if fallback is not None:
        reader = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Wood/Texture"))
        reader.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*fallback))
    bind(add_quads(stage, "/World/Floor").GetPrim(), material)
    return stage


def test_missing_texture_warns_and_uses_the_preview_surface_default():
    scene = extract_scene(textured_stage("textures/wood.png"))
    assert scene.warnings == (MISSING_TEXTURE,)
    np.testing.assert_allclose(scene.tri_albedo, np.full((2, 3), 0.18), atol=FLOAT32_STORAGE)


def test_missing_texture_uses_the_texture_fallback_when_authored():
    scene = extract_scene(textured_stage("textures/wood.png", fallback=(0.2, 0.3, 0.4, 1.0)))
    assert scene.warnings == ("/World/Looks/Wood/Texture.inputs:file: texture textures/wood.png not found; "
                              "/World/Looks/Wood/Surface.inputs:diffuseColor falls back to (0.2, 0.3, 0.4), "
                              "the texture's inputs:fallback",)
    np.testing.assert_allclose(scene.tri_albedo, [[0.2, 0.3, 0.4]] * 2, atol=FLOAT32_STORAGE)


def test_unreadable_texture_warns_with_the_reader_error(tmp_path):
    (tmp_path / "wood.png").write_bytes(b"not a png")
    scene = extract_scene(textured_stage(str(tmp_path / "wood.png")))
    (warning,) = scene.warnings
    assert warning.startswith(f"/World/Looks/Wood/Texture.inputs:file: texture {tmp_path / 'wood.png'} "
                              "cannot be read (")
    assert warning.endswith("); /World/Looks/Wood/Surface.inputs:diffuseColor falls back to (0.18, 0.18, 0.18), "
                            "the UsdPreviewSurface default")


def test_a_shader_other_than_a_texture_is_named_not_evaluated():
    stage = new_stage()
    material = add_preview_material(stage, "/World/Looks/Tint")
    reader = UsdShade.Shader.Define(stage, "/World/Looks/Tint/Reader")
    reader.CreateIdAttr("UsdPrimvarReader_float3")
    surface = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Tint/Surface"))
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        reader.CreateOutput("result", Sdf.ValueTypeNames.Float3))
    bind(add_quads(stage, "/World/Floor").GetPrim(), material)
    scene = extract_scene(stage)
    assert scene.warnings == ("/World/Looks/Tint/Reader: UsdPrimvarReader_float3 is not evaluated; "
                              "/World/Looks/Tint/Surface.inputs:diffuseColor falls back to (0.18, 0.18, 0.18), "
                              "the UsdPreviewSurface default",)


def test_material_interface_inputs_are_followed_without_warnings():
    stage = new_stage()
    material = add_preview_material(stage, "/World/Looks/Paint")
    base = material.CreateInput("baseColor", Sdf.ValueTypeNames.Color3f)
    base.Set(Gf.Vec3f(0.3, 0.4, 0.5))
    surface = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Paint/Surface"))
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(base)
    bind(add_quads(stage, "/World/Floor").GetPrim(), material)
    scene = extract_scene(stage)
    assert scene.warnings == ()
    np.testing.assert_allclose(scene.tri_albedo, [[0.3, 0.4, 0.5]] * 2, atol=FLOAT32_STORAGE)


def write_textured_file(folder: Path) -> Path:
    path = folder / "textured.usda"
    stage = Usd.Stage.CreateNew(str(path))
    fakes.build_stage(stage)
    material = add_preview_material(stage, "/World/Looks/Wood", texture="textures/wood.png")
    bind(stage.GetPrimAtPath("/World/Ground"), material)
    stage.GetRootLayer().Save()
    return path


def test_cli_bake_prints_the_missing_texture_warning(capsys, tmp_path, cache):
    source = write_textured_file(tmp_path)
    before = snapshot(tmp_path)
    code, out, err = run_cli(capsys, "bake", source, "-o", tmp_path / "out.usda", "--cache", cache, *FAST)

    assert code == 0, err
    assert f"warning: {MISSING_TEXTURE}" in err.splitlines()
    after = snapshot(tmp_path)
    assert {name: after[name] for name in before} == before


def test_hook_reports_the_missing_texture(tmp_path, cache):
    source = write_textured_file(tmp_path)
    before = snapshot(tmp_path)
    with pytest.warns(UserWarning, match="texture textures/wood.png not found"):
        layer = usdbake.bake(Usd.Stage.Open(str(source)), params=AO_FAST, cache_dir=cache)
    assert last_warnings(layer) == [MISSING_TEXTURE]
    assert snapshot(tmp_path) == before
