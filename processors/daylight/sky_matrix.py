"""Sky matrices: the radiance of every sky patch at every hour of a year (numpy).

The Perez all-weather model (Perez, Seals & Michalsky 1993) driven by each
hour's direct-normal and diffuse-horizontal irradiance, as Radiance's
``gendaymtx`` builds it for daylight-coefficient methods: column h is the
patch radiance vector Lhat_j of Bosch, Besuievsky & Martin's Eq. 1 for hour h,
so the sky irradiance of every face at every hour is one product V (dw * S).
Vectorized over hours (the per-hour evaluation in ``kernels/sky.py`` is the
reference it is tested against).
"""

from __future__ import annotations

import math

import numpy as np

from ...kernels.sky import SkyPatches, _hemisphere_quadrature, patch_samples, perez_coefficients, perez_sky_state

NORMALIZATION_GRID = (45, 90)
"""Zenith rings x azimuth segments of the quadrature that scales each hour's sky to its diffuse
horizontal irradiance (2-degree cells: the horizontal integral is within 0.1% of a 0.5-degree grid)."""


def perez_sky_matrix(patches: SkyPatches, suns: np.ndarray, direct_normal: np.ndarray,
                     diffuse_horizontal: np.ndarray, days: np.ndarray, *, per_side: int = 3) -> np.ndarray:
    """(N, H) float32 mean grey radiance of each patch (W/(m^2 sr)) for each hour.

    ``suns`` (H, 3) unit ENU sun directions; hours with the sun below the horizon or no diffuse
    light give a dark sky (zero column). Each hour's model is scaled so that its horizontal
    integral, integral_H L cos(zeta) dw, equals that hour's diffuse horizontal irradiance.
    """
    suns = np.asarray(suns, np.float64)
    direct_normal = np.asarray(direct_normal, np.float64)
    diffuse_horizontal = np.asarray(diffuse_horizontal, np.float64)
    hours = len(suns)
    matrix = np.zeros((len(patches), hours), np.float32)
    lit = np.flatnonzero((suns[:, 2] > 0.0) & (diffuse_horizontal > 0.0))
    if len(lit) == 0:
        return matrix
    zenith = np.arccos(np.clip(suns[lit, 2], -1.0, 1.0))
    coefficients = np.array([
        perez_coefficients(z, *perez_sky_state(min(z, math.radians(87.0)), dni, dhi, int(day)))
        for z, dni, dhi, day in zip(zenith, direct_normal[lit], diffuse_horizontal[lit], days[lit])])
    grid, solid = _hemisphere_quadrature(*NORMALIZATION_GRID)
    samples = patch_samples(patches, per_side).reshape(-1, 3)
    for lo in range(0, len(lit), 256):  # bounds the (hours, directions) temporaries to ~30 MB
        part = slice(lo, lo + 256)
        sun, coeff = suns[lit[part]], coefficients[part]
        horizontal = (_relative_luminance(grid, sun, coeff) * (grid[:, 2] * solid)[None, :]).sum(axis=1)
        scale = np.where(horizontal > 0, diffuse_horizontal[lit[part]] / np.maximum(horizontal, 1e-300), 0.0)
        values = _relative_luminance(samples, sun, coeff) * scale[:, None]
        matrix[:, lit[part]] = values.reshape(len(sun), len(patches), -1).mean(axis=2).T
    return matrix


def _relative_luminance(directions: np.ndarray, suns: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """(H, D) Perez lv for H hours (suns (H, 3), coefficients (H, 5)) at D directions; zero below the horizon.

    The vectorized ``kernels.sky.perez_relative_luminance``: (1 + a exp(b / cos zeta)) (1 + c exp(d gamma)
    + e cos^2 gamma) (Perez et al. 1993, Eq. 1), cos zeta floored at 0.01 as gendaylit does."""
    a, b, c, d, e = (coefficients[:, k, None] for k in range(5))
    cos_zeta = directions[None, :, 2]
    cos_gamma = np.clip(suns @ directions.T, -1.0, 1.0)
    gamma = np.arccos(cos_gamma)
    gradation = 1.0 + a * np.exp(b / np.maximum(cos_zeta, 0.01))
    indicatrix = 1.0 + c * np.exp(d * gamma) + e * cos_gamma ** 2
    return np.where(cos_zeta >= 0.0, np.maximum(gradation * indicatrix, 0.0), 0.0)
