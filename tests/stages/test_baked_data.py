"""stages.baked_data, the readers ``usdbake preview`` draws from: stages opened or passed through, primvars
flattened to (N, C) float64 (indices applied, faceVarying topology, first time sample at the default
time), UsdGeom cameras, LightProbeCloud and IrradianceVectorGrid prims placed in world space, and a clear
UsageError for what cannot be previewed. Expected values are written out by hand or by plain loops."""

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from stage_builders import add_mesh, add_quads, add_xform, new_stage
from tolerances import FLOAT32_STORAGE, FLOAT64_ROUNDING
from usdbake.core.errors import UsageError  # importing usdbake registers its schemas (LightProbeCloud is Xformable)
from usdbake.stages.baked_data import (CONDON_SHORTLEY_BASIS, has_attribute, open_stage, read_camera,
                                       read_primvar, read_probe_clouds, read_vector_grids)


def primvar(prim_or_mesh, name: str, type_name, value=None, interpolation="vertex", *, indices=None,
            element_size=None, samples=None) -> UsdGeom.Primvar:
    created = UsdGeom.PrimvarsAPI(prim_or_mesh).CreatePrimvar(name, type_name, interpolation)
    if value is not None:
        created.Set(value)
    if indices is not None:
        created.SetIndices(Vt.IntArray(indices))
    if element_size is not None:
        created.SetElementSize(element_size)
    for time, sample in (samples or {}).items():
        created.Set(sample, time)
    return created


# --- open_stage and has_attribute -------------------------------------------------------------


def test_an_open_stage_passes_through_and_a_path_is_opened(tmp_path):
    stage = new_stage()
    assert open_stage(stage) is stage
    path = tmp_path / "scene.usda"
    stage.GetRootLayer().Export(str(path))
    opened = open_stage(str(path))
    assert isinstance(opened, Usd.Stage) and opened.GetPrimAtPath("/World")


def test_open_stage_refuses_what_is_not_a_stage_file(tmp_path):
    with pytest.raises(UsageError) as raised:
        open_stage(str(tmp_path / "missing.usda"))
    assert str(raised.value) == f"{tmp_path / 'missing.usda'}: no such file"
    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\ndef Xform \"X\" {\n")
    with pytest.raises(UsageError) as raised:
        open_stage(str(bad))
    assert str(raised.value).startswith(f"{bad}: cannot be read as USD")
    assert "\n" not in str(raised.value)


def test_has_attribute_looks_at_every_named_prim_and_skips_missing_ones():
    stage = new_stage()
    add_quads(stage, "/World/A")
    primvar(add_quads(stage, "/World/B"), "bake:ao", Sdf.ValueTypeNames.FloatArray, [1.0] * 4)
    assert has_attribute(stage, ["/World/Nope", "/World/A", "/World/B"], ["primvars:bake:light", "primvars:bake:ao"])
    assert not has_attribute(stage, ["/World/A", "/World/Nope"], ["primvars:bake:ao"])
    assert not has_attribute(stage, [], ["primvars:bake:ao"])


# --- read_primvar -----------------------------------------------------------------------------


def test_the_first_named_primvar_the_prim_has_is_read():
    stage = new_stage()
    mesh = add_quads(stage, "/World/Floor")
    primvar(mesh, "bake:ao", Sdf.ValueTypeNames.FloatArray, [0.1, 0.2, 0.3, 0.4])
    primvar(mesh, "bake:light", Sdf.ValueTypeNames.Color3fArray, [(1, 0, 0)] * 4)
    read = read_primvar(stage, "/World/Floor", ["primvars:bake:missing", "primvars:bake:ao", "primvars:bake:light"])
    assert read.attribute == "/World/Floor.primvars:bake:ao"
    assert (read.components, read.interpolation, read.element_size) == (1, "vertex", 1)
    assert read.values.dtype == np.float64 and read.values.shape == (4, 1)
    np.testing.assert_allclose(read.values[:, 0], [0.1, 0.2, 0.3, 0.4], rtol=FLOAT32_STORAGE)
    assert len(read.face_vertex_counts) == 0 and len(read.face_vertex_indices) == 0  # vertex: no topology
    assert read_primvar(stage, "/World/Floor", ["primvars:bake:other"]) is None
    assert read_primvar(stage, "/World/Nope", ["primvars:bake:ao"]) is None


def test_an_indexed_colour_is_flattened_through_its_indices():
    stage = new_stage()
    mesh = add_quads(stage, "/World/Floor", count=2)
    primvar(mesh, "bake:light", Sdf.ValueTypeNames.Color3fArray, [(1, 0, 0), (0, 0.5, 0)], "uniform",
            indices=[1, 0])
    read = read_primvar(stage, "/World/Floor", ["primvars:bake:light"])
    assert (read.components, read.interpolation) == (3, "uniform")
    np.testing.assert_array_equal(read.values, [[0, 0.5, 0], [1, 0, 0]])


def test_face_varying_values_come_with_the_meshs_topology():
    stage = new_stage()
    mesh = add_mesh(stage, "/World/Shape", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0)],
                    [4, 3], [0, 1, 2, 3, 1, 4, 2])
    primvar(mesh, "bake:dirs", Sdf.ValueTypeNames.FloatArray, [float(i) for i in range(14)], "faceVarying",
            element_size=2)
    read = read_primvar(stage, "/World/Shape", ["primvars:bake:dirs"])
    assert (read.interpolation, read.element_size, read.components) == ("faceVarying", 2, 1)
    np.testing.assert_array_equal(read.values[:, 0], np.arange(14))
    np.testing.assert_array_equal(read.face_vertex_counts, [4, 3])
    np.testing.assert_array_equal(read.face_vertex_indices, [0, 1, 2, 3, 1, 4, 2])
    assert read.face_vertex_counts.dtype == np.int64


def test_the_default_time_reads_the_first_sample_and_a_time_reads_its_own():
    stage = new_stage()
    mesh = add_quads(stage, "/World/Floor")
    primvar(mesh, "bake:sun", Sdf.ValueTypeNames.FloatArray,
            samples={5.0: [5.0] * 4, 2.0: [2.0] * 4, 9.0: [9.0] * 4})  # authored out of order
    np.testing.assert_array_equal(read_primvar(stage, "/World/Floor", ["primvars:bake:sun"]).values, [[2.0]] * 4)
    np.testing.assert_array_equal(read_primvar(stage, "/World/Floor", ["primvars:bake:sun"], time=9).values,
                                  [[9.0]] * 4)


def test_a_primvar_without_a_value_comes_back_empty():
    stage = new_stage()
    primvar(add_quads(stage, "/World/Floor"), "bake:ao", Sdf.ValueTypeNames.FloatArray, interpolation="vertex")
    read = read_primvar(stage, "/World/Floor", ["primvars:bake:ao"])
    assert read.attribute == "/World/Floor.primvars:bake:ao"
    assert read.values is None and read.components == 0 and read.interpolation == "vertex"


@pytest.mark.parametrize("type_name, value, shape", [
    (Sdf.ValueTypeNames.Float2Array, [(1, 2), (3, 4)], "(2,)"),
    (Sdf.ValueTypeNames.Float4Array, [(1, 2, 3, 4)], "(4,)"),
    (Sdf.ValueTypeNames.Matrix4dArray, Vt.Matrix4dArray([Gf.Matrix4d(1)]), "(4, 4)"),
], ids=["float2", "float4", "matrix"])
def test_a_primvar_of_another_shape_is_refused_naming_it_and_its_type(type_name, value, shape):
    stage = new_stage()
    primvar(add_quads(stage, "/World/Floor"), "bake:odd", type_name, value, "constant")
    with pytest.raises(UsageError) as raised:
        read_primvar(stage, "/World/Floor", ["primvars:bake:odd"])
    assert str(raised.value) == (f"/World/Floor.primvars:bake:odd: type {type_name} cannot be previewed (need a "
                                 f"float or a 3-vector/colour, got shape {shape})")


def test_a_text_primvar_is_refused_naming_it():
    stage = new_stage()
    primvar(add_quads(stage, "/World/Floor"), "bake:tag", Sdf.ValueTypeNames.StringArray, ["a", "b"], "constant")
    with pytest.raises(UsageError, match=r"/World/Floor\.primvars:bake:tag: type string\[\] cannot be previewed"):
        read_primvar(stage, "/World/Floor", ["primvars:bake:tag"])


@pytest.mark.parametrize("type_name, value, expected", [
    (Sdf.ValueTypeNames.Color3f, Gf.Vec3f(0.25, 0.5, 1.0), [[0.25, 0.5, 1.0]]),
    (Sdf.ValueTypeNames.Float, 0.5, [[0.5]]),
], ids=["color3f", "float"])
def test_a_constant_scalar_primvar_is_one_value(type_name, value, expected):
    stage = new_stage()
    primvar(add_quads(stage, "/World/Floor"), "bake:tint", type_name, value, "constant")
    read = read_primvar(stage, "/World/Floor", ["primvars:bake:tint"])
    np.testing.assert_array_equal(read.values, expected)


# --- read_camera ------------------------------------------------------------------------------


def define_camera(stage, path="/World/Cam", **attributes) -> UsdGeom.Camera:
    camera = UsdGeom.Camera.Define(stage, path)
    camera.AddRotateYOp().Set(90.0)
    camera.AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))  # xformOpOrder [rotateY, translate]: points move first
    for name, value in attributes.items():
        getattr(camera, f"Create{name[0].upper()}{name[1:]}Attr")(value)
    return camera


def test_a_camera_is_read_with_its_transform_and_lens():
    stage = new_stage()
    define_camera(stage, focalLength=35.0, horizontalAperture=36.0, verticalAperture=24.0,
                  horizontalApertureOffset=1.0, verticalApertureOffset=-2.0)
    read = read_camera(stage, "/World/Cam")
    # p' = p T R with R a 90 degree turn about y (x -> -z, z -> x): the origin lands at (3, 2, -1)
    expected = np.array([[0, 0, -1, 0], [0, 1, 0, 0], [1, 0, 0, 0], [3, 2, -1, 1]], np.float64)
    np.testing.assert_allclose(read.camera_to_world, expected, atol=FLOAT64_ROUNDING)
    assert (read.focal_length, read.horizontal_aperture, read.vertical_aperture) == (35.0, 36.0, 24.0)
    assert (read.horizontal_aperture_offset, read.vertical_aperture_offset) == (1.0, -2.0)
    assert read.projection == "perspective"


def test_an_orthographic_camera_says_so():
    stage = new_stage()
    define_camera(stage, projection=UsdGeom.Tokens.orthographic)
    assert read_camera(stage, "/World/Cam").projection == "orthographic"


def test_a_camera_path_that_names_no_camera_is_refused_listing_the_cameras():
    stage = new_stage()
    define_camera(stage, "/World/Cam")
    define_camera(stage, "/World/Rig/Side")
    add_xform(stage, "/World/Box")
    stage.DefinePrim("/World/Thing")
    for path in ("/World/Nope", "not a path"):
        with pytest.raises(UsageError) as raised:
            read_camera(stage, path)
        assert str(raised.value) == f"--camera {path}: no such prim (cameras in the stage: /World/Cam, /World/Rig/Side)"
    with pytest.raises(UsageError, match=r"^--camera /World/Box: is a Xform, not a Camera$"):
        read_camera(stage, "/World/Box")
    with pytest.raises(UsageError, match=r"^--camera /World/Thing: is a typeless prim, not a Camera$"):
        read_camera(stage, "/World/Thing")
    with pytest.raises(UsageError, match=r"cameras in the stage: none\)$"):
        read_camera(new_stage(), "/World/Cam")


def test_a_camera_without_a_positive_lens_is_refused():
    stage = new_stage()
    define_camera(stage, focalLength=0.0, horizontalAperture=36.0, verticalAperture=24.0)
    with pytest.raises(UsageError) as raised:
        read_camera(stage, "/World/Cam")
    assert str(raised.value) == "/World/Cam: focal length 0.0 and apertures 36.0 x 24.0 must be positive"


# --- probe clouds -----------------------------------------------------------------------------


def test_probe_clouds_are_placed_in_world_space_with_their_coefficients_per_probe():
    stage = new_stage()
    add_xform(stage, "/World/Rig", translate=(10, 0, 0), scale=(2, 2, 2))
    cloud = stage.DefinePrim("/World/Rig/Probes", "LightProbeCloud")
    cloud.GetAttribute("probePositions").Set(Vt.Vec3fArray([(0, 0, 0), (1, 0, 0), (0, 0, 1)]))
    # coefficient k of probe p, colour c: (p, k, c / 2)
    cloud.GetAttribute("shCoefficients").Set(Vt.Vec3fArray([(p, k, 0.5) for p in range(3) for k in range(9)]))
    cloud.GetAttribute("shBasis").Set(CONDON_SHORTLEY_BASIS)
    other = stage.DefinePrim("/World/Other", "LightProbeCloud")
    other.GetAttribute("probePositions").Set(Vt.Vec3fArray([(0, 5, 0)]))
    other.GetAttribute("shCoefficients").Set(Vt.Vec3fArray([(1, 1, 1)] * 8))  # one short of 9: not used
    stage.DefinePrim("/World/Empty", "LightProbeCloud").GetAttribute("probePositions").Set(Vt.Vec3fArray())

    clouds = read_probe_clouds(stage)
    assert [c.path for c in clouds] == ["/World/Rig/Probes", "/World/Other"]  # the empty cloud is left out
    rig, other_cloud = clouds
    np.testing.assert_allclose(rig.probe_positions, [(10, 0, 0), (12, 0, 0), (10, 0, 2)], atol=FLOAT64_ROUNDING)
    assert rig.probe_sh.shape == (3, 9, 3) and rig.probe_sh.dtype == np.float32
    for p in range(3):
        for k in range(9):
            assert tuple(rig.probe_sh[p, k]) == (p, k, 0.5)
    assert rig.condon_shortley
    np.testing.assert_allclose(other_cloud.probe_positions, [(0, 5, 0)])
    assert other_cloud.probe_sh is None and not other_cloud.condon_shortley  # the schema's realOrthonormal


def test_probe_positions_follow_the_time_asked_for():
    stage = new_stage()
    cloud = stage.DefinePrim("/World/Probes", "LightProbeCloud")
    UsdGeom.Xformable(cloud).AddTranslateOp().Set(Gf.Vec3d(0, 0, 4), 3.0)
    cloud.GetAttribute("probePositions").Set(Vt.Vec3fArray([(1, 0, 0)]))
    np.testing.assert_allclose(read_probe_clouds(stage, time=3)[0].probe_positions, [(1, 0, 4)])


# --- vector grids -----------------------------------------------------------------------------


def test_a_vector_grid_lattice_runs_x_fastest_then_y_then_z_in_world_space():
    stage = new_stage()
    add_xform(stage, "/World/Rig", translate=(0, 0, 10))
    grid = stage.DefinePrim("/World/Rig/Grid", "IrradianceVectorGrid")
    grid.GetAttribute("resolution").Set(Gf.Vec3i(2, 3, 4))
    grid.GetAttribute("gridOrigin").Set(Gf.Vec3f(1, 2, 3))
    grid.GetAttribute("cellSize").Set(Gf.Vec3f(0.5, 1, 2))
    grid.GetAttribute("colorsRGB9E5").Set(Vt.UIntArray(list(range(24 * 6))))
    skipped = stage.DefinePrim("/World/Flat", "IrradianceVectorGrid")
    skipped.GetAttribute("resolution").Set(Gf.Vec3i(4, 0, 4))
    stage.DefinePrim("/World/Unset", "IrradianceVectorGrid")  # resolution (0, 0, 0): nothing to draw

    [read] = read_vector_grids(stage)
    assert read.path == "/World/Rig/Grid"
    expected = [(1 + 0.5 * i, 2 + 1.0 * j, 3 + 2.0 * k + 10) for k in range(4) for j in range(3) for i in range(2)]
    np.testing.assert_allclose(read.vertex_positions, expected, atol=FLOAT64_ROUNDING)
    np.testing.assert_array_equal(read.vertex_colors_rgb9e5, np.arange(24 * 6))
    assert read.vertex_colors_rgb9e5.dtype == np.uint32
    assert read.vectors_per_vertex == 6  # the schema's fallback


def test_a_vector_grid_with_its_own_vector_count_and_no_colours():
    stage = new_stage()
    grid = stage.DefinePrim("/World/Grid", "IrradianceVectorGrid")
    grid.GetAttribute("resolution").Set(Gf.Vec3i(1, 1, 2))
    grid.GetAttribute("vectorsPerVertex").Set(2)
    [read] = read_vector_grids(stage)
    assert read.vectors_per_vertex == 2 and len(read.vertex_colors_rgb9e5) == 0
    np.testing.assert_allclose(read.vertex_positions, [(0, 0, 0), (0, 0, 1)])  # the schema's origin and cell
