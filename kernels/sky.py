"""Sky dome patch layouts, their samples, and sky radiance models (numpy).

Frames
------
Layouts and sky models live in the local ENU frame of the site: x = east,
y = north, z = up (Radiance's convention). ``enu_to_world(up_axis, north)``
maps them into the stage: for a Z-up stage east = +X, north = +Y; for a Y-up
stage east = +X, north = -Z, up = +Y (right-handed in both cases). ``north``
(degrees) turns north counter-clockwise about the up axis (seen from above).

Patch layouts
-------------
Every layout is a set of altitude rings split in azimuth plus a zenith cap.
Azimuth is measured from north towards east; the first patch of every ring
is centred on north. Patches are ordered from the horizon ring upwards, and
around each ring eastwards, the zenith cap last:

- ``reinhart`` MF:n -- Radiance's ``reinhartb.cal`` / ``genskyvec`` order.
  Ring height 90 / (7 n + 0.5) degrees, rings of n * (30, 30, 24, 24, 18, 12,
  6) patches (each Tregenza band split into n rings), one zenith cap of half
  a ring height: 145 (n = 1, ``tregenza``), 577 (n = 2), 2305 (n = 4)
  patches. Our patch j is Radiance's bin j + 1 (Radiance's bin 0 is the
  ground); directions and solid angles equal Radiance's ``Dx, Dy, Dz`` and
  ``Romega`` for x1 = x2 = 0.5.
- ``uniform`` N -- equal solid angle 2 pi / N for every patch (the layout of
  Bosch et al., Fig. 3): a zenith cap of one patch, rings of roughly square
  patches whose z boundaries are placed so each patch spans exactly 2 pi / N.

Sky models (radiance in W/(m^2 sr), "visible-equivalent" RGB: luminance / 179 lm/W, as Radiance)
----------
- ``preetham``: Preetham, Shirley & Smits 1999, "A practical analytic model
  for daylight" (SIGGRAPH 99), doi:10.1145/311535.311545: Perez functions for
  Y, x, y with turbidity-linear coefficients, zenith luminance and
  chromaticity (their Appendix A.2), xyY -> XYZ -> linear sRGB (D65).
- ``overcast``: CIE standard overcast sky, L(theta) = Lz (1 + 2 cos theta) / 3,
  Lz = 8.6 sin(sun altitude) + 0.123 kcd/m^2 (Radiance ``gensky -c``).
- ``uniform``: constant radiance.
- Sun: direct normal irradiance from the extraterrestrial illuminance
  (133.8 klx) attenuated by Preetham's Rayleigh and aerosol (Angstrom,
  beta = 0.04608 T - 0.04586, alpha = 1.3) transmittances at three
  wavelengths (680, 550, 440 nm), air mass after Kasten (1966) as in
  Preetham's appendix; ozone, water vapour and mixed-gas absorption are
  left out.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

LUMINOUS_EFFICACY = 179.0
"""lm/W: Radiance's white efficacy, turns cd/m^2 into visible-equivalent W/(m^2 sr)."""

EXTRATERRESTRIAL_ILLUMINANCE = 133_800.0
"""lux at mean Earth-Sun distance (Darula, Hooper & Kittler 2005)."""

SUN_ANGULAR_DIAMETER = 0.53
"""degrees."""

RGB_WAVELENGTHS_UM = np.array([0.680, 0.550, 0.440])
"""Wavelengths (micrometres) standing for the R, G, B channels in the sun's transmittance."""

XYZ_TO_SRGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                        [-0.9692660, 1.8760108, 0.0415560],
                        [0.0556434, -0.2040259, 1.0572252]])


# ---------------------------------------------------------------------------
# Patch layouts


@dataclass(frozen=True)
class SkyPatches:
    """A patch layout in the ENU frame (x east, y north, z up)."""

    layout: str
    subdivision: int
    patch_directions: np.ndarray
    """(N, 3) float64 unit centre directions (ENU)."""
    patch_solid_angles: np.ndarray
    """(N,) float64 steradians, summing to 2 pi."""
    patch_bounds: np.ndarray
    """(N, 4) float64 (z_lo, z_hi, azimuth_lo, azimuth_hi): z = sin(altitude), azimuth in radians from north
    towards east; the patch is the set of directions with z in [z_lo, z_hi] and azimuth in [lo, hi]."""
    patch_radius: np.ndarray
    """(N,) float64 largest angle (radians) between the centre and any point of the patch."""

    def __len__(self) -> int:
        return len(self.patch_solid_angles)


def _rings_to_patches(layout: str, subdivision: int, alt_edges: np.ndarray, counts: list[int],
                      z_edges: np.ndarray | None = None) -> SkyPatches:
    """Build a layout from ring altitude edges (radians, horizon first) and patch counts per ring."""
    if z_edges is None:
        z_edges = np.sin(alt_edges)
    rows = []
    for ring, count in enumerate(counts):
        z_lo, z_hi = z_edges[ring], z_edges[ring + 1]
        width = 2 * np.pi / count
        for col in range(count):
            rows.append((z_lo, z_hi, (col - 0.5) * width, (col + 0.5) * width))
    bounds = np.array(rows, np.float64)
    z_lo, z_hi, az_lo, az_hi = bounds.T
    solid = (z_hi - z_lo) * (az_hi - az_lo)
    cap = z_hi >= 1.0 - 1e-12
    # Centre: mid altitude (as Radiance: (row + 0.5) * ring height) and mid azimuth; the cap centre is the zenith.
    alt_mid = 0.5 * (np.arcsin(np.clip(z_lo, -1, 1)) + np.arcsin(np.clip(z_hi, -1, 1)))
    alt_mid = np.where(cap & (np.abs(az_hi - az_lo - 2 * np.pi) < 1e-9), np.pi / 2, alt_mid)
    az_mid = 0.5 * (az_lo + az_hi)
    directions = altaz_to_enu(alt_mid, az_mid)
    radius = _patch_radius(bounds, directions)
    return SkyPatches(layout, subdivision, directions, solid, bounds, radius)


def _patch_radius(bounds: np.ndarray, directions: np.ndarray, steps: int = 9) -> np.ndarray:
    """Largest angle between a patch centre and its boundary (sampled), plus a small margin."""
    t = np.linspace(0.0, 1.0, steps)
    z_lo, z_hi, az_lo, az_hi = (bounds[:, k:k + 1] for k in range(4))
    az = az_lo + t * (az_hi - az_lo)
    z = z_lo + t * (z_hi - z_lo)
    edges = [
        (np.broadcast_to(z_lo, az.shape), az), (np.broadcast_to(z_hi, az.shape), az),
        (z, np.broadcast_to(az_lo, z.shape)), (z, np.broadcast_to(az_hi, z.shape)),
    ]
    worst = np.zeros(len(bounds))
    for zz, aa in edges:
        points = altaz_to_enu(np.arcsin(np.clip(zz, -1, 1)), aa)
        cos = np.einsum("nkc,nc->nk", points, directions)
        worst = np.maximum(worst, np.arccos(np.clip(cos, -1, 1)).max(axis=1))
    return worst * 1.02 + 1e-6


def altaz_to_enu(altitude, azimuth) -> np.ndarray:
    """Unit ENU vectors from altitude and azimuth (radians, azimuth from north towards east)."""
    altitude = np.asarray(altitude, np.float64)
    azimuth = np.asarray(azimuth, np.float64)
    c = np.cos(altitude)
    return np.stack([np.sin(azimuth) * c, np.cos(azimuth) * c, np.sin(altitude)], axis=-1)


def reinhart_patches(subdivision: int = 1) -> SkyPatches:
    """Radiance's Reinhart MF:n layout (n = 1 is Tregenza's 145 patches), in reinhartb.cal order."""
    if subdivision < 1:
        raise ValueError(f"subdivision={subdivision} must be >= 1")
    mf = int(subdivision)
    ring_height = np.radians(90.0 / (7 * mf + 0.5))
    tregenza = (30, 30, 24, 24, 18, 12, 6)
    counts = [mf * tregenza[row // mf] for row in range(7 * mf)] + [1]
    alt_edges = np.append(np.arange(7 * mf + 1) * ring_height, np.pi / 2)
    z_edges = np.sin(alt_edges)
    z_edges[-1] = 1.0
    return _rings_to_patches("tregenza" if mf == 1 else "reinhart", mf, alt_edges, counts, z_edges)


def tregenza_patches() -> SkyPatches:
    return reinhart_patches(1)


def uniform_patches(count: int = 256) -> SkyPatches:
    """``count`` patches of equal solid angle 2 pi / count: a zenith cap and rings of near-square patches."""
    if count < 1:
        raise ValueError(f"count={count} must be >= 1")
    if count == 1:
        return _rings_to_patches("uniform", count, np.array([0.0, np.pi / 2]), [1], np.array([0.0, 1.0]))
    side = math.sqrt(2 * np.pi / count)
    cap_angle = math.acos(1.0 - 1.0 / count)  # one patch of solid angle 2 pi / count
    rings = max(1, int(round((np.pi / 2 - cap_angle) / side)))
    theta = np.linspace(np.pi / 2, cap_angle, rings + 1)  # zenith angles, horizon first
    areas = np.cos(theta[1:]) - np.cos(theta[:-1])        # ring areas / 2 pi
    ideal = areas / areas.sum() * (count - 1)
    counts = np.floor(ideal).astype(int)
    for k in np.argsort(ideal - counts)[::-1][: count - 1 - counts.sum()]:  # largest remainders
        counts[k] += 1
    counts = np.maximum(counts, 1)
    while counts.sum() > count - 1:  # only when a tiny count forced 1s
        counts[np.argmax(counts)] -= 1
    cumulative = np.concatenate([[0], np.cumsum(counts)])
    z_edges = np.append(cumulative / count, 1.0)  # ring k spans exactly counts[k] * 2 pi / count
    z_edges[-2] = 1.0 - 1.0 / count
    alt_edges = np.arcsin(np.clip(z_edges, 0, 1))
    return _rings_to_patches("uniform", count, alt_edges, list(counts) + [1], z_edges)


def patch_layout(layout: str, *, count: int = 256, subdivision: int = 2) -> SkyPatches:
    """The named layout: 'uniform' (``count`` patches), 'tregenza' (145) or 'reinhart' (MF ``subdivision``)."""
    if layout == "uniform":
        return uniform_patches(count)
    if layout == "tregenza":
        return reinhart_patches(1)
    if layout == "reinhart":
        return reinhart_patches(subdivision)
    raise ValueError(f"unknown patch layout {layout!r} (uniform, tregenza, reinhart)")


def enu_to_world(up_axis: str, north: float = 0.0) -> np.ndarray:
    """(3, 3) float64 matrix M with world = M @ enu for the stage's up axis; ``north`` in degrees."""
    a = math.radians(north)
    turn = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    if up_axis == "Z":
        base = np.eye(3)
    elif up_axis == "Y":
        base = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    else:
        raise ValueError(f"up axis {up_axis!r} is not 'Y' or 'Z'")
    return base @ turn


def patch_samples(patches: SkyPatches, per_side: int = 3) -> np.ndarray:
    """(N, per_side^2, 3) ENU directions on a per_side x per_side grid in (z, azimuth), equal solid angle each."""
    t = (np.arange(per_side) + 0.5) / per_side
    z_lo, z_hi, az_lo, az_hi = patches.patch_bounds.T
    z = z_lo[:, None, None] + t[None, :, None] * (z_hi - z_lo)[:, None, None]
    az = az_lo[:, None, None] + t[None, None, :] * (az_hi - az_lo)[:, None, None]
    z, az = np.broadcast_arrays(z, az)
    directions = altaz_to_enu(np.arcsin(np.clip(z, -1, 1)), az)
    return directions.reshape(len(patches), per_side * per_side, 3)


def patch_jittered_samples(patches: SkyPatches, strata: int, seed: int, variants: int = 1) -> np.ndarray:
    """(variants, N, strata^2, 3) ENU unit directions: in each patch, per variant, one uniform (equal solid
    angle) direction per cell of a strata x strata grid over its (z, azimuth) rectangle, cell s at z column
    s % strata, azimuth row s // strata.

    The random samples inside a sky patch of Bosch, Besuievsky & Martin, Sec. 4.1 (Fig. 2 and 4: "generate
    s random samples within the patch"), stratified (Cook 1986): z = sin(altitude) and azimuth uniform in a
    cell give directions of constant density per steradian (Archimedes' hat-box theorem). Drawn once per
    (seed, strata, variants) from a generator of their own, so a kernel reads them instead of making them
    per ray; a face takes one of the ``variants`` sets, so that neighbouring faces do not all
    err the same way (the paper's renderings share one set across all faces, and an average over faces then
    keeps that set's error however many faces it spans). Kept for the next pass (a few ms each to draw):
    the array is read-only.
    """
    bounds = np.ascontiguousarray(patches.patch_bounds, np.float64)
    return _jittered_samples(bounds.tobytes(), len(bounds), strata, seed, variants)


@functools.lru_cache(maxsize=8)
def _jittered_samples(bounds: bytes, count: int, strata: int, seed: int, variants: int) -> np.ndarray:
    """``patch_jittered_samples`` of the (count, 4) float64 patch bounds in ``bounds``."""
    bounds = np.frombuffer(bounds, np.float64).reshape(count, 4)
    rng = np.random.default_rng([seed, strata, variants])
    cells = np.arange(strata * strata)
    grid = np.stack([cells % strata, cells // strata], axis=1)
    u = (grid[None, None] + rng.random((variants, count, len(cells), 2))) / strata
    z_lo, z_hi, az_lo, az_hi = (bounds[None, :, k, None] for k in range(4))
    z = z_lo + u[..., 0] * (z_hi - z_lo)
    samples = altaz_to_enu(np.arcsin(np.clip(z, -1.0, 1.0)), az_lo + u[..., 1] * (az_hi - az_lo))
    samples.flags.writeable = False
    return samples


def patch_mean_directions(bounds: np.ndarray) -> np.ndarray:
    """(N, 3) mean of the ENU direction w over each patch (per steradian), exact: n . (this) is the patch's
    mean of n . w, which equals its mean of max(0, n . w) when the whole patch lies above the plane of n.
    With z and azimuth uniform, w = (r sin az, r cos az, z), r = sqrt(1 - z^2), so

        int w dw = (int r dz (cos az0 - cos az1), int r dz (sin az1 - sin az0), (z1^2 - z0^2) / 2 (az1 - az0)),

    int r dz = (z r + asin z) / 2, divided by the patch's (z1 - z0)(az1 - az0)."""
    z0, z1, a0, a1 = np.asarray(bounds, np.float64).T

    def int_r(z):
        return 0.5 * (z * np.sqrt(np.maximum(1.0 - z * z, 0.0)) + np.arcsin(np.clip(z, -1.0, 1.0)))

    rings = int_r(z1) - int_r(z0)
    integral = np.stack([rings * (np.cos(a0) - np.cos(a1)), rings * (np.sin(a1) - np.sin(a0)),
                         0.5 * (z1 * z1 - z0 * z0) * (a1 - a0)], axis=1)
    return integral / np.maximum((z1 - z0) * (a1 - a0), 1e-30)[:, None]


def patch_outlines(bounds: np.ndarray) -> np.ndarray:
    """(N, 5, 3) ENU unit directions of each patch's four corners and its (z, azimuth) midpoint, which
    ``patch_visibility`` holds against a face's plane to find the patches wholly above it."""
    z0, z1, a0, a1 = np.asarray(bounds, np.float64).T
    z = np.stack([z0, z0, z1, z1, 0.5 * (z0 + z1)], axis=1)
    azimuth = np.stack([a0, a1, a0, a1, 0.5 * (a0 + a1)], axis=1)
    return altaz_to_enu(np.arcsin(np.clip(z, -1.0, 1.0)), azimuth)


# ---------------------------------------------------------------------------
# Sky models (ENU directions; sun given as an ENU unit vector)


def _perez(cos_theta, gamma, coeffs):
    a, b, c, d, e = coeffs
    cos_theta = np.maximum(cos_theta, 0.01)  # the horizon limit; Perez diverges at cos = 0
    return (1 + a * np.exp(b / cos_theta)) * (1 + c * np.exp(d * gamma) + e * np.cos(gamma) ** 2)


def _xyy_to_rgb(x, y, big_y) -> np.ndarray:
    y = np.maximum(y, 1e-6)
    xyz = np.stack([x / y * big_y, big_y, (1 - x - y) / y * big_y], axis=-1)
    return np.maximum(xyz @ XYZ_TO_SRGB.T, 0.0)


def preetham_radiance(directions: np.ndarray, sun: np.ndarray, turbidity: float = 3.0) -> np.ndarray:
    """(..., 3) sky radiance (W/(m^2 sr), luminance / 179) of Preetham et al. 1999 for ENU directions.

    The sky is black when the sun is below the horizon (the model is not defined there).
    """
    t = float(turbidity)
    directions = np.asarray(directions, np.float64)
    sun = np.asarray(sun, np.float64) / np.linalg.norm(sun)
    if sun[2] <= 0.0:
        return np.zeros(directions.shape[:-1] + (3,))
    theta_s = math.acos(min(1.0, sun[2]))
    coeff_y = (0.1787 * t - 1.4630, -0.3554 * t + 0.4275, -0.0227 * t + 5.3251, 0.1206 * t - 2.5771,
               -0.0670 * t + 0.3703)
    coeff_x = (-0.0193 * t - 0.2592, -0.0665 * t + 0.0008, -0.0004 * t + 0.2125, -0.0641 * t - 0.8989,
               -0.0033 * t + 0.0452)
    coeff_yc = (-0.0167 * t - 0.2608, -0.0950 * t + 0.0092, -0.0079 * t + 0.2102, -0.0441 * t - 1.6537,
                -0.0109 * t + 0.0529)
    chi = (4.0 / 9.0 - t / 120.0) * (np.pi - 2 * theta_s)
    zenith_y = max(0.0, (4.0453 * t - 4.9710) * math.tan(chi) - 0.2155 * t + 2.4192) * 1000.0  # cd/m^2
    t_vec = np.array([t * t, t, 1.0])
    th = np.array([theta_s ** 3, theta_s ** 2, theta_s, 1.0])
    zenith_x = t_vec @ np.array([[0.00166, -0.00375, 0.00209, 0.0], [-0.02903, 0.06377, -0.03202, 0.00394],
                                 [0.11693, -0.21196, 0.06052, 0.25886]]) @ th
    zenith_yc = t_vec @ np.array([[0.00275, -0.00610, 0.00317, 0.0], [-0.04214, 0.08970, -0.04153, 0.00516],
                                  [0.15346, -0.26756, 0.06670, 0.26688]]) @ th
    cos_theta = directions[..., 2]
    gamma = np.arccos(np.clip(directions @ sun, -1.0, 1.0))

    def relative(coeffs):
        return _perez(cos_theta, gamma, coeffs) / _perez(np.float64(1.0), theta_s, coeffs)

    big_y = zenith_y * relative(coeff_y)
    x = zenith_x * relative(coeff_x)
    y = zenith_yc * relative(coeff_yc)
    rgb = _xyy_to_rgb(x, y, big_y) / LUMINOUS_EFFICACY
    return np.where((cos_theta >= 0.0)[..., None], rgb, 0.0)


def overcast_radiance(directions: np.ndarray, sun: np.ndarray) -> np.ndarray:
    """(..., 3) CIE overcast sky radiance, grey, zenith 8.6 sin(sun altitude) + 0.123 kcd/m^2 (gensky -c)."""
    directions = np.asarray(directions, np.float64)
    sun = np.asarray(sun, np.float64) / np.linalg.norm(sun)
    zenith = (8.6 * max(sun[2], 0.0) + 0.123) * 1000.0 / LUMINOUS_EFFICACY
    value = zenith * (1 + 2 * np.maximum(directions[..., 2], 0.0)) / 3.0
    return np.repeat(value[..., None], 3, axis=-1)


def uniform_radiance(directions: np.ndarray, radiance: float = 1.0) -> np.ndarray:
    directions = np.asarray(directions, np.float64)
    return np.full(directions.shape[:-1] + (3,), float(radiance))


def air_mass(cos_zenith: float) -> float:
    """Relative optical air mass, Kasten (1966), finite at the horizon."""
    zenith_deg = math.degrees(math.acos(min(1.0, max(-1.0, cos_zenith))))
    if zenith_deg >= 93.885:
        return math.inf
    return 1.0 / (max(cos_zenith, 0.0) + 0.15 * (93.885 - zenith_deg) ** -1.253)


def sun_normal_irradiance(sun: np.ndarray, turbidity: float = 3.0, day_of_year: int = 172) -> np.ndarray:
    """(3,) direct normal irradiance of the sun (W/m^2, illuminance / 179), RGB; zero below the horizon.

    Extraterrestrial illuminance (with the Earth-Sun distance correction) times Preetham's Rayleigh and
    aerosol transmittances at the RGB wavelengths.
    """
    sun = np.asarray(sun, np.float64) / np.linalg.norm(sun)
    if sun[2] <= 0.0:
        return np.zeros(3)
    m = air_mass(sun[2])
    beta = max(0.0, 0.04608 * turbidity - 0.04586)
    lam = RGB_WAVELENGTHS_UM
    transmittance = np.exp(-0.008735 * lam ** -4.08 * m) * np.exp(-beta * lam ** -1.3 * m)
    distance = 1.0 + 0.033 * math.cos(2 * np.pi * day_of_year / 365.0)
    return EXTRATERRESTRIAL_ILLUMINANCE * distance / LUMINOUS_EFFICACY * transmittance


# Perez, Seals & Michalsky 1993, "All-weather model for sky luminance distribution", Table 1 (with the
# 1993 erratum): for each of the 8 sky-clearness bins, coefficients x1..x4 of a, b, c, d and e, where
# x = x1 + x2 Z + Delta (x3 + x4 Z) (Z: solar zenith angle in radians).
PEREZ_COEFFICIENTS = np.array([
    1.3525, -0.2576, -0.2690, -1.4366, -0.7670, 0.0007, 1.2734, -0.1233, 2.8000, 0.6004, 1.2375, 1.0000,
    1.8734, 0.6297, 0.9738, 0.2809, 0.0356, -0.1246, -0.5718, 0.9938,
    -1.2219, -0.7730, 1.4148, 1.1016, -0.2054, 0.0367, -3.9128, 0.9156, 6.9750, 0.1774, 6.4477, -0.1239,
    -1.5798, -0.5081, -1.7812, 0.1080, 0.2624, 0.0672, -0.2190, -0.4285,
    -1.1000, -0.2515, 0.8952, 0.0156, 0.2782, -0.1812, -4.5000, 1.1766, 24.7219, -13.0812, -37.7000, 34.8438,
    -5.0000, 1.5218, 3.9229, -2.6204, -0.0156, 0.1597, 0.4199, -0.5562,
    -0.5484, -0.6654, -0.2672, 0.7117, 0.7234, -0.6219, -5.6812, 2.6297, 33.3389, -18.3000, -62.2500, 52.0781,
    -3.5000, 0.0016, 1.1477, 0.1062, 0.4659, -0.3296, -0.0876, -0.0329,
    -0.6000, -0.3566, -2.5000, 2.3250, 0.2937, 0.0496, -5.6812, 1.8415, 21.0000, -4.7656, -21.5906, 7.2492,
    -3.5000, -0.1554, 1.4062, 0.3988, 0.0032, 0.0766, -0.0656, -0.1294,
    -1.0156, -0.3670, 1.0078, 1.4051, 0.2875, -0.5328, -3.8500, 3.3750, 14.0000, -0.9999, -7.1406, 7.5469,
    -3.4000, -0.1078, -1.0750, 1.5702, -0.0672, 0.4016, 0.3017, -0.4844,
    -1.0000, 0.0211, 0.5025, -0.5119, -0.3000, 0.1922, 0.7023, -1.6317, 19.0000, -5.0000, 1.2438, -1.9094,
    -4.0000, 0.0250, 0.3844, 0.2656, 1.0468, -0.3788, -2.4517, 1.4656,
    -1.0500, 0.0289, 0.4260, 0.3590, -0.3250, 0.1156, 0.7781, 0.0025, 31.0625, -14.5000, -46.1148, 55.3750,
    -7.2312, 0.4050, 13.3500, 0.6234, 1.5000, -0.6426, 1.8564, 0.5636,
]).reshape(8, 5, 4)

PEREZ_CLEARNESS_EDGES = np.array([1.065, 1.230, 1.500, 1.950, 2.800, 4.500, 6.200])
"""Upper edges of the sky-clearness bins 1..7 (bin 8 is open above 6.2)."""

SOLAR_CONSTANT = 1367.0
"""Extraterrestrial normal irradiance at the mean Earth-Sun distance, W/m^2."""


def perez_sky_state(sun_zenith: float, direct_normal: float, diffuse_horizontal: float,
                    day_of_year: int = 172) -> tuple[float, float]:
    """Sky clearness epsilon and brightness Delta (Perez et al. 1990) from DNI and DHI in W/m^2,
    clamped to the model's range (epsilon 1..12, Delta 0.01..0.6) as Radiance's gendaylit does."""
    z = float(sun_zenith)
    dhi = max(float(diffuse_horizontal), 1e-9)
    kappa_z3 = 1.041 * z ** 3
    epsilon = ((dhi + max(float(direct_normal), 0.0)) / dhi + kappa_z3) / (1.0 + kappa_z3)
    extraterrestrial = SOLAR_CONSTANT * (1.0 + 0.033 * math.cos(2 * np.pi * day_of_year / 365.0))
    delta = min(air_mass(math.cos(z)), 40.0) * dhi / extraterrestrial
    return float(np.clip(epsilon, 1.0, 12.0)), float(np.clip(delta, 0.01, 0.6))


def perez_coefficients(sun_zenith: float, epsilon: float, delta: float) -> np.ndarray:
    """(5,) a, b, c, d, e of the all-weather model for one sky state (bin 1 has its own c and d)."""
    z = float(sun_zenith)
    x = PEREZ_COEFFICIENTS[int(np.searchsorted(PEREZ_CLEARNESS_EDGES, epsilon, side="right"))]
    coefficients = x[:, 0] + x[:, 1] * z + delta * (x[:, 2] + x[:, 3] * z)
    if epsilon < PEREZ_CLEARNESS_EDGES[0]:
        coefficients[2] = math.exp((delta * (x[2, 0] + x[2, 1] * z)) ** x[2, 2]) - x[2, 3]
        coefficients[3] = -math.exp(delta * (x[3, 0] + x[3, 1] * z)) + x[3, 2] + delta * x[3, 3]
    return coefficients


def perez_relative_luminance(directions: np.ndarray, sun: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """(...,) lv = (1 + a exp(b / cos zeta)) (1 + c exp(d gamma) + e cos^2 gamma) (Perez et al. 1993, Eq. 1);
    zeta is the element's zenith angle, gamma its angle to the sun; zero below the horizon."""
    directions = np.asarray(directions, np.float64)
    sun = np.asarray(sun, np.float64) / np.linalg.norm(sun)
    a, b, c, d, e = coefficients
    cos_zeta = directions[..., 2]
    cos_gamma = np.clip(directions @ sun, -1.0, 1.0)
    gamma = np.arccos(cos_gamma)
    gradation = 1.0 + a * np.exp(b / np.maximum(cos_zeta, 0.01))  # 0.01: finite at the horizon, as gendaylit
    indicatrix = 1.0 + c * np.exp(d * gamma) + e * cos_gamma ** 2
    return np.where(cos_zeta >= 0.0, np.maximum(gradation * indicatrix, 0.0), 0.0)


def _hemisphere_quadrature(rings: int = 90, segments: int = 180) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint directions and solid angles of a (zenith x azimuth) grid over the upper hemisphere."""
    zeta_edges = np.linspace(0.0, np.pi / 2, rings + 1)
    zeta = (zeta_edges[:-1] + zeta_edges[1:]) / 2
    phi = (np.arange(segments) + 0.5) * 2 * np.pi / segments
    solid = (np.cos(zeta_edges[:-1]) - np.cos(zeta_edges[1:]))[:, None] * np.full(segments, 2 * np.pi / segments)
    zz, pp = np.meshgrid(zeta, phi, indexing="ij")
    directions = np.stack([np.sin(zz) * np.sin(pp), np.sin(zz) * np.cos(pp), np.cos(zz)], axis=-1)
    return directions.reshape(-1, 3), solid.reshape(-1)


def perez_radiance(directions: np.ndarray, sun: np.ndarray, direct_normal: float, diffuse_horizontal: float,
                   day_of_year: int = 172) -> np.ndarray:
    """(..., 3) grey sky radiance (W/(m^2 sr)) of the Perez all-weather model driven by direct-normal and
    diffuse-horizontal irradiance (what weather files give), scaled so that the sky's horizontal
    irradiance integral_{H} L cos(zeta) dw equals ``diffuse_horizontal`` (as gendaylit normalizes)."""
    sun = np.asarray(sun, np.float64) / np.linalg.norm(sun)
    zenith = math.acos(float(np.clip(sun[2], -1.0, 1.0)))
    coefficients = perez_coefficients(zenith, *perez_sky_state(min(zenith, math.radians(87.0)), direct_normal,
                                                                diffuse_horizontal, day_of_year))
    grid, solid = _hemisphere_quadrature()
    horizontal = float((perez_relative_luminance(grid, sun, coefficients) * grid[:, 2] * solid).sum())
    scale = float(diffuse_horizontal) / horizontal if horizontal > 0 else 0.0
    value = perez_relative_luminance(directions, sun, coefficients) * scale
    return np.repeat(value[..., None], 3, axis=-1)


def patch_radiance(patches: SkyPatches, model: str, sun: np.ndarray, *, turbidity: float = 3.0,
                   radiance: float = 1.0, per_side: int = 3, direct_normal: float = 0.0,
                   diffuse_horizontal: float = 0.0, day_of_year: int = 172) -> np.ndarray:
    """(N, 3) mean radiance of each patch (model averaged over a per_side^2 grid of equal solid angle).

    The patch radiance Lhat_j of Bosch, Besuievsky & Martin, Sec. 5, Eq. 1 ("the
    average radiance of the sky patch j"), in W/(m^2 sr) (visible-equivalent
    for the preetham and overcast models).
    """
    directions = patch_samples(patches, per_side)
    if model == "perez":
        values = perez_radiance(directions, sun, direct_normal, diffuse_horizontal, day_of_year)
    elif model == "preetham":
        values = preetham_radiance(directions, sun, turbidity)
    elif model == "overcast":
        values = overcast_radiance(directions, sun)
    elif model == "uniform":
        values = uniform_radiance(directions, radiance)
    else:
        raise ValueError(f"unknown sky model {model!r} (preetham, perez, overcast, uniform)")
    return values.mean(axis=1)
