"""Glazing (issue 29): the visible transmittance of transparent faces, read from the stage, and the rays
through them (processors.daylight.glazing).

- the angular falloff of Radiance's ``glass``: the VLT at normal incidence, monotone, 0 at grazing, and
  equal to Fresnel's equations for a thin slab written here independently (angles via Snell's law,
  Radiance's own transmissivity formula), with the Warp twin against the numpy one;
- ``segment_transmittance`` in a kernel: through 0, 1 and 2 parallel panes of VLT 0.6 the product of
  the falloffs, a pane's shared diagonal counted once, 16 panes crossed and a 17th refused, at 1, 1e-9
  and 1e9 stage units;
- extraction: UsdPreviewSurface opacity, ``bake:transmittance`` on the mesh and on the material,
  GeomSubset bindings, point-instanced glass, opacity from a texture, cutouts; bad values refused with
  one line naming prim, attribute and value, before any compute (through the command);
- ``Glazing.of_scene``: None without glass; its opaque tracer does not meet the pane, its glass tracer
  does, both scaled alike; the materials fingerprint sees the transmittance.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import warp as wp
from hypothesis import given
from hypothesis import strategies as st
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade
from stage_builders import add_mesh, add_preview_material, bind, write_png
from glass_reference import slab_transmittance
from tolerances import FLOAT32_STORAGE, FLOAT32_WARP_MATH, FLOAT64_ROUNDING, RADIANCE_GLASS_DIGITS
from usdbake.cli.main import main
from usdbake.core.errors import StageError
from usdbake.kernels.traversal import TraceScene
from usdbake.processors.daylight.glazing import (CLEAR_TRANSMITTANCE, MAX_CROSSINGS, Glazing, glass_transmittance,
                                                 radiance_glass_transmittance, segment_transmittance)
from usdbake.stages.extract import extract_scene

wp.set_module_options({"enable_backward": False})

VLT = 0.6
"""The issue's office window."""


@wp.kernel
def falloff_kernel(cos_i: wp.array(dtype=float), vlt: wp.array(dtype=float), out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = glass_transmittance(cos_i[i], vlt[i])


@wp.kernel
def segment_kernel(glass: TraceScene, glass_tn: wp.array(dtype=float), glass_normal: wp.array(dtype=wp.vec3),
                   origins: wp.array(dtype=wp.vec3), directions: wp.array(dtype=wp.vec3),
                   max_t: wp.array(dtype=float), epsilon: float, out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = segment_transmittance(glass, glass_tn, glass_normal, origins[i], directions[i], max_t[i], epsilon)


def warp_falloff(cos_i, vlt) -> np.ndarray:
    cos_i, vlt = np.broadcast_arrays(np.asarray(cos_i, np.float32), np.asarray(vlt, np.float32))
    out = wp.zeros(cos_i.size, dtype=float, device="cpu")
    wp.launch(falloff_kernel, dim=cos_i.size, device="cpu",
              inputs=[wp.array(cos_i.ravel(), dtype=float, device="cpu"),
                      wp.array(vlt.ravel(), dtype=float, device="cpu"), out])
    return out.numpy().reshape(cos_i.shape)


def segment(glazing: Glazing, origins, directions, max_t) -> np.ndarray:
    origins = np.asarray(origins, np.float32).reshape(-1, 3)
    directions = np.asarray(directions, np.float32).reshape(-1, 3)
    max_t = np.broadcast_to(np.asarray(max_t, np.float32), len(origins)).copy()
    out = wp.zeros(len(origins), dtype=float, device="cpu")
    wp.launch(segment_kernel, dim=len(origins), device="cpu",
              inputs=[glazing.glass_scene, glazing.glass_tn, glazing.glass_normal,
                      wp.array(origins, dtype=wp.vec3, device="cpu"), wp.array(directions, dtype=wp.vec3, device="cpu"),
                      wp.array(max_t, dtype=float, device="cpu"), glazing.glass_tracer.epsilon, out])
    return out.numpy()


def slab(theta_deg: float, vlt: float) -> float:
    return float(slab_transmittance(np.cos(np.radians(theta_deg)), vlt))


# -- (a) the angular falloff ---------------------------------------------------------------------------

def test_the_falloff_is_the_vlt_at_normal_incidence_and_zero_at_grazing():
    vlt = np.linspace(0.0, 1.0, 201)
    np.testing.assert_allclose(radiance_glass_transmittance(1.0, vlt), vlt, atol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(radiance_glass_transmittance(-1.0, vlt), vlt, atol=FLOAT64_ROUNDING)  # either side
    np.testing.assert_allclose(warp_falloff(1.0, vlt), vlt.astype(np.float32), atol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(radiance_glass_transmittance(0.0, vlt), 0.0)
    np.testing.assert_array_equal(warp_falloff(0.0, vlt), 0.0)
    assert radiance_glass_transmittance(1e-4, 1.0) < 1e-3  # the clear limit tends to 0 too


@pytest.mark.parametrize("vlt", [0.05, VLT, 0.88, CLEAR_TRANSMITTANCE, 0.95, 1.0])
def test_the_falloff_decreases_monotonically_with_the_angle(vlt):
    cos_i = np.cos(np.radians(np.linspace(0.0, 90.0, 9001)))
    values = radiance_glass_transmittance(cos_i, vlt)
    assert (np.diff(values) <= 0.0).all()
    assert values[0] == pytest.approx(vlt, abs=FLOAT64_ROUNDING) and values[-1] < 1e-3
    np.testing.assert_allclose(warp_falloff(cos_i, vlt), values, atol=FLOAT32_WARP_MATH)


@pytest.mark.parametrize("theta", [20.0, 50.0, 80.0])
def test_the_falloff_is_fresnels_for_a_thin_slab(theta):
    expected = slab(theta, VLT)
    cos_i = math.cos(math.radians(theta))
    assert radiance_glass_transmittance(cos_i, VLT) == pytest.approx(expected, rel=RADIANCE_GLASS_DIGITS)
    assert warp_falloff(cos_i, VLT) == pytest.approx(expected, abs=FLOAT32_WARP_MATH)


@given(st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_the_falloff_stays_within_zero_and_the_vlt(cos_i, vlt):
    value = float(radiance_glass_transmittance(cos_i, vlt))
    assert 0.0 <= value <= vlt + FLOAT64_ROUNDING


# -- (b) rays through panes ------------------------------------------------------------------------------

def panes(heights, vlt=VLT, *, half=2.0, wall=True, scale=1.0):
    """Square panes (two triangles each, diagonal from (-half, -half) to (half, half)) at z = each height,
    and, unless not ``wall``, an opaque quad at x = 3 (in the plane of no ray here): points, triangles,
    normals and transmittances, all times ``scale``."""
    points, triangles, transmittance = [], [], []
    for z in heights:
        base = len(points)
        points += [(-half, -half, z), (half, -half, z), (half, half, z), (-half, half, z)]
        triangles += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
        transmittance += [vlt, vlt]
    if wall:
        base = len(points)
        points += [(3, -1, 0), (3, 1, 0), (3, 1, 1), (3, -1, 1)]
        triangles += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
        transmittance += [0.0, 0.0]
    points = np.array(points, np.float64) * scale
    triangles = np.array(triangles, np.int32)
    corners = points[triangles]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = cross / np.linalg.norm(cross, axis=1, keepdims=True)
    return points.astype(np.float32), triangles, normals.astype(np.float32), np.array(transmittance, np.float32)


@pytest.mark.parametrize("scale", [1.0, 1e-9, 1e9])
def test_rays_through_zero_one_and_two_panes(scale):
    points, triangles, normals, transmittance = panes([1.0, 2.0], scale=scale)
    glazing = Glazing(points, triangles, normals, transmittance)
    assert glazing.glass_tracer.scale == glazing.opaque_tracer.scale
    assert (glazing.glass_tracer.scale == 1.0) == (scale == 1.0)  # the far scales go through the scaled core
    theta = np.radians(35.0)
    up = np.array([np.sin(theta), 0.0, np.cos(theta)])  # meets z = 1 at x = 0.70, z = 2 at x = 1.40
    diagonal = np.array([1.0, 1.0, 2.0]) / np.sqrt(6.0)  # meets each pane on its shared diagonal
    cos_diagonal = 2.0 / np.sqrt(6.0)
    origins = np.zeros((7, 3))
    directions = np.array([up, up, up, -up, diagonal, 2.0 * up, [0.0, 0.0, 0.0]])
    lengths = np.array([0.5 / np.cos(theta), 1.5 / np.cos(theta), 1e20, 1e20, 1e20, 1.5 / np.cos(theta) / 2, 1e20])
    got = segment(glazing, origins * scale, directions, lengths * scale)
    one = radiance_glass_transmittance(np.cos(theta), VLT)
    expected = [1.0, one, one ** 2, 1.0, radiance_glass_transmittance(cos_diagonal, VLT) ** 2, one, 1.0]
    np.testing.assert_allclose(got, expected, atol=FLOAT32_WARP_MATH)


def test_more_panes_than_max_crossings_block_the_ray():
    """16 clear panes (VLT 1) keep the product of their falloffs, a 17th blocks the ray."""
    heights = 1.0 + 0.25 * np.arange(MAX_CROSSINGS + 1)
    glazing = Glazing(*panes(heights, vlt=1.0))
    direction = np.array([0.0, 0.1, 1.0]) / np.linalg.norm([0.0, 0.1, 1.0])  # off the panes' diagonals
    got = segment(glazing, np.zeros((2, 3)), np.tile(direction, (2, 1)), [heights[-2] + 0.1, heights[-1] + 0.1])
    each = radiance_glass_transmittance(direction[2], 1.0)
    np.testing.assert_allclose(got, [each ** MAX_CROSSINGS, 0.0], atol=MAX_CROSSINGS * FLOAT32_WARP_MATH)


# -- (c) extraction --------------------------------------------------------------------------------------

WINDOW = "/World/Window"
FLOOR = "/World/Floor"
GLASS = "/World/Looks/Glass"


def room(tmp_path, edit=None, *, opacity=0.4) -> str:
    """A floor (no material) and a window quad bound to a UsdPreviewSurface of ``opacity``; ``edit(stage)``
    before saving. Written to tmp_path/room.usda."""
    path = str(tmp_path / "room.usda")
    stage = Usd.Stage.CreateNew(path)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    add_mesh(stage, FLOOR, [(0, 0, 0), (4, 0, 0), (4, 0, 4), (0, 0, 4)], [4], [0, 3, 2, 1])
    add_mesh(stage, WINDOW, [(1, 1, 0), (3, 1, 0), (3, 2, 0), (1, 2, 0)], [4], [0, 1, 2, 3])
    material = add_preview_material(stage, GLASS, diffuse=(0.1, 0.1, 0.1))
    if opacity is not None:
        surface = UsdShade.Shader(stage.GetPrimAtPath(f"{GLASS}/Surface"))
        surface.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(opacity)
    bind(stage.GetPrimAtPath(WINDOW), material)
    if edit is not None:
        edit(stage)
    stage.Save()
    return path


def transmittance_of(scene, path: str) -> np.ndarray:
    return scene.tri_transmittance[scene.tri_prim == scene.prim_paths.index(path)]


def set_float(prim_path: str, value, type_name=Sdf.ValueTypeNames.Float):
    def edit(stage):
        stage.GetPrimAtPath(prim_path).CreateAttribute("bake:transmittance", type_name).Set(value)
    return edit


def test_opacity_gives_the_window_its_transmittance_and_the_rest_none(tmp_path):
    scene = extract_scene(Usd.Stage.Open(room(tmp_path)))
    assert scene.tri_transmittance.dtype == np.float32 and scene.tri_transmittance.shape == (scene.num_triangles,)
    np.testing.assert_allclose(transmittance_of(scene, WINDOW), [0.6, 0.6], atol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(transmittance_of(scene, FLOOR), [0.0, 0.0])
    assert scene.warnings == ()


def test_an_opaque_or_unset_opacity_is_no_glazing(tmp_path):
    for opacity in (1.0, None):
        scene = extract_scene(Usd.Stage.Open(room(tmp_path, opacity=opacity)))
        np.testing.assert_array_equal(scene.tri_transmittance, 0.0)


def test_bake_transmittance_on_the_mesh_overrides_the_material(tmp_path):
    scene = extract_scene(Usd.Stage.Open(room(tmp_path, set_float(WINDOW, 0.7))))
    np.testing.assert_allclose(transmittance_of(scene, WINDOW), [0.7, 0.7], atol=FLOAT32_STORAGE)
    scene = extract_scene(Usd.Stage.Open(room(tmp_path, set_float(FLOOR, 0.25, Sdf.ValueTypeNames.Double))))
    np.testing.assert_allclose(transmittance_of(scene, FLOOR), [0.25, 0.25], atol=FLOAT32_STORAGE)


def test_bake_transmittance_on_the_material_overrides_its_opacity_and_the_mesh_its_material(tmp_path):
    scene = extract_scene(Usd.Stage.Open(room(tmp_path, set_float(GLASS, 0.5))))
    np.testing.assert_allclose(transmittance_of(scene, WINDOW), [0.5, 0.5], atol=FLOAT32_STORAGE)

    def both(stage):
        set_float(GLASS, 0.5)(stage)
        set_float(WINDOW, 0.0)(stage)
    scene = extract_scene(Usd.Stage.Open(room(tmp_path, both)))
    np.testing.assert_array_equal(transmittance_of(scene, WINDOW), [0.0, 0.0])


def test_a_subset_bound_glass_material_glazes_its_faces_only(tmp_path):
    def facade(stage):
        add_mesh(stage, "/World/Facade", [(0, 0, 5), (1, 0, 5), (1, 1, 5), (0, 1, 5), (2, 0, 5), (2, 1, 5)],
                 [4, 4], [0, 1, 2, 3, 1, 4, 5, 2])
        binding = UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath("/World/Facade"))
        subset = binding.CreateMaterialBindSubset("pane", [1])
        bind(subset.GetPrim(), UsdShade.Material(stage.GetPrimAtPath(GLASS)))
    scene = extract_scene(Usd.Stage.Open(room(tmp_path, facade)))
    facade_tris = scene.tri_prim == scene.prim_paths.index("/World/Facade")
    expected = np.where(scene.tri_face[facade_tris] == 1, 0.6, 0.0)
    np.testing.assert_allclose(scene.tri_transmittance[facade_tris], expected, atol=FLOAT32_STORAGE)


def test_instanced_glass_carries_its_transmittance(tmp_path):
    def instancer(stage):
        inst = UsdGeom.PointInstancer.Define(stage, "/World/Panes")
        add_mesh(stage, "/World/Panes/Protos/Pane", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [4], [0, 1, 2, 3])
        set_float("/World/Panes/Protos/Pane", 0.3)(stage)
        inst.CreatePrototypesRel().SetTargets([Sdf.Path("/World/Panes/Protos/Pane")])
        inst.CreateProtoIndicesAttr([0, 0, 0])
        inst.CreatePositionsAttr([Gf.Vec3f(0, 0, 8 + i) for i in range(3)])
    scene = extract_scene(Usd.Stage.Open(room(tmp_path, instancer)))
    instanced = scene.tri_instance >= 0
    assert instanced.sum() == 6
    np.testing.assert_allclose(scene.tri_transmittance[instanced], 0.3, atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(transmittance_of(scene, WINDOW), [0.6, 0.6], atol=FLOAT32_STORAGE)


def opacity_texture(output: str, *, threshold: float | None = None):
    """The window's opacity connected to ``output`` of a UsdUVTexture whose red channel is 51/255 = 0.2 (raw)."""
    def edit(stage):
        folder = stage.GetRootLayer().realPath.rsplit("/", 1)[0]
        png = write_png(f"{folder}/opacity.png", np.tile(np.array([51, 200, 0], np.uint8), (4, 4, 1)))
        texture = UsdShade.Shader.Define(stage, f"{GLASS}/Opacity")
        texture.CreateIdAttr("UsdUVTexture")
        texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(png))
        texture.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
        source = texture.CreateOutput(output, Sdf.ValueTypeNames.Float)
        surface = UsdShade.Shader(stage.GetPrimAtPath(f"{GLASS}/Surface"))
        surface.GetInput("opacity").ConnectToSource(source)
        if threshold is not None:
            surface.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(threshold)
    return edit


def test_an_opacity_texture_gives_one_minus_its_mean(tmp_path):
    scene = extract_scene(Usd.Stage.Open(room(tmp_path, opacity_texture("r"))))
    np.testing.assert_allclose(transmittance_of(scene, WINDOW), [0.8, 0.8], atol=FLOAT32_STORAGE)
    assert scene.warnings == ()


def test_an_opacity_from_alpha_is_opaque_with_one_warning(tmp_path):
    scene = extract_scene(Usd.Stage.Open(room(tmp_path, opacity_texture("a"))))
    np.testing.assert_array_equal(scene.tri_transmittance, 0.0)
    assert len(scene.warnings) == 1
    assert scene.warnings[0].startswith(f"{GLASS}/Surface.inputs:opacity: connected to {GLASS}/Opacity.outputs:a")
    assert "treated as opaque" in scene.warnings[0]


def test_a_cutout_is_no_glazing(tmp_path):
    """opacityThreshold > 0: the opacity is an alpha mask (leaves, fences), drawn or not, never glass."""
    scene = extract_scene(Usd.Stage.Open(room(tmp_path, opacity_texture("a", threshold=0.5))))
    np.testing.assert_array_equal(scene.tri_transmittance, 0.0)
    assert scene.warnings == ()


BAD_VALUES = {
    "above one": (WINDOW, 1.5, Sdf.ValueTypeNames.Float, f"{WINDOW}.bake:transmittance: 1.5 is outside [0, 1]"),
    "nan": (WINDOW, float("nan"), Sdf.ValueTypeNames.Float, f"{WINDOW}.bake:transmittance: nan is outside [0, 1]"),
    "negative on the material": (GLASS, -0.25, Sdf.ValueTypeNames.Double,
                                 f"{GLASS}.bake:transmittance: -0.25 is outside [0, 1]"),
    "inf": (WINDOW, float("inf"), Sdf.ValueTypeNames.Float, f"{WINDOW}.bake:transmittance: inf is outside [0, 1]"),
    "a string": (WINDOW, "clear", Sdf.ValueTypeNames.String,
                 f'{WINDOW}.bake:transmittance: string "clear" is not a float (a share of light in [0, 1])'),
    "an int": (WINDOW, 1, Sdf.ValueTypeNames.Int,
               f"{WINDOW}.bake:transmittance: int 1 is not a float (a share of light in [0, 1])"),
}


@pytest.mark.parametrize("case", BAD_VALUES)
def test_a_bad_transmittance_is_one_line_naming_prim_attribute_and_value(tmp_path, case):
    prim, value, type_name, line = BAD_VALUES[case]
    with pytest.raises(StageError) as error:
        extract_scene(Usd.Stage.Open(room(tmp_path, set_float(prim, value, type_name))))
    assert str(error.value) == line
    assert (error.value.prim, error.value.attribute) == (prim, "bake:transmittance")


def test_a_bad_opacity_is_one_line_too(tmp_path):
    with pytest.raises(StageError) as error:
        extract_scene(Usd.Stage.Open(room(tmp_path, opacity=1.5)))
    assert str(error.value) == f"{GLASS}/Surface.inputs:opacity: 1.5 is outside [0, 1]"


@pytest.mark.parametrize("case", ["above one", "nan"])
def test_a_bad_transmittance_is_refused_before_compute(tmp_path, capfd, no_compute, case):
    prim, value, type_name, line = BAD_VALUES[case]
    source = room(tmp_path, set_float(prim, value, type_name))
    out = tmp_path / "out.usda"
    capfd.readouterr()
    code = main(["bake", source, "-o", str(out), "-p", "ambient_occlusion", "--set", "ambient_occlusion.samples=16"])
    err = capfd.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert err.strip().splitlines()[-1] == f"usdbake: error: {line}", err
    assert not out.exists()


# -- (d) Glazing.of_scene --------------------------------------------------------------------------------

def test_a_scene_without_glass_has_no_glazing(tmp_path):
    assert Glazing.of_scene(extract_scene(Usd.Stage.Open(room(tmp_path, opacity=None)))) is None


def test_the_opaque_tracer_misses_the_pane_and_the_glass_tracer_meets_it(tmp_path):
    scene = extract_scene(Usd.Stage.Open(room(tmp_path)))
    glazing = Glazing.of_scene(scene, "cpu")
    window = np.flatnonzero(scene.tri_prim == scene.prim_paths.index(WINDOW))
    np.testing.assert_array_equal(glazing.glass_triangles, window)
    np.testing.assert_array_equal(np.sort(np.concatenate([glazing.opaque_triangles, glazing.glass_triangles])),
                                  np.arange(scene.num_triangles))
    assert glazing.glass_triangles.dtype == glazing.opaque_triangles.dtype == np.int32
    np.testing.assert_allclose(glazing.glass_tn.numpy(), 0.6, atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(glazing.glass_normal.numpy(), scene.tri_normals[window])
    assert glazing.glass_tracer.scale == glazing.opaque_tracer.scale
    assert glazing.glass_scene is glazing.glass_tracer.scene

    # Rays from z = 1 towards -z through the window's middle (world (2, 1.5, 0)), in the scene's frame.
    origin = np.array([[2.0, 1.5, 1.0], [2.0, 0.5, 1.0]]) - scene.origin  # the second passes beside it
    down = np.array([[0.0, 0.0, -1.0]] * 2)
    glass = glazing.glass_tracer.closest_hit(origin, down)
    assert glass.hit_triangle[1] == -1 and glass.hit_t[0] == pytest.approx(1.0, abs=FLOAT32_STORAGE)
    assert glazing.glass_triangles[glass.hit_triangle[0]] in window
    assert not glazing.opaque_tracer.occluded(origin, down).any()
    # Down onto the floor (y = 0), the opaque tracer meets it and maps back to the floor's triangles.
    floor_hit = glazing.opaque_tracer.closest_hit(np.array([[2.0, 1.0, 2.0]]) - scene.origin, [[0.0, -1.0, 0.0]])
    assert scene.tri_prim[glazing.opaque_triangles[floor_hit.hit_triangle[0]]] == scene.prim_paths.index(FLOOR)


def test_the_materials_fingerprint_sees_the_transmittance(tmp_path):
    scene = extract_scene(Usd.Stage.Open(room(tmp_path)))
    opaque = dataclasses.replace(scene, tri_transmittance=np.zeros(scene.num_triangles, np.float32))
    assert opaque.fingerprint(("materials",)) != scene.fingerprint(("materials",))
    assert opaque.fingerprint(("geometry",)) == scene.fingerprint(("geometry",))
