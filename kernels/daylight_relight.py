"""Daylight relit from daylight coefficients: the sky, the sun and their interreflected light at any time.

Bosch, Besuievsky & Martin, Sec. 5, Eq. 1: with the sky visibility factors V_ij precomputed, any sky and
sun relights a face with one matrix product and no rays; the indirect coefficients D_ij (interreflection:
the two-phase method of Tregenza & Waters 1983) and a table of the sun's visibility over its yearly path
(``SunTable``) make the total exact without rays too. Shared by the daylight technique, which computes the
coefficients, and by what relights them elsewhere (``preview/stream_client.py``: the browser stream's
coefficients, relit as the library does).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .luminous_efficacy import CLEARNESS_EDGES, DIFFUSE_COEFFICIENTS, DIRECT_COEFFICIENTS, perez_efficacy
from .sky import (LUMINOUS_EFFICACY, PEREZ_CLEARNESS_EDGES, PEREZ_COEFFICIENTS, SkyPatches, enu_to_world,
                  patch_radiance, patch_samples, sun_normal_irradiance)
from .solar import day_of_year, sun_position

RELIGHT_CHUNK = 16384
"""Rows per chunk when V is uint8: the float32 copy of a chunk (16 MB at 256 patches) stays small."""


def relight_daylight(visibility: np.ndarray, sky_weights: np.ndarray, *, scale: float = 1.0,
            albedo: np.ndarray | None = None, sun: np.ndarray | None = None, patch_major: bool = False,
            chunk: int = RELIGHT_CHUNK) -> np.ndarray:
    """Paper Eq. 1 as one matrix product: (F, 3) float32 radiance (or irradiance without ``albedo``).

    Bosch, Besuievsky & Martin, Sec. 5, Eq. 1, L_i = rho_i / pi * (sum_j Lhat_j V_ij
    dw_j + E_sun,i): irradiance in W/m^2, radiance in W/(m^2 sr) with ``albedo``
    (the 1/pi of a Lambertian BRDF, which the paper's Eq. 1 leaves in rho).

    Parameters
    ----------
    visibility : (F, N) float32 V_ij, or uint8 quantized V (then multiplied by ``scale``); with
        ``patch_major`` the transpose, (N, F) float32 -- the fastest layout (one (3, N) x (N, F) BLAS
        product streaming V once; see ``SkyVisibilityProduct.visibility_patch_major``)
    sky_weights : (N, 3) Lhat_j * dw_j, RGB (W/m^2 per patch)
    albedo : (F, 3), optional; the result is then albedo / pi * irradiance (Lambertian radiance)
    sun : (F, 3), optional direct sun irradiance added before the albedo

    Linear in ``sky_weights`` and ``sun``. uint8 V is converted in chunks of ``chunk`` rows.
    """
    weights = np.ascontiguousarray(sky_weights, np.float32).reshape(-1, 3) * np.float32(scale)
    n_patch = visibility.shape[0] if patch_major else visibility.shape[-1]
    if visibility.ndim != 2 or n_patch != len(weights):
        raise ValueError(f"visibility {visibility.shape} does not match sky_weights {weights.shape}")
    if patch_major:
        out = np.ascontiguousarray((weights.T @ visibility).T)
    elif visibility.dtype == np.float32:
        out = visibility @ weights
    else:
        out = np.empty((len(visibility), 3), np.float32)
        for lo in range(0, len(visibility), chunk):
            out[lo:lo + chunk] = visibility[lo:lo + chunk].astype(np.float32) @ weights
    if sun is not None:
        out += np.asarray(sun, np.float32)
    if albedo is not None:
        out *= np.asarray(albedo, np.float32) * np.float32(1.0 / np.pi)
    return out


def sky_weights(patches: SkyPatches, model: str, sun_layout: np.ndarray, *, turbidity: float, radiance: float,
                direct_normal: float = 0.0, diffuse_horizontal: float = 0.0, day_of_year: int = 172,
                efficacy: str = "perez") -> np.ndarray:
    """(N, 3) Lhat_j * dw_j for ``patches``; ``sun_layout`` is the sun in the layout's ENU frame.
    The Perez sky (solar W/m^2 from the weather's DHI) is turned into visible-equivalent watts by
    ``visible_factors``; the other models are visible already."""
    values = patch_radiance(patches, model, sun_layout, turbidity=turbidity, radiance=radiance,
                            direct_normal=direct_normal, diffuse_horizontal=diffuse_horizontal,
                            day_of_year=day_of_year)
    if model == "perez":
        values = values * visible_factors(efficacy, direct_normal, diffuse_horizontal, sun_layout, day_of_year)[1]
    return (values * patches.patch_solid_angles[:, None]).astype(np.float32)


def sky_and_sun(patches: SkyPatches, model: str, sun_site: np.ndarray, sun_layout: np.ndarray, day: int, *,
                sun: bool, turbidity: float, uniform_radiance: float, direct_normal: float, diffuse_horizontal: float,
                efficacy: str) -> tuple[np.ndarray, np.ndarray | None]:
    """One time's (N, 3) sky patch weights (``sky_weights``) and the sun's (3,) direct normal irradiance
    (``sun_normal``; None without a sun, or with ``sun`` off)."""
    weights = sky_weights(patches, model, sun_layout, turbidity=turbidity, radiance=uniform_radiance,
                          direct_normal=direct_normal, diffuse_horizontal=diffuse_horizontal, day_of_year=day,
                          efficacy=efficacy)
    e_normal = sun_normal(model, sun_site, turbidity=turbidity, direct_normal=direct_normal, day_of_year=day,
                          diffuse_horizontal=diffuse_horizontal, efficacy=efficacy) if sun else None
    return weights, e_normal


def sky_model_tables() -> dict:
    """The sky models' tables, JSON-able, for what evaluates them elsewhere (the browser viewer's sky.js reads
    them from the daylight stream's header rather than keeping a copy): Perez, Seals & Michalsky 1993 Table 1
    (bins x parameters x 4, flat) and its clearness edges, and the Perez et al. 1990 efficacy Table 4."""
    return {"perez_coefficients": PEREZ_COEFFICIENTS.ravel().tolist(),
            "perez_clearness_edges": PEREZ_CLEARNESS_EDGES.tolist(),
            "efficacy_clearness_edges": CLEARNESS_EDGES.tolist(),
            "efficacy_diffuse": DIFFUSE_COEFFICIENTS.tolist(), "efficacy_direct": DIRECT_COEFFICIENTS.tolist()}


def visible_factors(efficacy: str, direct_normal: float, diffuse_horizontal: float, sun_enu: np.ndarray,
                    day: int) -> tuple[float, float]:
    """(beam, diffuse) factors from solar to visible-equivalent W/m^2 (lux / 179): the Perez et al. 1990
    luminous efficacies over Radiance's 179 lm/W (``efficacy = perez``, as gendaymtx -O0), or 1 (``179``:
    solar watts taken as visible, gendaymtx -O1)."""
    if efficacy == "179":
        return 1.0, 1.0
    zenith = np.degrees(np.arccos(np.clip(sun_enu[2] / np.linalg.norm(sun_enu), -1.0, 1.0)))
    beam, diffuse = perez_efficacy(np.array([direct_normal]), np.array([diffuse_horizontal]), np.array([zenith]),
                                   np.array([day]))
    return float(beam[0]) / LUMINOUS_EFFICACY, float(diffuse[0]) / LUMINOUS_EFFICACY


def sun_normal(sky: str, sun_site: np.ndarray, *, turbidity: float, direct_normal: float,
               day_of_year: int, diffuse_horizontal: float = 0.0, efficacy: str = "perez") -> np.ndarray | None:
    """(3,) direct normal irradiance of the sun (visible-equivalent W/m^2) for the sky model, or None when the
    model has no sun (overcast, uniform) or it is below the horizon (``sun_site``: unit ENU direction)."""
    if sky not in ("preetham", "perez") or sun_site[2] <= 0:
        return None
    if sky == "preetham":
        return sun_normal_irradiance(sun_site, turbidity, day_of_year)
    beam, _ = visible_factors(efficacy, direct_normal, diffuse_horizontal, sun_site, day_of_year)
    return np.full(3, float(direct_normal) * beam)


SUN_PATCHES = 4
"""Patches the sun's reflected light is spread over (``gendaymtx``: the 4 nearest, weights 1 / (1.002 - cos))."""


def horizontal_cosines(patches: SkyPatches) -> np.ndarray:
    """(N,) mean cosine of each patch's directions with the zenith: sum_j w_j c_j is the sky's horizontal
    irradiance."""
    return np.maximum(patch_samples(patches, 3)[..., 2], 0.0).mean(axis=1)


def sun_patch_weights(patches: SkyPatches, sun_enu: np.ndarray, normal_irradiance: np.ndarray) -> np.ndarray:
    """(N, 3) the sun's direct normal irradiance spread over the ``SUN_PATCHES`` patches nearest it, weights
    1 / (1.002 - cos) as ``gendaymtx`` (zeros below the horizon): the sun seen as sky, for its reflected light."""
    out = np.zeros((len(patches), 3), np.float32)
    if sun_enu[2] <= 0:
        return out
    cosines = patches.patch_directions @ (np.asarray(sun_enu, np.float64) / np.linalg.norm(sun_enu))
    nearest = np.argsort(-cosines)[:SUN_PATCHES]
    weights = 1.0 / (1.002 - cosines[nearest])
    out[nearest] = (weights / weights.sum())[:, None] * np.asarray(normal_irradiance, np.float32)[None, :]
    return out


def ground_radiance(patches: SkyPatches, sky_weights: np.ndarray, sun_enu: np.ndarray,
                    normal_irradiance: np.ndarray | None, reflectance: float) -> np.ndarray:
    """(3,) radiance of the ground outside the model: rho_g (sky + sun horizontal irradiance) / pi."""
    horizontal = horizontal_cosines(patches) @ np.asarray(sky_weights, np.float64)
    if normal_irradiance is not None and sun_enu[2] > 0:
        horizontal = horizontal + np.asarray(normal_irradiance, np.float64) * sun_enu[2] / np.linalg.norm(sun_enu)
    return (reflectance * horizontal / np.pi).astype(np.float32)


def sun_levels(samples: int) -> int:
    """Steps of a byte that ``sun_bin_hits`` stores the visible share in: the largest multiple of ``samples``
    up to 255, so ray counts without glazing are stored exactly and shares through glass to 1/levels."""
    return int(samples) * (255 // int(samples))


MAX_DECLINATION = 23.45
"""Degrees: the sun's declination stays within the obliquity of the ecliptic."""


@dataclass(frozen=True)
class SunTable:
    """The sun's visibility S_i of every face on a grid of the sun's declination and hour angle at one
    site -- the sun's path over any year -- bilinear in between: relighting any time there is a blend of
    four table rows instead of shadow rays. Written here because a face's shadows move with the sun
    along this grid, not along sky patches, so neighbouring nodes blend into the shadow in between."""

    declinations: np.ndarray
    """(K,) degrees, ascending, -MAX_DECLINATION..MAX_DECLINATION."""
    hour_angles: np.ndarray
    """(M,) degrees, -180 + m * 360 / M (periodic)."""
    node_row: np.ndarray
    """(K, M) int64 row of ``hits`` per node, -1 where the sun is below the horizon."""
    hits: np.ndarray
    """(R, F) uint8 share of the sun each face sees per node above the horizon, in steps of
    1 / ``sun_levels(samples)`` (``sun_bin_hits``)."""
    samples: int

    def visibility(self, declination: float, hour_angle: float) -> np.ndarray:
        """(F,) float32 S_i at the sun's declination and hour angle (degrees), bilinear over the nodes
        (a node below the horizon counts 0)."""
        k = float(np.clip(np.interp(declination, self.declinations, np.arange(len(self.declinations))), 0,
                          len(self.declinations) - 1 - 1e-9))
        step = 360.0 / len(self.hour_angles)
        m = ((hour_angle + 180.0) % 360.0) / step
        k0, m0 = int(k), int(m) % len(self.hour_angles)
        out = np.zeros(self.hits.shape[1], np.float32)
        for dk, wk in ((0, 1.0 - (k - k0)), (1, k - k0)):
            for dm, wm in ((0, 1.0 - (m - int(m))), (1, m - int(m))):
                row = self.node_row[min(k0 + dk, len(self.declinations) - 1), (m0 + dm) % len(self.hour_angles)]
                if row >= 0 and wk * wm > 0:
                    out += np.float32(wk * wm / sun_levels(self.samples)) * self.hits[row]
        return out


@dataclass(frozen=True)
class Receivers:
    """What relighting needs of the faces: their sky visibility factors, frame and normals."""

    visibility: np.ndarray
    """(N, F) float32 V_ij, patch-major (the layout ``relight_daylight`` streams fastest)."""
    patches: SkyPatches
    to_world: np.ndarray
    """(3, 3) float64 layout ENU -> scene frame."""
    face_normals: np.ndarray
    """(F, 3) float32 unit."""


@dataclass(frozen=True)
class IndirectCoefficients:
    """The interreflected light's coefficients (``InterreflectionProduct`` has these fields too)."""

    sky_indirect: np.ndarray
    """(K, F, N) float32 D_ij; K = 1 (grey) or 3 (R, G, B)."""
    ground_direct: np.ndarray
    """(F,) float32 pi g_i."""
    ground_indirect: np.ndarray
    """(K, F) float32."""
    ground_reflectance: float

    def channel(self, c: int) -> int:
        """Index into the K axis for colour channel c."""
        return min(c, len(self.sky_indirect) - 1)


class Relighter:
    """Interactive relighting (Bosch, Besuievsky & Martin, Sec. 5, Eq. 1) of faces for any time at one site,
    no rays: the sky by one BLAS product over V (patch-major float32), the sun from a ``SunTable``, and with
    ``indirect`` coefficients the bounced light in the same product (V and D stacked patch-major, the
    interreflection module's E_i = sum_j V_ij w_j + sum_j D_ij (w_j + s_j) + (pi g_i + D^g_i) L_g + E_sun).

    ``at(time)`` returns (F, 3) float32 radiance (W/(m^2 sr), with ``albedo``) or irradiance (W/m^2)."""

    def __init__(self, receivers: Receivers, table: SunTable, *, latitude: float, longitude: float,
                 timezone: float, north: float = 0.0, albedo: np.ndarray | None = None,
                 indirect: IndirectCoefficients | None = None):
        """``table`` from the sun's visibility at the same latitude and north; ``indirect``: any object with
        ``IndirectCoefficients``' fields."""
        self.receivers, self.table, self.albedo = receivers, table, albedo
        self.interreflection = indirect
        self.site = (latitude, longitude, timezone)
        self.turn = enu_to_world("Z", north)
        self.visibility = receivers.visibility
        if indirect is not None:  # [V; D_1 ..; D_K], (N (1 + K), F): one pass over memory per time
            self.visibility = np.concatenate([self.visibility] + [np.ascontiguousarray(d.T)
                                                                  for d in indirect.sky_indirect])

    def at(self, time: np.datetime64, *, sky: str = "preetham", turbidity: float = 3.0,
           uniform_radiance: float = 1000.0, direct_normal: float = 600.0, diffuse_horizontal: float = 150.0,
           sun: bool = True, efficacy: str = "perez") -> np.ndarray:
        """Eq. 1 at local standard ``time`` with the sky model's parameters (as ``compute_daylight``)."""
        times = np.atleast_1d(np.datetime64(time))
        position = sun_position(times, *self.site)
        sun_site = position.enu()[0]
        sun_layout = self.turn @ sun_site
        day = int(day_of_year(times)[0])
        patches = self.receivers.patches
        weights, e_normal = sky_and_sun(patches, sky, sun_site, sun_layout, day, sun=sun, turbidity=turbidity,
                                        uniform_radiance=uniform_radiance, direct_normal=direct_normal,
                                        diffuse_horizontal=diffuse_horizontal, efficacy=efficacy)
        direct = None
        if e_normal is not None:
            sun_world = (self.receivers.to_world @ sun_layout).astype(np.float32)
            seen = self.table.visibility(float(position.declination[0]), float(position.hour_angle[0]))
            cos_i = np.maximum(self.receivers.face_normals @ sun_world, 0.0) * seen
            direct = cos_i[:, None] * e_normal.astype(np.float32)[None, :]
        inter = self.interreflection
        if inter is None:
            return relight_daylight(self.visibility, weights, albedo=self.albedo, sun=direct, patch_major=True)
        bounced = weights if e_normal is None else weights + sun_patch_weights(patches, sun_layout, e_normal)
        stacked = [weights]
        for k in range(len(inter.sky_indirect)):  # one block per set of coefficients (grey: all three channels)
            block = bounced.copy() if len(inter.sky_indirect) == 1 else np.zeros_like(bounced)
            if len(inter.sky_indirect) > 1:
                block[:, k] = bounced[:, k]
            stacked.append(block)
        out = relight_daylight(self.visibility, np.concatenate(stacked), sun=direct, patch_major=True)
        ground = ground_radiance(patches, weights, sun_layout, e_normal, inter.ground_reflectance)
        for c in range(3):
            out[:, c] += (inter.ground_direct + inter.ground_indirect[inter.channel(c)]) * ground[c]
        if self.albedo is not None:
            out *= np.asarray(self.albedo, np.float32) * np.float32(1.0 / np.pi)
        return out


