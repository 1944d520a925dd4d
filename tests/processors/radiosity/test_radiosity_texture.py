"""radiosity's texture target: direct irradiance per texel against the closed form of a sphere light."""

from __future__ import annotations

import math

import numpy as np
from pxr import Gf, Sdf, UsdGeom, UsdLux
from lightmap_checks import read_image, saved_and_baked
from stage_builders import add_mesh, new_stage
from tolerances import DIRECT_TOLERANCE

RADIUS, RADIANCE = 0.1, 50.0
CENTRE = np.array([1.5, 0.6, 0.5])  # off the floor's centre: a mirrored or flipped image reads other values


def test_texel_direct_irradiance_matches_the_sphere_light_closed_form(tmp_path):
    """Floor z = 0, x and y in [0, 2] m, st = (x, y) / 2; a sphere light of radiance L and radius r at c:
    E(p) = pi L (r / d)^2 cos(theta) (Lambert: exact for a sphere wholly above the plane), at each texel's
    centre, which is its baked point (st covers the page)."""
    stage = new_stage(up_axis="Z", meters_per_unit=1.0)
    floor = add_mesh(stage, "/World/Floor", [(0, 0, 0), (2, 0, 0), (2, 2, 0), (0, 2, 0)], [4], [0, 1, 2, 3])
    UsdGeom.PrimvarsAPI(floor).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
        [(0, 0), (1, 0), (1, 1), (0, 1)])
    lamp = UsdLux.SphereLight.Define(stage, "/World/Lamp")
    lamp.CreateRadiusAttr(RADIUS)
    lamp.CreateIntensityAttr(RADIANCE)
    UsdGeom.Xformable(lamp).AddTranslateOp().Set(Gf.Vec3d(*CENTRE))
    stage = saved_and_baked(stage, tmp_path / "lamp.usda", "radiosity",
                            {"radiosity": {"light_samples": 256, "texel_density": 8.0}}, "texture")
    prim = stage.GetPrimAtPath("/World/Floor")
    assert not prim.HasAttribute("primvars:bake:irradianceDirect")
    image = read_image(prim.GetAttribute("bake:lightmap:irradianceDirect:file").Get().resolvedPath)[::-1, :, 0]
    height, width = image.shape
    assert (width, height) == (16, 16)  # 2 m at 8 texels per metre
    x = (np.arange(width) + 0.5) / width * 2.0
    y = (np.arange(height) + 0.5) / height * 2.0
    px, py = np.meshgrid(x, y)
    offset = CENTRE - np.stack([px, py, np.zeros_like(px)], axis=-1)
    d = np.linalg.norm(offset, axis=-1)
    expected = math.pi * RADIANCE * (RADIUS / d) ** 2 * offset[..., 2] / d
    np.testing.assert_allclose(image, expected, rtol=DIRECT_TOLERANCE + 1e-3)  # + half-float storage
