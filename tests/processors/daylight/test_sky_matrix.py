"""processors.daylight.sky_matrix: each hour's column against a plainly written float64 Perez sky
(Perez, Seals & Michalsky 1993, Eq. 1) on the same patch samples, scaled to the hour's diffuse
horizontal irradiance by a finer quadrature of its own."""

import math

import numpy as np
from tolerances import FLOAT32_STORAGE, SKY_MATRIX_NORMALISATION
from usdbake.kernels.sky import perez_coefficients, perez_sky_state, reinhart_patches
from usdbake.processors.daylight.sky_matrix import perez_sky_matrix

PER_SIDE = 3


def direction(altitude_z, azimuth):
    """ENU unit direction at z = sin(altitude) and azimuth from north towards east."""
    r = np.sqrt(np.maximum(0.0, 1.0 - altitude_z ** 2))
    return np.stack([r * np.sin(azimuth), r * np.cos(azimuth), altitude_z], axis=-1)


def perez_lv(directions, sun, a, b, c, d, e):
    """Relative luminance (1 + a exp(b / cos zeta)) (1 + c exp(d gamma) + e cos^2 gamma), cos zeta >= 0.01."""
    cos_zeta = directions[..., 2]
    cos_gamma = np.clip(directions @ sun, -1.0, 1.0)
    value = (1 + a * np.exp(b / np.maximum(cos_zeta, 0.01))) * (1 + c * np.exp(d * np.arccos(cos_gamma))
                                                               + e * cos_gamma ** 2)
    return np.where(cos_zeta >= 0, np.maximum(value, 0.0), 0.0)


def reference_column(patches, sun, dni, dhi, day):
    """(N,) float64 mean radiance over each patch's PER_SIDE x PER_SIDE samples, the sky scaled to DHI by
    a 360 x 720 midpoint rule in (zenith, azimuth)."""
    zenith = math.acos(sun[2])
    coefficients = perez_coefficients(zenith, *perez_sky_state(min(zenith, math.radians(87.0)), dni, dhi, day))
    rings, segments = 360, 720
    zeta = (np.arange(rings) + 0.5) * (math.pi / 2) / rings
    phi = (np.arange(segments) + 0.5) * 2 * math.pi / segments
    zz, pp = np.meshgrid(zeta, phi, indexing="ij")
    grid = direction(np.cos(zz), pp)
    solid = np.sin(zz) * (math.pi / 2 / rings) * (2 * math.pi / segments)
    horizontal = (perez_lv(grid, sun, *coefficients) * grid[..., 2] * solid).sum()
    t = (np.arange(PER_SIDE) + 0.5) / PER_SIDE
    z_lo, z_hi, az_lo, az_hi = patches.patch_bounds.T
    z = z_lo[:, None, None] + t[None, :, None] * (z_hi - z_lo)[:, None, None]
    az = az_lo[:, None, None] + t[None, None, :] * (az_hi - az_lo)[:, None, None]
    samples = direction(*np.broadcast_arrays(z, az))
    return perez_lv(samples, sun, *coefficients).mean(axis=(1, 2)) * dhi / horizontal


def test_columns_match_a_plain_perez_sky_and_dark_hours_are_zero():
    patches = reinhart_patches(1)
    suns = np.array([direction(np.float64(0.7), 2.0), direction(np.float64(-0.1), 1.0),
                     direction(np.float64(0.2), 4.0), direction(np.float64(0.95), 0.3)])
    direct_normal = np.array([600.0, 0.0, 50.0, 850.0])
    diffuse = np.array([120.0, 30.0, 0.0, 60.0])  # hour 1: sun down; hour 2: no diffuse light
    days = np.array([172, 10, 300, 200])
    matrix = perez_sky_matrix(patches, suns, direct_normal, diffuse, days, per_side=PER_SIDE)
    assert matrix.shape == (len(patches), 4) and matrix.dtype == np.float32
    assert not matrix[:, 1].any() and not matrix[:, 2].any()
    for hour in (0, 3):
        reference = reference_column(patches, suns[hour], direct_normal[hour], diffuse[hour], int(days[hour]))
        np.testing.assert_allclose(matrix[:, hour], reference, rtol=SKY_MATRIX_NORMALISATION)
        # the shape of the sky does not depend on the scale: patch ratios to float32 rounding
        np.testing.assert_allclose(matrix[:, hour] / matrix[0, hour], reference / reference[0],
                                   rtol=4 * FLOAT32_STORAGE)


def test_a_sky_with_no_sun_up_is_all_zero():
    patches = reinhart_patches(1)
    matrix = perez_sky_matrix(patches, np.array([[0.0, 0.6, -0.8]]), np.array([500.0]), np.array([100.0]),
                              np.array([1]))
    assert matrix.shape == (len(patches), 1) and not matrix.any()
