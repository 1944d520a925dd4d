"""A DomeLight's lat-long texture lights every processor through the one light model.

Closed forms: under a dome whose texture is T_top on the upper half of the sphere (latitude > 0 in
the dome's frame) and T_bottom below, an open face looking along the pole gets E = pi L T_top, and
one looking away E = pi L T_bottom; the same split across longitude tests the OpenEXR layout
(longitude 0 along +z, pi/2 along +x).
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from pxr import UsdGeom, UsdLux

from stage_builders import add_mesh, new_stage
from tolerances import FLOAT32_UNIT_ROUNDOFF, MC_SIGMAS
from usdbake.core.errors import StageError
from open_irradiance import direct_irradiance_at
from usdbake.kernels.light_bundles import light_bundle
from usdbake.kernels.lights import Lights, sky_radiance
from usdbake.kernels.tracer import Tracer
from usdbake.stages.sidecars import write_texture
from usdbake.core.records import Texture
from usdbake.stages.extract import extract_scene

RADIANCE = 2.0
SKY_SUM = 64 * 8 * FLOAT32_UNIT_ROUNDOFF
"""direct_irradiance sums 64 cosine-weighted sky samples in float32, each a product of ~8 operations."""


@wp.kernel
def sky_kernel(lights: Lights, directions: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = sky_radiance(lights, directions[i])


def split_texture(folder, *, along: str, high: float = 3.0, low: float = 0.5, name="dome.exr") -> str:
    """A 64 x 32 float lat-long map: ``high`` on the upper half (along='latitude') or on the half of
    longitudes within 90 degrees of +z (along='longitude'), ``low`` elsewhere."""
    pixels = np.full((32, 64, 3), low, np.float32)
    if along == "latitude":
        pixels[:16] = high  # rows from latitude +pi/2 down to 0
    else:
        pixels[:, 16:48] = high  # columns (pi - longitude) / 2 pi in (1/4, 3/4): |longitude| < pi/2
    return write_texture(Texture(name, pixels), str(folder))


def dome_stage(texture: str | None, *, up: str = "Y", rotate_x: float = 0.0):
    """A tiny quad far below the origin (so nothing occludes the test points) and a textured DomeLight."""
    stage = new_stage(up_axis=up)
    add_mesh(stage, "/World/Speck", [(0, -100, 0), (0.01, -100, 0), (0, -100, 0.01)], [3], [0, 1, 2])
    dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
    dome.CreateIntensityAttr(RADIANCE)
    if texture is not None:
        dome.CreateTextureFileAttr(texture)
    if rotate_x:
        UsdGeom.Xformable(dome).AddRotateXOp().Set(rotate_x)
    return stage


def irradiance(scene, normals) -> np.ndarray:
    """Red-channel direct irradiance at the world origin (100 units from the speck) for each normal."""
    points = np.tile(-scene.origin, (len(normals), 1))
    return direct_irradiance_at(scene, points, normals)[:, 0]


def test_untextured_dome_is_uniform(tmp_path):
    scene = extract_scene(dome_stage(None))
    assert scene.lights.dome_texture.size == 0
    np.testing.assert_allclose(irradiance(scene, [[0, 1, 0], [0, -1, 0]]), np.pi * RADIANCE, rtol=SKY_SUM)


def test_latitude_split_lights_up_and_down_faces_by_their_half(tmp_path):
    scene = extract_scene(dome_stage(split_texture(tmp_path, along="latitude")))
    assert scene.lights.dome_texture.shape == (32, 64, 3)
    up, down, side = irradiance(scene, [[0, 1, 0], [0, -1, 0], [1, 0, 0]])
    assert up == pytest.approx(np.pi * RADIANCE * 3.0, rel=SKY_SUM)
    assert down == pytest.approx(np.pi * RADIANCE * 0.5, rel=SKY_SUM)
    # Each of the 64^2 cosine-weighted samples sees 3 or 0.5: i.i.d. standard deviation pi L (3 - 0.5) / 2.
    assert side == pytest.approx(np.pi * RADIANCE * (3.0 + 0.5) / 2,
                                 abs=MC_SIGMAS * np.pi * RADIANCE * (3.0 - 0.5) / 2 / 64)


def test_longitude_zero_is_plus_z_and_ninety_is_plus_x(tmp_path):
    scene = extract_scene(dome_stage(split_texture(tmp_path, along="longitude")))
    front, back = irradiance(scene, [[0, 0, 1], [0, 0, -1]])
    assert front == pytest.approx(np.pi * RADIANCE * 3.0, rel=SKY_SUM)
    assert back == pytest.approx(np.pi * RADIANCE * 0.5, rel=SKY_SUM)
    tracer = Tracer.from_scene(scene)
    directions = np.array([[0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, 0, -1]], np.float32)
    out = wp.zeros(4, dtype=wp.vec3, device=tracer.device)
    wp.launch(sky_kernel, dim=4, device=tracer.device,
              inputs=[light_bundle(scene, tracer.device), tracer.array(directions, wp.vec3), out])
    np.testing.assert_allclose(out.numpy()[:, 0], RADIANCE * np.array([3.0, 3.0, 0.5, 0.5]), rtol=SKY_SUM)
    # +x is longitude pi/2: column (pi - pi/2) / 2 pi = 1/4 of the width, the first bright column


def test_a_rotated_dome_puts_its_pole_where_the_transform_says(tmp_path):
    """Z-up stage, dome turned +90 degrees about X: its +Y pole points along +Z, so the bright upper half
    of the texture is above a Z-up floor."""
    scene = extract_scene(dome_stage(split_texture(tmp_path, along="latitude"), up="Z", rotate_x=90.0))
    up, down = irradiance(scene, [[0, 0, 1], [0, 0, -1]])
    assert up == pytest.approx(np.pi * RADIANCE * 3.0, rel=SKY_SUM)
    assert down == pytest.approx(np.pi * RADIANCE * 0.5, rel=SKY_SUM)


def test_a_dome_texture_that_cannot_be_read_is_named(tmp_path):
    broken = tmp_path / "sky.exr"
    broken.write_text("not an image")
    with pytest.raises(StageError) as error:
        extract_scene(dome_stage(str(broken)))
    assert str(error.value).startswith(f"/World/Sky.inputs:texture:file: {broken}: cannot be read (")
    with pytest.raises(StageError, match=r"/World/Sky.inputs:texture:file: missing.exr: not found"):
        extract_scene(dome_stage("missing.exr"))


def test_only_lat_long_maps_are_read(tmp_path):
    stage = dome_stage(split_texture(tmp_path, along="latitude"))
    UsdLux.DomeLight(stage.GetPrimAtPath("/World/Sky")).CreateTextureFormatAttr(UsdLux.Tokens.mirroredBall)
    with pytest.raises(StageError, match="inputs:texture:format: 'mirroredBall': only lat-long dome textures"):
        extract_scene(stage)


def test_a_second_untextured_dome_stays_uniform(tmp_path):
    """A sky layer's textured dome over a stage's own uniform dome (the atrium under ``usdbake sky``): the
    texture modulates its own dome only, so up = pi (L_sky 3 + L_fill) and down = pi (L_sky 0.5 + L_fill)."""
    stage = dome_stage(split_texture(tmp_path, along="latitude"))
    fill = UsdLux.DomeLight.Define(stage, "/World/Fill")
    fill.CreateIntensityAttr(0.25)
    scene = extract_scene(stage)
    assert scene.lights.light_paths[scene.lights.textured_dome] == "/World/Sky"
    up, down = irradiance(scene, [[0, 1, 0], [0, -1, 0]])
    assert up == pytest.approx(np.pi * (RADIANCE * 3.0 + 0.25), rel=SKY_SUM)
    assert down == pytest.approx(np.pi * (RADIANCE * 0.5 + 0.25), rel=SKY_SUM)
    tracer = Tracer.from_scene(scene)
    out = wp.zeros(2, dtype=wp.vec3, device=tracer.device)
    wp.launch(sky_kernel, dim=2, device=tracer.device, inputs=[
        light_bundle(scene, tracer.device), tracer.array(np.array([[0, 1, 0], [0, -1, 0]], np.float32), wp.vec3),
        out])
    np.testing.assert_allclose(out.numpy()[:, 0], [RADIANCE * 3.0 + 0.25, RADIANCE * 0.5 + 0.25], rtol=SKY_SUM)
