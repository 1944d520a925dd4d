"""preview/channels.py: channel names to attributes, each USD interpolation mapped onto the Scene's triangle
corners (checked against the geometry: values authored as functions of position or of the face a triangle lies
in), sums, the ``irradiance`` fallback, ``NAME[k]`` elements, per-instance values, and the errors and messages
for bad or missing data."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, Vt
from stage_builders import add_mesh, add_quads, add_xform, new_stage
from tolerances import FLOAT32_STORAGE

from usdbake.core.errors import UsageError
from usdbake.preview.channels import IRRADIANCE_PREFIXES, attribute_candidates, read_channel
from usdbake.stages.extract import extract_scene

# Two quads sharing the edge x = 1 (points 1 and 4), in the xz plane, both faces wound alike.
STRIP_POINTS = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 0, -1), (1, 0, -1), (2, 0, -1)]
STRIP_COUNTS = [4, 4]
STRIP_INDICES = [0, 1, 4, 3, 1, 2, 5, 4]


def strip_stage():
    stage = new_stage(up_axis="Y")
    add_mesh(stage, "/World/Strip", STRIP_POINTS, STRIP_COUNTS, STRIP_INDICES)
    return stage


def primvar(stage, path, name, values, interpolation, type_name=Sdf.ValueTypeNames.FloatArray, element_size=None):
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(path)).CreatePrimvar(name, type_name, interpolation)
    if values is not None:
        pv.Set(values)
    if element_size is not None:
        pv.SetElementSize(element_size)
    return pv


def world_corners(scene):
    """(T, 3, 3) float64 world positions of every triangle corner."""
    return scene.points[scene.tri_vertices].astype(np.float64) + scene.origin


def field(p):
    """A linear function of position that tells every strip point apart."""
    return 1.0 + p[..., 0] + 10.0 * p[..., 2]


def test_attribute_candidates_follow_the_naming_rule():
    assert attribute_candidates("ao") == ["primvars:bake:ao", "primvars:ao"]
    assert attribute_candidates("bake:ao") == ["primvars:bake:ao"]
    assert attribute_candidates("primvars:displayColor") == ["primvars:displayColor"]
    assert attribute_candidates("primvars:bake:x") == ["primvars:bake:x"]


def test_vertex_values_land_on_the_corners_at_their_points():
    stage = strip_stage()
    values = field(np.array(STRIP_POINTS, np.float64))
    primvar(stage, "/World/Strip", "bake:ramp", Vt.FloatArray(values.tolist()), UsdGeom.Tokens.vertex)
    scene = extract_scene(stage)
    channel = read_channel(stage, scene, "ramp")
    assert channel.components == 1 and channel.tri_has_value.all()
    assert channel.attributes == ["/World/Strip.primvars:bake:ramp"]
    np.testing.assert_allclose(channel.corner_values[..., 0], field(world_corners(scene)), rtol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(channel.corner_values[..., 1:], 0.0)  # scalars in component 0 only
    assert (channel.lo, channel.hi) == pytest.approx((values.min(), values.max()))
    assert not channel.irradiance and channel.messages == []


def test_varying_reads_like_vertex_and_colours_keep_three_components():
    stage = strip_stage()
    points = np.array(STRIP_POINTS, np.float64)
    colours = np.stack([field(points), 2 * field(points), np.full(len(points), 0.5)], axis=1)
    primvar(stage, "/World/Strip", "bake:tint", Vt.Vec3fArray.FromNumpy(colours.astype(np.float32)),
            UsdGeom.Tokens.varying, Sdf.ValueTypeNames.Color3fArray)
    scene = extract_scene(stage)
    channel = read_channel(stage, scene, "tint")
    assert channel.components == 3
    corners = field(world_corners(scene))
    expected = np.stack([corners, 2 * corners, np.full_like(corners, 0.5)], axis=-1)
    np.testing.assert_allclose(channel.corner_values, expected, rtol=FLOAT32_STORAGE)
    assert (channel.lo, channel.hi) == pytest.approx((colours.min(), colours.max()))


def test_uniform_values_are_constant_over_each_authored_face():
    stage = strip_stage()
    primvar(stage, "/World/Strip", "bake:faces", Vt.FloatArray([0.25, 0.75]), UsdGeom.Tokens.uniform)
    scene = extract_scene(stage)
    channel = read_channel(stage, scene, "faces")
    # The face a triangle belongs to, from geometry: the first quad spans x in [0, 1], the second [1, 2].
    face = (world_corners(scene)[..., 0].mean(axis=1) > 1.0).astype(int)
    expected = np.array([0.25, 0.75])[face]
    np.testing.assert_array_equal(channel.corner_values[..., 0], np.repeat(expected[:, None], 3, axis=1))


def test_constant_value_covers_the_prim():
    stage = strip_stage()
    primvar(stage, "/World/Strip", "bake:level", Vt.FloatArray([0.6]), UsdGeom.Tokens.constant)
    scene = extract_scene(stage)
    channel = read_channel(stage, scene, "level")
    np.testing.assert_allclose(channel.corner_values[..., 0], 0.6, rtol=FLOAT32_STORAGE)
    assert channel.lo == channel.hi == pytest.approx(0.6)


def test_face_varying_values_follow_the_face_of_each_corner():
    """The shared points 1 and 4 carry a different value on each face: each triangle takes its own face's."""
    stage = strip_stage()
    # Value of face f at its corner on point v: 100 f + v (distinct for every face corner).
    values = [100.0 * f + v for f, corner_list in enumerate((STRIP_INDICES[:4], STRIP_INDICES[4:]))
              for v in corner_list]
    primvar(stage, "/World/Strip", "bake:seam", Vt.FloatArray(values), UsdGeom.Tokens.faceVarying)
    scene = extract_scene(stage)
    channel = read_channel(stage, scene, "seam")
    corners = world_corners(scene)
    points = np.array(STRIP_POINTS, np.float64)
    for t in range(scene.num_triangles):
        face = int(corners[t, :, 0].mean() > 1.0)
        for k in range(3):
            point = int(np.argmin(np.linalg.norm(points - corners[t, k], axis=1)))
            assert channel.corner_values[t, k, 0] == 100.0 * face + point


def test_indexed_primvars_are_flattened():
    stage = strip_stage()
    pv = primvar(stage, "/World/Strip", "bake:ix", Vt.FloatArray([5.0, 7.0]), UsdGeom.Tokens.vertex)
    pv.SetIndices(Vt.IntArray([0, 1, 0, 1, 0, 1]))  # point p -> 5 if p even else 7
    scene = extract_scene(stage)
    channel = read_channel(stage, scene, "ix")
    points = np.array(STRIP_POINTS, np.float64)
    corners = world_corners(scene)
    for t in range(scene.num_triangles):
        for k in range(3):
            point = int(np.argmin(np.linalg.norm(points - corners[t, k], axis=1)))
            assert channel.corner_values[t, k, 0] == (5.0 if point % 2 == 0 else 7.0)


def test_prims_without_the_channel_have_no_value_and_a_wrong_count_is_skipped_with_a_message():
    stage = strip_stage()
    add_quads(stage, "/World/Plain", 1)
    add_quads(stage, "/World/Short", 1)
    primvar(stage, "/World/Strip", "bake:ao", Vt.FloatArray([0.5] * 6), UsdGeom.Tokens.vertex)
    primvar(stage, "/World/Short", "bake:ao", Vt.FloatArray([0.5] * 3), UsdGeom.Tokens.vertex)  # 4 points
    scene = extract_scene(stage)
    channel = read_channel(stage, scene, "ao")
    strip = scene.prim_paths.index("/World/Strip")
    np.testing.assert_array_equal(channel.tri_has_value, scene.tri_prim == strip)
    np.testing.assert_array_equal(channel.corner_values[~channel.tri_has_value], 0.0)
    assert any("/World/Short.primvars:bake:ao" in m and "3 vertex values for 4 points" in m
               for m in channel.messages)
    assert channel.attributes == ["/World/Strip.primvars:bake:ao"]


def test_uniform_and_face_varying_count_mismatches_are_skipped_with_a_message():
    stage = strip_stage()
    add_quads(stage, "/World/Other", 1)
    primvar(stage, "/World/Strip", "bake:u", Vt.FloatArray([1.0, 2.0, 3.0]), UsdGeom.Tokens.uniform)
    primvar(stage, "/World/Other", "bake:u", Vt.FloatArray([4.0]), UsdGeom.Tokens.uniform)
    primvar(stage, "/World/Strip", "bake:fv", Vt.FloatArray([1.0] * 7), UsdGeom.Tokens.faceVarying)
    primvar(stage, "/World/Other", "bake:fv", Vt.FloatArray([1.0] * 4), UsdGeom.Tokens.faceVarying)
    scene = extract_scene(stage)
    uniform = read_channel(stage, scene, "u")
    assert any("3 uniform values for 2 faces" in m for m in uniform.messages)
    assert uniform.lo == uniform.hi == 4.0  # the skipped prim's values are left out of the range too
    varying = read_channel(stage, scene, "fv")
    assert any("7 faceVarying values for 8 face corners" in m for m in varying.messages)


def test_the_range_leaves_out_non_finite_values():
    stage = strip_stage()
    primvar(stage, "/World/Strip", "bake:v", Vt.FloatArray([0.2, float("nan"), 0.9, float("inf"), 0.4, 0.3]),
            UsdGeom.Tokens.vertex)
    channel = read_channel(stage, extract_scene(stage), "v")
    assert (channel.lo, channel.hi) == pytest.approx((0.2, 0.9))


def test_sum_adds_where_both_exist_and_keeps_either_elsewhere():
    stage = strip_stage()
    add_quads(stage, "/World/Only", 1)
    points = np.array(STRIP_POINTS, np.float64)
    primvar(stage, "/World/Strip", "bake:a", Vt.FloatArray(field(points).tolist()), UsdGeom.Tokens.vertex)
    primvar(stage, "/World/Strip", "bake:b", Vt.FloatArray([3.0]), UsdGeom.Tokens.constant)
    primvar(stage, "/World/Only", "bake:b", Vt.FloatArray([-2.0]), UsdGeom.Tokens.constant)
    scene = extract_scene(stage)
    total = read_channel(stage, scene, "a + b")
    strip = scene.tri_prim == scene.prim_paths.index("/World/Strip")
    assert total.name == "a + b" and total.tri_has_value.all()
    np.testing.assert_allclose(total.corner_values[strip, :, 0], field(world_corners(scene)[strip]) + 3.0,
                               rtol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(total.corner_values[~strip, :, 0], -2.0)
    # The range of a sum is that of the summed corners: the strip's field + 3 and Only's -2 together.
    summed = np.append(field(points) + 3.0, -2.0)
    assert (total.lo, total.hi) == pytest.approx((summed.min(), summed.max()))
    assert total.attributes == ["/World/Strip.primvars:bake:a", "/World/Strip.primvars:bake:b",
                                "/World/Only.primvars:bake:b"]


def test_bad_sums_are_refused():
    stage = strip_stage()
    primvar(stage, "/World/Strip", "bake:s", Vt.FloatArray([1.0]), UsdGeom.Tokens.constant)
    primvar(stage, "/World/Strip", "bake:c", Vt.Vec3fArray([Gf.Vec3f(1, 2, 3)]), UsdGeom.Tokens.constant,
            Sdf.ValueTypeNames.Color3fArray)
    scene = extract_scene(stage)
    with pytest.raises(UsageError, match="empty term"):
        read_channel(stage, scene, "s+")
    with pytest.raises(UsageError, match="cannot add scalar and colour"):
        read_channel(stage, scene, "s+c")


def test_components_must_agree_across_prims():
    stage = strip_stage()
    add_quads(stage, "/World/Coloured", 1)
    primvar(stage, "/World/Strip", "bake:x", Vt.FloatArray([1.0]), UsdGeom.Tokens.constant)
    primvar(stage, "/World/Coloured", "bake:x", Vt.Vec3fArray([Gf.Vec3f(1, 2, 3)]), UsdGeom.Tokens.constant,
            Sdf.ValueTypeNames.Color3fArray)
    with pytest.raises(UsageError, match="3 components where other prims have 1"):
        read_channel(stage, extract_scene(stage), "x")


def test_non_numeric_primvars_are_refused():
    stage = strip_stage()
    primvar(stage, "/World/Strip", "bake:uv", Vt.Vec2fArray([(0, 0)] * 6), UsdGeom.Tokens.vertex,
            Sdf.ValueTypeNames.TexCoord2fArray)
    with pytest.raises(UsageError, match="cannot be previewed"):
        read_channel(stage, extract_scene(stage), "uv")


def test_a_missing_channel_says_what_was_tried():
    stage = strip_stage()
    scene = extract_scene(stage)
    with pytest.raises(UsageError, match="primvars:bake:nope or primvars:nope"):
        read_channel(stage, scene, "nope")
    with pytest.raises(UsageError, match="at time 3"):
        read_channel(stage, scene, "nope", time=3.0)


def test_a_primvar_without_a_value_is_reported_not_read():
    stage = strip_stage()
    add_quads(stage, "/World/Other", 1)
    primvar(stage, "/World/Strip", "bake:e", None, UsdGeom.Tokens.vertex)
    primvar(stage, "/World/Other", "bake:e", Vt.FloatArray([1.0]), UsdGeom.Tokens.constant)
    scene = extract_scene(stage)
    channel = read_channel(stage, scene, "e")
    assert any("/World/Strip.primvars:bake:e: no value" in m for m in channel.messages)
    np.testing.assert_array_equal(channel.tri_has_value, scene.tri_prim == scene.prim_paths.index("/World/Other"))


def test_time_samples_are_read_at_the_time_asked_for():
    stage = strip_stage()
    pv = primvar(stage, "/World/Strip", "bake:t", None, UsdGeom.Tokens.constant)
    pv.Set(Vt.FloatArray([1.0]), 1.0)
    pv.Set(Vt.FloatArray([3.0]), 3.0)
    scene = extract_scene(stage)
    assert read_channel(stage, scene, "t", time=3.0).hi == 3.0
    assert read_channel(stage, scene, "t", time=2.0).hi == pytest.approx(2.0)  # linear interpolation of samples
    assert read_channel(stage, scene, "t").hi == 1.0  # the default time: the first sample


def test_element_size_picks_an_element_or_averages_them():
    stage = strip_stage()
    values = np.array([[10.0 * p + e for e in range(3)] for p in range(6)])  # point p, element e
    primvar(stage, "/World/Strip", "bake:sh", Vt.FloatArray(values.ravel().tolist()), UsdGeom.Tokens.vertex,
            element_size=3)
    scene = extract_scene(stage)
    points = np.array(STRIP_POINTS, np.float64)
    corners = world_corners(scene)
    point_of = np.argmin(np.linalg.norm(corners[:, :, None] - points[None, None], axis=3), axis=2)  # (T, 3)
    for element in range(3):
        channel = read_channel(stage, scene, f"sh[{element}]")
        np.testing.assert_array_equal(channel.corner_values[..., 0], 10.0 * point_of + element)
        assert channel.messages == []
    mean = read_channel(stage, scene, "sh")
    np.testing.assert_allclose(mean.corner_values[..., 0], 10.0 * point_of + 1.0, rtol=FLOAT32_STORAGE)
    assert any("elementSize 3" in m and "NAME[k]" in m for m in mean.messages)
    with pytest.raises(UsageError, match="element 3 requested but elementSize is 3"):
        read_channel(stage, scene, "sh[3]")


def test_values_not_a_multiple_of_the_element_size_are_refused():
    stage = strip_stage()
    primvar(stage, "/World/Strip", "bake:odd", Vt.FloatArray([1.0] * 7), UsdGeom.Tokens.vertex, element_size=2)
    with pytest.raises(UsageError, match="7 values are not a multiple of elementSize 2"):
        read_channel(stage, extract_scene(stage), "odd[0]")


@pytest.mark.parametrize("parts, expected", [
    (("irradianceDirect", "irradianceIndirect"), "sum"),
    (("irradianceDirect",), "direct"),
    (("irradiance", "irradianceDirect", "irradianceIndirect"), "own"),
])
def test_irradiance_falls_back_to_its_parts(parts, expected):
    stage = strip_stage()
    given = {"irradiance": 100.0, "irradianceDirect": 30.0, "irradianceIndirect": 5.0}
    for part in parts:
        primvar(stage, "/World/Strip", f"bake:{part}", Vt.FloatArray([given[part]]), UsdGeom.Tokens.constant)
    channel = read_channel(stage, extract_scene(stage), "irradiance")
    assert channel.irradiance
    assert channel.hi == {"sum": 35.0, "direct": 30.0, "own": 100.0}[expected]


@pytest.mark.parametrize("name, irradiance", [
    ("irradianceDirect", True), ("daylightIlluminance", True), ("radiosity", True),
    ("primvars:bake:radiosityIndirect", True), ("ao", False), ("skyVisibility", False),
])
def test_irradiance_channels_are_named_by_prefix(name, irradiance):
    stage = strip_stage()
    attribute = name if name.startswith("primvars:") else f"primvars:bake:{name}"
    primvar(stage, "/World/Strip", attribute[len("primvars:"):], Vt.FloatArray([1.0]), UsdGeom.Tokens.constant)
    assert read_channel(stage, extract_scene(stage), name).irradiance is irradiance
    assert any(attribute.split(":")[-1].startswith(p) for p in IRRADIANCE_PREFIXES) is irradiance


def test_a_sum_is_irradiance_when_any_term_is():
    stage = strip_stage()
    primvar(stage, "/World/Strip", "bake:ao", Vt.FloatArray([0.5]), UsdGeom.Tokens.constant)
    primvar(stage, "/World/Strip", "bake:daylight", Vt.FloatArray([2.0]), UsdGeom.Tokens.constant)
    assert read_channel(stage, extract_scene(stage), "ao+daylight").irradiance


def instancer_stage(values, interpolation=UsdGeom.Tokens.varying):
    """Three boxes (unit quads) scattered by a PointInstancer at x = 0, 3, 6, with per-instance values."""
    stage = new_stage(up_axis="Y")
    add_quads(stage, "/World/Protos/Quad", 1)
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    instancer.CreatePrototypesRel().SetTargets([Sdf.Path("/World/Protos/Quad")])
    instancer.CreatePositionsAttr([Gf.Vec3f(3.0 * k, 0, 0) for k in range(3)])
    instancer.CreateProtoIndicesAttr([0, 0, 0])
    UsdGeom.Imageable(stage.GetPrimAtPath("/World/Protos")).MakeInvisible()
    primvar(stage, "/World/Scatter", "bake:level", Vt.FloatArray(values), interpolation)
    return stage


def test_point_instancer_values_colour_each_instance():
    values = [0.1, 0.5, 0.9]
    stage = instancer_stage(values)
    scene = extract_scene(stage)
    channel = read_channel(stage, scene, "level")
    instanced = scene.tri_instance >= 0
    assert instanced.sum() == 6 and channel.tri_has_value[instanced].all()
    instance_of = np.rint(world_corners(scene)[..., 0].min(axis=1) / 3.0).astype(int)  # from the positions
    for t in np.flatnonzero(instanced):
        np.testing.assert_allclose(channel.corner_values[t, :, 0], values[instance_of[t]], rtol=FLOAT32_STORAGE)
    assert (channel.lo, channel.hi) == pytest.approx((0.1, 0.9))
    assert "/World/Scatter.primvars:bake:level" in channel.attributes


def test_point_instancer_values_of_the_wrong_count_are_skipped():
    stage = instancer_stage([0.1, 0.5])
    with pytest.raises(UsageError, match="no prim"):
        read_channel(stage, extract_scene(stage), "level")
    stage = instancer_stage([0.1, 0.5])
    add_quads(stage, "/World/Ground", 1)
    primvar(stage, "/World/Ground", "bake:level", Vt.FloatArray([0.3]), UsdGeom.Tokens.constant)
    channel = read_channel(stage, extract_scene(stage), "level")
    assert any("2 values for 3 instances; skipped" in m for m in channel.messages)


def test_values_on_the_prototype_win_over_per_instance_values():
    stage = instancer_stage([0.1, 0.5, 0.9])
    primvar(stage, "/World/Protos/Quad", "bake:level", Vt.FloatArray([0.7]), UsdGeom.Tokens.constant)
    scene = extract_scene(stage)
    channel = read_channel(stage, scene, "level")
    np.testing.assert_allclose(channel.corner_values[scene.tri_instance >= 0, :, 0], 0.7, rtol=FLOAT32_STORAGE)


def test_native_instances_take_the_constant_value_on_their_root():
    stage = new_stage(up_axis="Y")
    add_xform(stage, "/World/Proto")
    add_quads(stage, "/World/Proto/M", 1)
    UsdGeom.Imageable(stage.GetPrimAtPath("/World/Proto")).MakeInvisible()
    for name, z, value in (("A", 5.0, 0.25), ("B", 10.0, 0.75)):
        root = add_xform(stage, f"/World/{name}", translate=(0, 0, z))
        root.GetPrim().GetReferences().AddInternalReference("/World/Proto")
        root.GetPrim().SetInstanceable(True)
        UsdGeom.Imageable(root).MakeVisible()
        primvar(stage, f"/World/{name}", "bake:level", Vt.FloatArray([value]), UsdGeom.Tokens.constant)
    scene = extract_scene(stage)
    channel = read_channel(stage, scene, "level")
    z = world_corners(scene)[..., 2].mean(axis=1)
    for target, value in ((5.0, 0.25), (10.0, 0.75)):
        at = np.isclose(z, target)
        assert at.sum() == 2 and channel.tri_has_value[at].all()
        np.testing.assert_array_equal(channel.corner_values[at, :, 0], value)


def test_a_channel_of_only_non_finite_values_is_read_or_refused_clearly():
    stage = strip_stage()
    primvar(stage, "/World/Strip", "bake:v", Vt.FloatArray([float("nan")] * 6), UsdGeom.Tokens.vertex)
    try:
        channel = read_channel(stage, extract_scene(stage), "v")
    except UsageError:
        return  # a clear refusal is fine
    assert np.isfinite([channel.lo, channel.hi]).all()


def test_the_range_of_per_instance_values_leaves_out_non_finite_ones():
    stage = instancer_stage([0.1, float("nan"), 0.9])
    channel = read_channel(stage, extract_scene(stage), "level")
    assert (channel.lo, channel.hi) == pytest.approx((0.1, 0.9))
