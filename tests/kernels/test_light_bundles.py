"""kernels/light_bundles.py: which triangles and lights light a scene, how many shadow rays a point costs, and
the power CDF emitters are picked by (Rec. 709 luminance written here from the standard)."""

import numpy as np
import pytest
from lit_scenes import make_lights, make_scene, merge, quad
from tolerances import FLOAT32_STORAGE
from usdbake.core.scene import LIGHT_DISTANT, LIGHT_DOME, LIGHT_SPHERE
from usdbake.kernels.light_bundles import (emissive_lights, emitter_triangles, has_light, light_bundle,
                                           shadow_rays_per_point)

REC709_RED, REC709_GREEN = 0.2126, 0.7152
"""ITU-R BT.709 luminance weights of red and green."""

MARKER = quad([40, 40, -40], [0.1, 0, 0], [0, 0.1, 0])


def test_emissive_mode_auto_lights_with_emitters_only_without_usdlux():
    emitter = quad([0, 0, 1], [1, 0, 0], [0, 1, 0])
    points, tris = merge([emitter])
    glow = np.ones((2, 3), np.float32)
    bare = make_scene(points, tris, emission=glow)
    lit = make_scene(points, tris, emission=glow,
                     lights=make_lights((LIGHT_DISTANT, [1] * 3, [0, 0, 0], [0, 0, -1], [0, 0])))
    assert emissive_lights(bare) and not emissive_lights(lit)
    assert emissive_lights(lit, "on") and not emissive_lights(bare, "off")
    assert list(emitter_triangles(bare)) == [0, 1] and len(emitter_triangles(lit)) == 0
    with pytest.raises(ValueError, match="emissive mode"):
        emissive_lights(bare, "always")


def test_has_light_needs_positive_radiance():
    points, tris = merge([MARKER])
    dark = make_scene(points, tris, lights=make_lights((LIGHT_SPHERE, [0] * 3, [0, 0, 1], [0, 0, -1], [1, 1])))
    assert not has_light(dark) and not has_light(make_scene(points, tris))
    assert has_light(make_scene(points, tris, emission=np.array([[0, 0, 0], [0, 0.1, 0]], np.float32)))
    assert has_light(make_scene(points, tris, lights=make_lights((LIGHT_DOME, [1] * 3, [0] * 3, [0, 0, -1], [0, 0]))))


def test_shadow_rays_per_point_counts_each_lights_samples():
    rows = [(LIGHT_DISTANT, [1] * 3, [0] * 3, [0, 0, -1], [0, 0]),  # delta: 1
            (LIGHT_DISTANT, [1] * 3, [0] * 3, [0, 0, -1], [5, 5]),  # cone: strata^2
            (LIGHT_SPHERE, [1] * 3, [0, 0, 2], [0, 0, -1], [1, 1]),  # strata^2
            (LIGHT_DOME, [1] * 3, [0] * 3, [0, 0, -1], [0, 0])]  # sky_strata^2
    points, tris = merge([MARKER])
    scene = make_scene(points, tris, emission=np.ones((2, 3), np.float32), lights=make_lights(*rows))
    assert shadow_rays_per_point(scene, strata=3, sky_strata=5) == 1 + 9 + 9 + 25
    assert shadow_rays_per_point(scene, strata=3, sky_strata=5, emissive="on") == 1 + 9 + 9 + 25 + 9


def test_light_bundle_picks_emitters_by_luminous_power():
    """The CDF holds Rec. 709 luminance x area x sides: a red unit triangle, a green one twice as large and
    double-sided."""
    small = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0]], np.float32)  # area 1
    large = np.array([[0, 0, 1], [2, 0, 1], [0, 2, 1]], np.float32)  # area 2
    points = np.concatenate([small, large])
    tris = np.array([[0, 1, 2], [3, 4, 5]], np.int32)
    scene = make_scene(points, tris, emission=np.array([[1, 0, 0], [0, 1, 0]], np.float32), double_sided=[False, True])
    cdf = light_bundle(scene, "cpu").emitter_cdf.numpy()
    np.testing.assert_allclose(cdf, [REC709_RED, REC709_RED + 2 * 2 * REC709_GREEN], rtol=FLOAT32_STORAGE)
