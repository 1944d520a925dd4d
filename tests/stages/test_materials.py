"""stages.materials: per-face albedo and emission in order of precedence (subset material, prim material,
displayColor, 0.5 grey), with the values worked out by hand for small stages."""

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade
from stage_builders import add_preview_material, add_quads, bind, new_stage
from tolerances import FLOAT32_STORAGE
from usdbake.stages.materials import DEFAULT_ALBEDO, MaterialReader, authored_type

FACES = 3


def shading(prim):
    reader = MaterialReader(Usd.TimeCode.Default())
    return (*reader.face_shading(prim, FACES), reader.warnings)


def display_color(mesh, values, interpolation, type_name=Sdf.ValueTypeNames.Color3fArray):
    primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("displayColor", type_name, interpolation)
    primvar.Set(values)
    return primvar


def test_no_colour_authored_gives_the_grey_default():
    stage = new_stage()
    albedo, emission, surface, warnings = shading(add_quads(stage, "/World/M", FACES).GetPrim())
    np.testing.assert_array_equal(albedo, np.tile(np.float32(DEFAULT_ALBEDO), (FACES, 1)))
    assert not emission.any() and surface == "" and warnings == []


def test_uniform_display_color_is_per_face_and_others_are_averaged():
    stage = new_stage()
    mesh = add_quads(stage, "/World/M", FACES)
    display_color(mesh, [Gf.Vec3f(1, 0, 0), Gf.Vec3f(0, 1, 0), Gf.Vec3f(0, 0, 1)], UsdGeom.Tokens.uniform)
    albedo = shading(mesh.GetPrim())[0]
    np.testing.assert_array_equal(albedo, np.eye(3, dtype=np.float32))
    display_color(mesh, [Gf.Vec3f(0.2, 0.4, 0.6)] * 6 + [Gf.Vec3f(0.8, 0.4, 0.0)] * 6, UsdGeom.Tokens.vertex)
    np.testing.assert_allclose(shading(mesh.GetPrim())[0], np.tile([0.5, 0.4, 0.3], (FACES, 1)), atol=FLOAT32_STORAGE)


def test_a_bound_material_overrides_display_color_and_a_subset_material_overrides_both():
    stage = new_stage()
    mesh = add_quads(stage, "/World/M", FACES)
    display_color(mesh, [Gf.Vec3f(0.9, 0.9, 0.9)], UsdGeom.Tokens.constant)
    bind(mesh.GetPrim(), add_preview_material(stage, "/World/Looks/Red", diffuse=(0.8, 0.1, 0.1),
                                               emissive=(2.0, -1.0, 0.0)))
    subset = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).CreateMaterialBindSubset("blue", [2, 7, -1])  # no face 7, -1
    bind(subset.GetPrim(), add_preview_material(stage, "/World/Looks/Blue", diffuse=(0.1, 0.2, 1.5)))
    albedo, emission, surface, warnings = shading(mesh.GetPrim())
    np.testing.assert_allclose(albedo, [[0.8, 0.1, 0.1], [0.8, 0.1, 0.1], [0.1, 0.2, 1.0]], atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(emission, [[2, 0, 0], [2, 0, 0], [0, 0, 0]], atol=FLOAT32_STORAGE)  # clamped >= 0
    assert surface == "/World/Looks/Red/Surface" and warnings == []


def test_a_material_without_diffuse_color_gives_the_preview_surface_default():
    stage = new_stage()
    mesh = add_quads(stage, "/World/M", FACES)
    bind(mesh.GetPrim(), add_preview_material(stage, "/World/Looks/Plain"))
    np.testing.assert_allclose(shading(mesh.GetPrim())[0], np.full((FACES, 3), 0.18), atol=FLOAT32_STORAGE)


def test_a_display_color_that_is_no_colour_falls_back_with_one_warning():
    stage = new_stage()
    mesh = add_quads(stage, "/World/M", FACES)
    display_color(mesh, [Gf.Vec3f(1, 0, 0)] * 2, UsdGeom.Tokens.uniform)  # 2 values for 3 faces
    albedo, _, _, warnings = shading(mesh.GetPrim())
    np.testing.assert_array_equal(albedo, np.tile(np.float32(DEFAULT_ALBEDO), (FACES, 1)))
    assert len(warnings) == 1 and "2 uniform values for 3 faces" in warnings[0] and "/World/M" in warnings[0]


def test_a_missing_texture_falls_back_to_its_authored_fallback():
    stage = new_stage()
    mesh = add_quads(stage, "/World/M", FACES)
    material = add_preview_material(stage, "/World/Looks/Tex", texture="missing.png")
    UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Tex/Texture")).CreateInput(
        "fallback", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(0.3, 0.6, 0.9, 1.0))
    bind(mesh.GetPrim(), material)
    albedo, _, _, warnings = shading(mesh.GetPrim())
    np.testing.assert_allclose(albedo, np.tile([0.3, 0.6, 0.9], (FACES, 1)), atol=FLOAT32_STORAGE)
    assert len(warnings) == 1 and "not found" in warnings[0] and "inputs:fallback" in warnings[0]


def test_authored_type_is_what_the_layer_wrote():
    stage = new_stage()
    add_quads(stage, "/World/M")
    spec = Sdf.AttributeSpec(stage.GetRootLayer().GetPrimAtPath("/World/M"), "primvars:displayColor",
                             Sdf.ValueTypeNames.Double3Array)
    spec.default = [Gf.Vec3d(1, 0, 0)]
    attribute = UsdGeom.Mesh(stage.GetPrimAtPath("/World/M")).GetDisplayColorAttr()
    assert attribute.GetTypeName() == Sdf.ValueTypeNames.Color3fArray  # the schema's type
    assert authored_type(attribute) == Sdf.ValueTypeNames.Double3Array
