"""stages.light_prims.read_lights called on light prims: radiance from intensity, exposure, colour and colour
temperature; sizes and normalize under scaled transforms (areas written out by hand); unit directions;
positions relative to the origin; the first textured DomeLight's file and world-to-dome rotation; and
StageErrors naming the light and the attribute.

The kinds, positions and directions of unscaled lights in an extracted scene are tests/stages/test_extract.py's;
what a dome texture does to the light, tests/kernels/test_dome_texture.py's."""

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

from stage_builders import add_xform, new_stage, write_png
from tolerances import FLOAT32_STORAGE, FLOAT64_ROUNDING
from usdbake.core.errors import StageError
from usdbake.core.scene import LIGHT_DISK, LIGHT_DISTANT, LIGHT_DOME, LIGHT_RECT, LIGHT_SPHERE
from usdbake.stages.light_prims import read_lights
from usdbake.stages.sky_dome import DomeTexture

DEFAULT = Usd.TimeCode.Default()


def lights_of(stage, paths, origin=(0.0, 0.0, 0.0)):
    prims = [stage.GetPrimAtPath(path) for path in paths]
    return read_lights(prims, UsdGeom.XformCache(DEFAULT), DEFAULT, np.array(origin, np.float64))


def define(stage, light_type, path, *, intensity=1.0, exposure=0.0, color=(1, 1, 1), normalize=False, **xform):
    light = light_type.Define(stage, path)
    light.CreateIntensityAttr(intensity)
    light.CreateExposureAttr(exposure)
    light.CreateColorAttr(Gf.Vec3f(*color))
    light.CreateNormalizeAttr(normalize)
    if xform:
        ops = UsdGeom.Xformable(light.GetPrim())
        if "translate" in xform:
            ops.AddTranslateOp().Set(Gf.Vec3d(*xform["translate"]))
        if "rotate_xyz" in xform:
            ops.AddRotateXYZOp().Set(Gf.Vec3f(*xform["rotate_xyz"]))
        if "scale" in xform:
            ops.AddScaleOp().Set(Gf.Vec3f(*xform["scale"]))
    return light


def test_no_lights_give_empty_rows_of_the_documented_shapes():
    lights = lights_of(new_stage(), [])
    assert len(lights) == 0 and lights.light_paths == ()
    assert lights.light_kind.shape == (0,) and lights.light_kind.dtype == np.int32
    for name, width in (("light_radiance", 3), ("light_position", 3), ("light_direction", 3), ("light_size", 2)):
        array = getattr(lights, name)
        assert array.shape == (0, width) and array.dtype == np.float32, name
    assert lights.dome_source is None
    np.testing.assert_array_equal(lights.dome_to_local, np.eye(3))


def test_radiance_is_intensity_times_two_to_the_exposure_times_colour():
    stage = new_stage()
    define(stage, UsdLux.SphereLight, "/World/A", intensity=3.0, exposure=-1.5, color=(1.0, 0.5, 0.25))
    define(stage, UsdLux.SphereLight, "/World/B", intensity=0.0, exposure=10.0)
    lights = lights_of(stage, ["/World/A", "/World/B"])
    np.testing.assert_allclose(lights.light_radiance[0], 3.0 / 2 ** 1.5 * np.array([1.0, 0.5, 0.25]),
                               rtol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(lights.light_radiance[1], [0, 0, 0])


def test_colour_temperature_counts_only_when_enabled():
    stage = new_stage()
    warm = define(stage, UsdLux.DiskLight, "/World/Warm", intensity=2.0, color=(1.0, 0.5, 1.0))
    warm.CreateEnableColorTemperatureAttr(True)
    warm.CreateColorTemperatureAttr(3000.0)
    off = define(stage, UsdLux.DiskLight, "/World/Off", intensity=2.0, color=(1.0, 0.5, 1.0))
    off.CreateColorTemperatureAttr(3000.0)  # authored, not enabled
    lights = lights_of(stage, ["/World/Warm", "/World/Off"])
    blackbody = np.array(UsdLux.BlackbodyTemperatureAsRgb(3000.0))  # USD's own blackbody colour
    assert blackbody[0] > blackbody[2]  # 3000 K is reddish: the check below is not a multiplication by 1
    np.testing.assert_allclose(lights.light_radiance[0], 2.0 * np.array([1.0, 0.5, 1.0]) * blackbody,
                               rtol=FLOAT32_STORAGE)
    np.testing.assert_allclose(lights.light_radiance[1], [2.0, 1.0, 2.0], rtol=FLOAT32_STORAGE)


def test_sizes_and_normalized_radiance_follow_the_transforms_scale():
    stage = new_stage()
    rect = define(stage, UsdLux.RectLight, "/World/Panel", intensity=12.0, normalize=True, scale=(2, 0.5, 7))
    rect.CreateWidthAttr(2.0)
    rect.CreateHeightAttr(3.0)
    add_xform(stage, "/World/Big", scale=(1, 3, 2))
    define(stage, UsdLux.SphereLight, "/World/Big/Ball", normalize=True).CreateRadiusAttr(1.0)
    define(stage, UsdLux.DiskLight, "/World/Disk", normalize=True, scale=(2, 4, 10)).CreateRadiusAttr(0.5)
    define(stage, UsdLux.DistantLight, "/World/Sun", intensity=5.0, normalize=True).CreateAngleAttr(0.53)
    define(stage, UsdLux.DomeLight, "/World/Sky", intensity=0.5, normalize=True)
    lights = lights_of(stage, ["/World/Panel", "/World/Big/Ball", "/World/Disk", "/World/Sun", "/World/Sky"])
    assert lights.light_kind.tolist() == [LIGHT_RECT, LIGHT_SPHERE, LIGHT_DISK, LIGHT_DISTANT, LIGHT_DOME]
    # rect: width x scale x, height x scale y (z does not stretch it); area 4 x 1.5 = 6
    # sphere: radius x the largest axis scale, 3; area 4 pi 9
    # disk: radius x the larger of the x and y scales, 2; area pi 4
    # distant: the angle twice, normalize leaves it alone; dome: no size, normalize leaves it alone
    np.testing.assert_allclose(lights.light_size, [(4, 1.5), (3, 3), (2, 2), (0.53, 0.53), (0, 0)],
                               rtol=FLOAT32_STORAGE)
    np.testing.assert_allclose(lights.light_radiance[:, 0], [12.0 / 6, 1 / (36 * np.pi), 1 / (4 * np.pi), 5.0, 0.5],
                               rtol=FLOAT32_STORAGE)


def test_directions_are_unit_minus_z_axes_and_positions_are_relative_to_the_origin():
    stage = new_stage()
    # rotateX 90 turns -z into +y; the z scale of 5 must not lengthen it
    define(stage, UsdLux.RectLight, "/World/Panel", translate=(101, 2, 3), rotate_xyz=(90, 0, 0), scale=(1, 1, 5))
    define(stage, UsdLux.SphereLight, "/World/Bulb", translate=(100, 0, 0))
    lights = lights_of(stage, ["/World/Panel", "/World/Bulb"], origin=(100, 0, 0))
    np.testing.assert_allclose(lights.light_direction, [(0, 1, 0), (0, 0, -1)], atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(np.linalg.norm(lights.light_direction, axis=1), 1.0, rtol=FLOAT32_STORAGE)
    np.testing.assert_allclose(lights.light_position, [(1, 2, 3), (0, 0, 0)], atol=FLOAT32_STORAGE)
    assert lights.light_paths == ("/World/Panel", "/World/Bulb")


def test_a_light_squashed_flat_along_z_still_points_down_its_axis():
    stage = new_stage()
    define(stage, UsdLux.DiskLight, "/World/Flat", scale=(1, 1, 0))  # no -z axis left to normalize
    np.testing.assert_array_equal(lights_of(stage, ["/World/Flat"]).light_direction, [(0, 0, -1)])


@pytest.mark.parametrize("intensity, exposure", [(float("inf"), 0.0), (float("nan"), 0.0), (1e300, 100.0)],
                         ids=["inf", "nan", "overflow"])
def test_a_radiance_that_is_not_finite_is_a_stage_error_naming_the_light(intensity, exposure):
    stage = new_stage()
    define(stage, UsdLux.SphereLight, "/World/Fine")
    define(stage, UsdLux.SphereLight, "/World/Bad", intensity=intensity, exposure=exposure)
    with pytest.raises(StageError) as raised:
        lights_of(stage, ["/World/Fine", "/World/Bad"])
    assert (raised.value.prim, raised.value.attribute) == ("/World/Bad", "inputs:intensity")
    assert str(raised.value).startswith("/World/Bad.inputs:intensity: light radiance [")
    assert str(raised.value).endswith("] is not finite")


# --- the dome's texture -----------------------------------------------------------------------


def test_the_first_textured_dome_gives_the_texture_and_its_rotation_without_scale(tmp_path):
    write_png(tmp_path / "sky.png", np.full((4, 8, 3), 128, np.uint8))
    stage = new_stage()
    define(stage, UsdLux.DomeLight, "/World/Plain")  # no texture: passed over
    textured = define(stage, UsdLux.DomeLight, "/World/Sky", rotate_xyz=(0, 90, 0), scale=(2, 2, 2))
    textured.CreateTextureFileAttr(Sdf.AssetPath(str(tmp_path / "sky.png")))
    define(stage, UsdLux.DomeLight, "/World/Second").CreateTextureFileAttr(Sdf.AssetPath(str(tmp_path / "sky.png")))
    lights = lights_of(stage, ["/World/Plain", "/World/Sky", "/World/Second"])
    assert isinstance(lights.dome_source, DomeTexture) and lights.dome_source.prim == "/World/Sky"
    # rotateY 90 (row vectors): x -> -z, z -> x. World to dome is its inverse, the transpose; the scale is dropped
    to_world = np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]], np.float64)
    np.testing.assert_allclose(lights.dome_to_local, to_world.T, atol=FLOAT64_ROUNDING)
    assert lights.dome_texture.shape == (4, 8, 3)  # read on first access


def test_a_dome_texture_that_is_missing_or_unreadable_is_named(tmp_path):
    (tmp_path / "garbage.png").write_bytes(b"\x89PNG\r\n\x1a\n and nothing else")
    stage = new_stage()
    define(stage, UsdLux.DomeLight, "/World/Gone").CreateTextureFileAttr(Sdf.AssetPath("gone.exr"))
    define(stage, UsdLux.DomeLight, "/World/Bad").CreateTextureFileAttr(Sdf.AssetPath(str(tmp_path / "garbage.png")))
    with pytest.raises(StageError) as raised:
        lights_of(stage, ["/World/Gone"])
    assert str(raised.value) == "/World/Gone.inputs:texture:file: gone.exr: not found"
    with pytest.raises(StageError) as raised:
        lights_of(stage, ["/World/Bad"])
    assert str(raised.value).startswith(f"/World/Bad.inputs:texture:file: {tmp_path / 'garbage.png'}: cannot be read (")
