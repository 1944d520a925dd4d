"""Sky models and patch geometry (kernels/sky.py) against the published formulas and tables, each written
out again here in float64 (Preetham et al. 1999, Perez et al. 1993, the CIE overcast sky, Kasten 1966, the
sRGB standard), and the patch functions against float64 quadrature.
"""

import math

import numpy as np
import pytest
from tolerances import (FLOAT32_ACCUMULATED, FLOAT64_ROUNDING, KASTEN_PLANE_PARALLEL, PEREZ_NORMALISATION,
                        PATCH_MIDPOINT_RULE, QUOTED_4_DECIMALS, SRGB_MATRIX_DIGITS)
from usdbake.kernels.sky import (LUMINOUS_EFFICACY, air_mass, enu_to_world, overcast_radiance, patch_jittered_samples,
                                 patch_layout, patch_mean_directions, patch_outlines, patch_radiance,
                                 perez_coefficients, perez_radiance, perez_sky_state, preetham_radiance,
                                 reinhart_patches, sun_normal_irradiance, uniform_patches)

SRGB_TO_XYZ = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
"""IEC 61966-2-1 (sRGB), linear RGB -> XYZ under D65, as the standard prints it (4 decimals)."""


def direction(zenith_degrees, azimuth_degrees):
    """ENU unit vector: azimuth from north towards east."""
    z, a = math.radians(zenith_degrees), math.radians(azimuth_degrees)
    return np.array([math.sin(z) * math.sin(a), math.sin(z) * math.cos(a), math.cos(z)])


def gauss_hemisphere(nodes=200):
    """Gauss-Legendre in cos(zenith) x midpoint rule in azimuth: directions and solid angles."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    mu, wmu = 0.5 * (x + 1), 0.5 * w
    phi = (np.arange(2 * nodes) + 0.5) * math.pi / nodes
    mm, pp = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - mm ** 2)
    directions = np.stack([s * np.sin(pp), s * np.cos(pp), mm], axis=-1).reshape(-1, 3)
    return directions, (wmu[:, None] * np.full(2 * nodes, math.pi / nodes)).ravel()


# -- Preetham, Shirley & Smits 1999 -------------------------------------------------------------------


def preetham_luminance(theta, gamma, theta_s, t):
    """Y (cd/m^2) of the paper's Appendix A.2: Yz F(theta, gamma) / F(0, theta_s), Perez's F with the
    turbidity-linear coefficients of Y."""
    a, b, c, d, e = (0.1787 * t - 1.4630, -0.3554 * t + 0.4275, -0.0227 * t + 5.3251, 0.1206 * t - 2.5771,
                     -0.0670 * t + 0.3703)

    def f(th, g):
        return (1 + a * math.exp(b / math.cos(th))) * (1 + c * math.exp(d * g) + e * math.cos(g) ** 2)

    chi = (4 / 9 - t / 120) * (math.pi - 2 * theta_s)
    zenith = ((4.0453 * t - 4.9710) * math.tan(chi) - 0.2155 * t + 2.4192) * 1000
    return zenith * f(theta, gamma) / f(0.0, theta_s)


@pytest.mark.parametrize("turbidity", [2.0, 3.0, 6.0])
def test_preetham_luminance_follows_the_papers_perez_function_across_the_sky(turbidity):
    sun_zenith = math.radians(35.0)
    sun = direction(35.0, 150.0)
    for zenith, azimuth in ((0, 0), (30, 150), (50, 40), (70, 260), (80, 150)):
        w = direction(zenith, azimuth)
        gamma = math.acos(float(np.clip(w @ sun, -1, 1)))
        expected = preetham_luminance(math.radians(zenith), gamma, sun_zenith, turbidity)
        rgb = preetham_radiance(w, sun, turbidity) * LUMINOUS_EFFICACY
        np.testing.assert_allclose(rgb @ SRGB_TO_XYZ[1], expected, rtol=SRGB_MATRIX_DIGITS)


def test_preetham_zenith_chromaticity_matches_the_papers_polynomials():
    """x_z, y_z = [T^2 T 1] M [theta_s^3 theta_s^2 theta_s 1] (Appendix A.2); the RGB, taken back to XYZ with the
    sRGB standard's matrix, has that chromaticity."""
    t, theta_s = 4.0, math.radians(50.0)
    tt, th = np.array([t * t, t, 1]), np.array([theta_s ** 3, theta_s ** 2, theta_s, 1])
    mx = np.array([[0.00166, -0.00375, 0.00209, 0], [-0.02903, 0.06377, -0.03202, 0.00394],
                   [0.11693, -0.21196, 0.06052, 0.25886]])
    my = np.array([[0.00275, -0.00610, 0.00317, 0], [-0.04214, 0.08970, -0.04153, 0.00516],
                   [0.15346, -0.26756, 0.06670, 0.26688]])
    xyz = SRGB_TO_XYZ @ preetham_radiance(np.array([0, 0, 1.0]), direction(50.0, 180.0), t)
    np.testing.assert_allclose(xyz[:2] / xyz.sum(), [tt @ mx @ th, tt @ my @ th], rtol=SRGB_MATRIX_DIGITS)


def test_preetham_is_black_below_the_horizon_and_at_night():
    sun = direction(40.0, 90.0)
    assert not preetham_radiance(direction(95.0, 0.0), sun).any()
    assert not preetham_radiance(np.array([0, 0, 1.0]), direction(100.0, 90.0)).any()


# -- CIE overcast sky (Moon & Spencer 1942; gensky -c) -------------------------------------------------


def test_overcast_sky_gradation_and_horizontal_illuminance():
    """L(theta) = Lz (1 + 2 cos theta) / 3: the horizon a third of the zenith, the horizontal illuminance
    7 pi / 9 Lz (integral of (mu + 2 mu^2) / 3 over the hemisphere), Lz = 8.6 sin(altitude) + 0.123 kcd/m^2."""
    altitude = math.radians(30.0)
    sun = direction(60.0, 200.0)
    zenith = overcast_radiance(np.array([0, 0, 1.0]), sun)
    np.testing.assert_allclose(zenith * LUMINOUS_EFFICACY, (8.6 * math.sin(altitude) + 0.123) * 1000,
                               rtol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(overcast_radiance(direction(90.0, 17.0), sun), zenith / 3, rtol=FLOAT64_ROUNDING)
    directions, solid = gauss_hemisphere()
    horizontal = (overcast_radiance(directions, sun)[:, 0] * directions[:, 2] * solid).sum()
    np.testing.assert_allclose(horizontal, 7 * math.pi / 9 * zenith[0], rtol=FLOAT64_ROUNDING)
    assert np.all(overcast_radiance(direction(60.0, 0.0), sun) == overcast_radiance(direction(60.0, 123.0), sun))


# -- Perez, Seals & Michalsky 1993 ---------------------------------------------------------------------


def test_perez_coefficients_read_the_published_table():
    """Bin 5 (clearness 1.95 to 2.8) of Table 1: x = x1 + x2 Z + Delta (x3 + x4 Z) for a, b, c, d and e."""
    rows = {"a": (-0.6000, -0.3566, -2.5000, 2.3250), "b": (0.2937, 0.0496, -5.6812, 1.8415),
            "c": (21.0000, -4.7656, -21.5906, 7.2492), "d": (-3.5000, -0.1554, 1.4062, 0.3988),
            "e": (0.0032, 0.0766, -0.0656, -0.1294)}
    zenith, delta = 0.7, 0.2
    expected = [x1 + x2 * zenith + delta * (x3 + x4 * zenith) for x1, x2, x3, x4 in rows.values()]
    np.testing.assert_allclose(perez_coefficients(zenith, 2.0, delta), expected, rtol=FLOAT64_ROUNDING)
    # 2.8 opens bin 6: its a1 is -1.0156
    np.testing.assert_allclose(perez_coefficients(0.0, 2.8, 0.0)[0], -1.0156, atol=QUOTED_4_DECIMALS)


def test_perez_sky_state_brightness_uses_kastens_air_mass():
    """Delta = m DHI / E0n with E0n = 1367 (1 + 0.033 cos(2 pi day / 365)) W/m^2 (Perez et al. 1990)."""
    zenith, dhi, day = math.radians(40.0), 120.0, 80
    _, delta = perez_sky_state(zenith, 500.0, dhi, day)
    extraterrestrial = 1367 * (1 + 0.033 * math.cos(2 * math.pi * day / 365))
    kasten = 1 / (math.cos(zenith) + 0.15 * (93.885 - 40.0) ** -1.253)
    np.testing.assert_allclose(delta, kasten * dhi / extraterrestrial, rtol=FLOAT64_ROUNDING)
    assert perez_sky_state(zenith, 1e5, 1.0)[0] == 12.0  # clamped to the model's range, as gendaylit


@pytest.mark.parametrize("dni, dhi", [(850.0, 90.0), (300.0, 220.0), (0.0, 160.0)])
def test_perez_sky_integrates_to_the_diffuse_horizontal_on_an_independent_grid(dni, dhi):
    sun = direction(50.0, 220.0)
    directions, solid = gauss_hemisphere()
    horizontal = (perez_radiance(directions, sun, dni, dhi)[:, 0] * directions[:, 2] * solid).sum()
    np.testing.assert_allclose(horizontal, dhi, rtol=PEREZ_NORMALISATION)


# -- the sun ---------------------------------------------------------------------------------------


def test_air_mass_is_plane_parallel_overhead_and_finite_at_the_horizon():
    """Kasten 1966: m cos(z) -> 1 towards the zenith (within 0.5 % up to 60 deg), 36.5 at the horizon."""
    for z in (0.0, 20.0, 45.0, 60.0):
        assert abs(air_mass(math.cos(math.radians(z))) * math.cos(math.radians(z)) - 1) < KASTEN_PLANE_PARALLEL
    assert 36.0 < air_mass(0.0) < 37.0
    assert air_mass(math.cos(math.radians(94.0))) == math.inf


def test_direct_sunlight_falls_off_by_beer_lambert_in_air_mass():
    """log E(m) = log E0 - tau m per channel: three sun heights lie on one line in (m, log E)."""
    zeniths = np.radians([10.0, 50.0, 75.0])
    masses = np.array([air_mass(math.cos(z)) for z in zeniths])
    logs = np.log([sun_normal_irradiance(np.array([0, math.sin(z), math.cos(z)]), 3.0) for z in zeniths])
    slopes = (logs[1:] - logs[:-1]) / (masses[1:] - masses[:-1])[:, None]
    np.testing.assert_allclose(slopes[0], slopes[1], rtol=FLOAT64_ROUNDING)
    assert (slopes < 0).all() and slopes[0, 2] < slopes[0, 0]  # blue is scattered more than red


def test_sun_distance_correction_follows_the_orbit():
    """Extraterrestrial irradiance x (1 + 0.033 cos(2 pi day / 365)) (Duffie & Beckman, Eq. 1.4.1a)."""
    up = np.array([0, 0, 1.0])
    ratio = sun_normal_irradiance(up, 3.0, day_of_year=3) / sun_normal_irradiance(up, 3.0, day_of_year=185)
    expected = (1 + 0.033 * math.cos(2 * math.pi * 3 / 365)) / (1 + 0.033 * math.cos(2 * math.pi * 185 / 365))
    np.testing.assert_allclose(ratio, expected, rtol=FLOAT64_ROUNDING)


# -- frames and layouts ----------------------------------------------------------------------------


def test_north_turns_counter_clockwise_seen_from_above():
    np.testing.assert_allclose(enu_to_world("Z", 90.0) @ [0, 1, 0], [-1, 0, 0], atol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(enu_to_world("Y", 90.0) @ [0, 1, 0], [-1, 0, 0], atol=FLOAT64_ROUNDING)
    with pytest.raises(ValueError, match="up axis"):
        enu_to_world("X")


def test_layout_names_and_bounds_are_checked():
    assert len(patch_layout("uniform", count=64)) == 64 and len(patch_layout("reinhart", subdivision=2)) == 577
    for call in (lambda: patch_layout("klems"), lambda: reinhart_patches(0), lambda: uniform_patches(0),
                 lambda: patch_radiance(uniform_patches(8), "cloudy", np.array([0, 0, 1.0]))):
        with pytest.raises(ValueError):
            call()


def test_uniform_model_patch_radiance_is_the_constant():
    np.testing.assert_allclose(patch_radiance(uniform_patches(32), "uniform", np.array([0, 0, 1.0]), radiance=2.5),
                               2.5, rtol=FLOAT64_ROUNDING)


def box_cosines(bounds: np.ndarray, normals: np.ndarray, steps: int = 400) -> np.ndarray:
    """(P, steps, steps) n . w at the midpoints of a steps x steps grid over each patch's (z, azimuth) box."""
    t = (np.arange(steps) + 0.5) / steps
    z = bounds[:, :1, None] + t[None, :, None] * (bounds[:, 1:2, None] - bounds[:, :1, None])
    az = bounds[:, 2:3, None] + t[None, None, :] * (bounds[:, 3:4, None] - bounds[:, 2:3, None])
    r = np.sqrt(1 - z ** 2)
    return normals[:, 0, None, None] * r * np.sin(az) + normals[:, 1, None, None] * r * np.cos(az) \
        + normals[:, 2, None, None] * z


def test_patch_mean_directions_and_outlines_against_float64():
    """n . (mean direction) is the mean of n . w over a (z, azimuth) box by a 400 x 400 midpoint rule; the
    outline test (corners on or above the plane, midpoint above) holds for patches wholly above and fails
    for those wholly below; a horizontal face's mean cosines over the sky, by solid angle, add up to pi."""
    patches = reinhart_patches(2)
    rng = np.random.default_rng(5)  # fixed: 64 random patches and normals
    picks = rng.choice(len(patches), 64, replace=False)
    bounds = patches.patch_bounds[picks]
    normals = rng.normal(size=(64, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    cosines = box_cosines(bounds, normals)
    mean_cos = np.einsum("pk,pk->p", patch_mean_directions(bounds), normals)
    np.testing.assert_allclose(mean_cos, cosines.mean(axis=(1, 2)), rtol=0, atol=PATCH_MIDPOINT_RULE)
    outline_cos = np.einsum("pck,pk->pc", patch_outlines(bounds), normals)
    above = (outline_cos[:, :4] >= -1e-6).all(axis=1) & (outline_cos[:, 4] > 0)
    wholly_above = cosines.min(axis=(1, 2)) > 1e-3
    wholly_below = cosines.max(axis=(1, 2)) < 0
    assert above[wholly_above].all() and not above[wholly_below].any()
    assert wholly_above.any() and wholly_below.any()
    up = np.array([0.0, 0.0, 1.0])
    for layout in (uniform_patches(64), patches):
        total = (patch_mean_directions(layout.patch_bounds) @ up * layout.patch_solid_angles).sum()
        assert total == pytest.approx(np.pi, rel=FLOAT32_ACCUMULATED)


def test_jittered_patch_samples_fall_one_in_each_cell_of_their_patch():
    """Sample s of a patch lies in cell (s % strata, s // strata) of the patch's strata x strata (z, azimuth)
    grid, in every set; the jitter comes from the seed alone (the same every call, another for another seed)
    and differs between sets."""
    patches = uniform_patches(32)
    strata = 3
    sets = patch_jittered_samples(patches, strata, seed=4, variants=2)
    assert sets.shape == (2, 32, 9, 3)
    assert not np.array_equal(sets[0], sets[1])
    np.testing.assert_allclose(np.linalg.norm(sets, axis=3), 1.0, atol=FLOAT64_ROUNDING)
    z0, z1, a0, a1 = (patches.patch_bounds[:, k, None] for k in range(4))
    s = np.arange(9)[None]
    inside = 1e-9
    for samples in sets:
        col = (samples[..., 2] - z0) / (z1 - z0) * strata
        azimuth = np.arctan2(samples[..., 0], samples[..., 1])
        row = np.mod(azimuth - a0, 2 * np.pi) / (a1 - a0) * strata
        row = np.where(row > strata + 1e-9, row - 2 * np.pi / (a1 - a0) * strata, row)  # a patch across north
        assert ((col >= s % strata - inside) & (col <= s % strata + 1 + inside)).all()
        assert ((row >= s // strata - inside) & (row <= s // strata + 1 + inside)).all()
    np.testing.assert_array_equal(sets, patch_jittered_samples(patches, strata, seed=4, variants=2))
    assert not np.array_equal(sets, patch_jittered_samples(patches, strata, seed=5, variants=2))
