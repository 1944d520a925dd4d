"""kernels/daylight_relight.py: the sun table's bilinear blend, Eq. 1's product linear in the sky and the sun,
and the sun's weights. (Against compute_daylight and rays: tests/processors/daylight.)"""

from __future__ import annotations

import numpy as np
import pytest

from usdbake.kernels.daylight_relight import SunTable, relight_daylight, sun_levels, sun_normal


def table() -> SunTable:
    hits = np.array([[0, 254], [254, 254], [127, 0]], np.uint8)  # 3 nodes above the horizon, 2 faces
    node_row = np.array([[0, 1, -1, -1], [2, -1, -1, -1]], np.int64)  # 2 declinations x 4 hour angles
    return SunTable(np.array([-10.0, 10.0]), np.array([-180.0, -90.0, 0.0, 90.0]), node_row, hits, 2)


def test_the_sun_table_blends_its_nodes_bilinearly():
    t = table()
    levels = sun_levels(2)
    np.testing.assert_allclose(t.visibility(-10.0, -180.0), [0, 254 / levels], rtol=1e-6)
    np.testing.assert_allclose(t.visibility(-10.0, -135.0), [127 / levels, 254 / levels], rtol=1e-6)
    middle = 0.5 * (0.5 * (0 + 254) + 0.5 * (127 + 0)) / levels  # a node below the horizon counts 0
    assert t.visibility(0.0, -135.0)[0] == pytest.approx(middle, rel=1e-6)
    np.testing.assert_allclose(t.visibility(-30.0, 180.0), t.visibility(-10.0, -180.0))  # clipped, periodic


def test_relight_is_linear_in_the_sky_and_the_sun():
    rng = np.random.default_rng(1)
    v = rng.uniform(0, 1, (50, 8)).astype(np.float32)
    w1, w2 = rng.uniform(0, 1, (8, 3)), rng.uniform(0, 1, (8, 3))
    sun = rng.uniform(0, 5, (50, 3)).astype(np.float32)
    both = relight_daylight(v, w1 + w2, sun=sun)
    np.testing.assert_allclose(both, relight_daylight(v, w1) + relight_daylight(v, w2) + sun, rtol=1e-5)
    np.testing.assert_allclose(relight_daylight(np.ascontiguousarray(v.T), w1, patch_major=True), relight_daylight(v, w1),
                               rtol=1e-5)
    codes = (v * 255).astype(np.uint8)
    np.testing.assert_allclose(relight_daylight(codes, w1, scale=1 / 255, chunk=7),
                               relight_daylight(codes.astype(np.float32) / 255, w1), rtol=1e-5)
    with pytest.raises(ValueError, match="does not match"):
        relight_daylight(v, w1[:5])


def test_no_sun_without_a_sunny_sky_or_below_the_horizon():
    up = np.array([0.0, 0.0, 1.0])
    assert sun_normal("overcast", up, turbidity=3, direct_normal=600, day_of_year=172) is None
    assert sun_normal("preetham", -up, turbidity=3, direct_normal=600, day_of_year=172) is None
    perez = sun_normal("perez", up, turbidity=3, direct_normal=600, day_of_year=172, diffuse_horizontal=100,
                       efficacy="179")
    np.testing.assert_allclose(perez, [600, 600, 600])
