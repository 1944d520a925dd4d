"""Luminous efficacy of daylight: the Perez et al. (1990) model, as Radiance's gendaymtx -O0 applies it.

Perez, Ineichen, Seals, Michalsky and Stewart, "Modeling daylight availability and irradiance
components from direct and global irradiance", Solar Energy 44(5):271-289, 1990. From the hour's
direct normal and diffuse horizontal irradiance (W/m^2, whole solar spectrum), the sun zenith Z
(radians in the formulas) and the surface dew point Td (degC):

    sky clearness     epsilon = ((DHI + DNI) / DHI + 1.041 Z^3) / (1 + 1.041 Z^3)        (eqn 1)
    sky brightness    Delta   = DHI m / (I0 E0)                                            (eqn 2)
    precipitable water W      = exp(0.07 Td - 0.075)  cm                                   (eqn 3)
    diffuse efficacy  K_d = a + b W + c cos Z + d ln Delta                       lm/W      (eqn 7)
    beam efficacy     K_b = max(0, a + b W + c exp(5.73 Z - 5) + d Delta)        lm/W      (eqn 8)

with m Kasten's (1966) relative air mass, I0 = 1367 W/m^2 and E0 the Earth-Sun distance factor
(Spencer 1971), and a, b, c, d taken from the paper's Table 4 for the hour's clearness bin (Table 1:
bounds 1.065, 1.23, 1.5, 1.95, 2.8, 4.5, 6.2). As gendaymtx does, the zenith is held in 3..90 degrees,
epsilon in 1..11.9 and Delta in 0.01..0.6 before the tables are applied. Pure numpy, vectorized over
hours; zeros (night, no diffuse light) give finite efficacies.
"""

from __future__ import annotations

import numpy as np

SOLAR_CONSTANT = 1367.0
"""Extraterrestrial normal irradiance at the mean Earth-Sun distance, W/m^2 (the value gendaymtx uses)."""

DEFAULT_DEW_POINT = 11.0
"""Surface dew point (degC) when the weather file gives none: gendaymtx's default."""

CLEARNESS_EDGES = np.array([1.065, 1.230, 1.500, 1.950, 2.800, 4.500, 6.200])
"""Upper bounds of the sky-clearness bins 1..7 (Perez et al. 1990, Table 1); bin 8 is open above 6.2.
An epsilon on a bound falls in the bin above it."""

CLEARNESS_RANGE = (1.0, 11.9)
"""epsilon is held in this range, as gendaymtx does for irradiance input."""

BRIGHTNESS_RANGE = (0.01, 0.6)
"""Delta is held in this range, as gendaymtx and gendaylit do (ln Delta stays finite)."""

ZENITH_RANGE_DEG = (3.0, 90.0)
"""The sun zenith is held here (a sun below the horizon counts as on it), as gendaymtx does."""

# Perez et al. 1990, Table 4, one row per clearness bin (overcast first), columns a, b, c, d. The values
# are the paper's; they were checked digit for digit against Radiance's src/gen/gendaymtx.c (tables
# DiffuseLumEff and DirectLumEff) and src/gen/gendaylit.c (glob_h_diffuse_effi_PEREZ, direct_n_effi_PEREZ).
DIFFUSE_COEFFICIENTS = np.array([
    [97.24, -0.46, 12.00, -8.91],
    [107.22, 1.15, 0.59, -3.95],
    [104.97, 2.96, -5.53, -8.77],
    [102.39, 5.59, -13.95, -13.90],
    [100.71, 5.94, -22.75, -23.74],
    [106.42, 3.83, -36.15, -28.83],
    [141.88, 1.90, -53.24, -14.03],
    [152.23, 0.35, -45.27, -7.98],
])
"""Diffuse horizontal efficacy K_d = a + b W + c cos Z + d ln Delta (lm/W), eqn 7."""

DIRECT_COEFFICIENTS = np.array([
    [57.20, -4.55, -2.98, 117.12],
    [98.99, -3.46, -1.21, 12.38],
    [109.83, -4.90, -1.71, -8.81],
    [110.34, -5.84, -1.99, -4.56],
    [106.36, -3.97, -1.75, -6.16],
    [107.19, -1.25, -1.51, -26.73],
    [105.75, 0.77, -1.26, -34.44],
    [101.18, 1.58, -1.10, -8.29],
])
"""Direct normal efficacy K_b = a + b W + c exp(5.73 Z - 5) + d Delta (lm/W, at least 0), eqn 8."""


def _finite(values, fallback: float) -> np.ndarray:
    """float64 array with NaN and infinities replaced by ``fallback``."""
    values = np.asarray(values, np.float64)
    return np.where(np.isfinite(values), values, fallback)


def eccentricity(day_of_year) -> np.ndarray:
    """(R0 / R)^2, the Earth-Sun distance factor of the extraterrestrial irradiance (Spencer 1971, the
    series gendaymtx uses); ``day_of_year`` 1 = 1 January."""
    angle = (_finite(day_of_year, 1.0) - 1.0) * (2.0 * np.pi / 365.0)
    return (1.00011 + 0.034221 * np.cos(angle) + 0.00128 * np.sin(angle)
            + 0.000719 * np.cos(2.0 * angle) + 0.000077 * np.sin(2.0 * angle))


def air_mass(sun_zenith_deg) -> np.ndarray:
    """Kasten's (1966) relative optical air mass, finite up to the horizon (about 36.5 at 90 degrees)."""
    zenith = np.clip(_finite(sun_zenith_deg, 90.0), 0.0, 90.0)
    return 1.0 / (np.cos(np.radians(zenith)) + 0.15 * (93.885 - zenith) ** -1.253)


def precipitable_water(dew_point_c) -> np.ndarray:
    """Atmospheric precipitable water W (cm) from the surface dew point (degC), Perez et al. 1990 eqn 3;
    a missing (non-finite) dew point counts as ``DEFAULT_DEW_POINT``."""
    return np.exp(0.07 * _finite(dew_point_c, DEFAULT_DEW_POINT) - 0.075)


def sky_state(direct_normal, diffuse_horizontal, sun_zenith_deg, day_of_year) -> tuple[np.ndarray, np.ndarray]:
    """(epsilon, Delta): Perez sky clearness and brightness, held in ``CLEARNESS_RANGE`` and
    ``BRIGHTNESS_RANGE``. No diffuse light with a beam is the clearest sky, no light at all the most overcast."""
    dni = np.maximum(_finite(direct_normal, 0.0), 0.0)
    dhi = np.maximum(_finite(diffuse_horizontal, 0.0), 0.0)
    zenith_deg = np.clip(_finite(sun_zenith_deg, 90.0), *ZENITH_RANGE_DEG)
    z3 = 1.041 * np.radians(zenith_deg) ** 3
    lit = dhi > 0.0
    ratio = np.where(lit, (dhi + dni) / np.where(lit, dhi, 1.0),
                     np.where(dni > 0.0, CLEARNESS_RANGE[1], 1.0))
    epsilon = np.clip((ratio + z3) / (1.0 + z3), *CLEARNESS_RANGE)
    delta = dhi * air_mass(zenith_deg) / (SOLAR_CONSTANT * eccentricity(day_of_year))
    return epsilon, np.clip(delta, *BRIGHTNESS_RANGE)


def clearness_bin(epsilon) -> np.ndarray:
    """0-based Perez clearness bin (0 overcast .. 7 clear) of each epsilon."""
    return np.searchsorted(CLEARNESS_EDGES, np.asarray(epsilon, np.float64), side="right")


def perez_efficacy(direct_normal, diffuse_horizontal, sun_zenith_deg, day_of_year,
                   dew_point_c=DEFAULT_DEW_POINT) -> tuple[np.ndarray, np.ndarray]:
    """(K_beam, K_diffuse) in lm/W: the luminous efficacy of the direct normal and of the diffuse horizontal
    irradiance (W/m^2) of each hour, Perez et al. 1990 eqns 7 and 8 as gendaymtx -O0 applies them.

    All arguments broadcast together: ``sun_zenith_deg`` the (apparent) sun zenith in degrees,
    ``day_of_year`` 1 = 1 January, ``dew_point_c`` the hour's surface dew point (degC; a NaN counts as the
    11 degC default; gendaymtx uses the mean of the last three hours). Night hours, zero irradiance and
    missing (NaN) irradiance give finite efficacies; K_beam is 0 where the model falls below it (a sun
    near the horizon under an overcast sky).
    """
    dni, dhi, zenith_deg, day, dew = np.broadcast_arrays(
        *(np.asarray(v, np.float64) for v in (direct_normal, diffuse_horizontal, sun_zenith_deg, day_of_year,
                                               dew_point_c)))
    epsilon, delta = sky_state(dni, dhi, zenith_deg, day)
    zenith = np.radians(np.clip(_finite(zenith_deg, 90.0), *ZENITH_RANGE_DEG))
    water = precipitable_water(dew)
    which = clearness_bin(epsilon)
    a, b, c, d = np.moveaxis(DIFFUSE_COEFFICIENTS[which], -1, 0)
    k_diffuse = a + b * water + c * np.cos(zenith) + d * np.log(delta)
    a, b, c, d = np.moveaxis(DIRECT_COEFFICIENTS[which], -1, 0)
    k_beam = np.maximum(a + b * water + c * np.exp(5.73 * zenith - 5.0) + d * delta, 0.0)
    return k_beam, k_diffuse


def illuminance(direct_normal, diffuse_horizontal, sun_zenith_deg, day_of_year,
                dew_point_c=DEFAULT_DEW_POINT) -> tuple[np.ndarray, np.ndarray]:
    """(direct normal illuminance, diffuse horizontal illuminance) in lux: each irradiance (W/m^2; negative
    or NaN counts as 0) times its Perez efficacy (``perez_efficacy``)."""
    k_beam, k_diffuse = perez_efficacy(direct_normal, diffuse_horizontal, sun_zenith_deg, day_of_year, dew_point_c)
    dni = np.maximum(_finite(direct_normal, 0.0), 0.0)
    dhi = np.maximum(_finite(diffuse_horizontal, 0.0), 0.0)
    return k_beam * dni, k_diffuse * dhi
