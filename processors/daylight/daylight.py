"""Daylight relighting from precomputed sky visibility (Bosch, Besuievsky & Martin, Sec. 5).

For each requested local time the sun position comes from ``kernels/solar.py``
(NOAA algorithm), the sky radiance per patch from a sky model
(``kernels/sky.py``: Preetham 1999 with turbidity, the Perez 1993
all-weather model driven by direct-normal and diffuse-horizontal irradiance as
in Radiance's gendaylit, CIE overcast, or
uniform), averaged over a 3 x 3 grid inside each patch. The outgoing radiance
of refined face i is the paper's Eq. 1 with a Lambertian BRDF rho_i / pi::

    L_i = rho_i / pi * ( sum_j Lhat_j V_ij dw_j  +  E_sun max(0, n_i . s) S_i )

with V_ij and the refined mesh from the ``sky_visibility`` product, E_sun the
sun's direct normal irradiance (Preetham's transmittances) and S_i the sun's
visibility: the share of ``sun_samples`` rays from random points of the face
toward random points of the 0.53 degree solar disk that escape. The sky part
is one (F, N) x (N, 3) float32 matrix product (``relight_daylight``), no ray casts;
only the sun term casts rays. Units: visible-equivalent W/(m^2 sr) (luminance
in cd/m^2 divided by 179 lm/W, as Radiance); ``bake:daylight`` times 179 is
luminance, and rho_i can be divided out to get irradiance. The Perez sky is in
the solar W/(m^2 sr) of its direct-normal and diffuse-horizontal inputs.

Times: ``times`` is an ISO 8601 instant (``2026-06-21T12:00``), a
comma-separated list, or an interval ``start/end/step``
(``2026-06-21T06:00/18:00/PT30M``, end inclusive), in local standard time
``timezone`` hours east of UTC. One time writes default values; several write
time samples at time codes 0, 1, 2, ... (sample k at time code k), so
scrubbing frames 0..N-1 in usdview plays the day.

USD written (bake layer), on each prim refined by ``sky_visibility``:

==================== ========= ============= ================================================
property             type      interpolation meaning
==================== ========= ============= ================================================
primvars:bake:daylight color3f[] uniform     L_i per refined face (time-sampled for several times)
primvars:displayColor  color3f[] uniform     ``display_color``: L_i * k / (1 + L_i * k), one k
                                             for all times (``exposure``, or 1 / the 90th
                                             percentile of the luminance)
==================== ========= ============= ================================================

Parameters: ``usdbake list daylight`` or docs/daylight.md, both generated from ``Params`` below.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, replace

import numpy as np
import warp as wp

from ...core import Context, ParamError, Params, Primvar, Processor, Result, param
from .products import DaylightProduct, InterreflectionProduct, SkyVisibilityProduct
from ...core.scene import Scene
from ...kernels.lights import LUMINANCE
from ...kernels.luminous_efficacy import perez_efficacy
from ...kernels.sky import LUMINOUS_EFFICACY, enu_to_world, patch_radiance, sun_normal_irradiance
from ...kernels.solar import SunPosition, day_of_year, horizontal_position, parse_times, sun_position
from .glazing import scene_glazing
from .interreflection import ground_radiance, sun_patch_weights
from .sun_visibility import SunFaces, sun_bin_hits, sun_levels
from .texel_receivers import receiver_sets, texel_lightmaps

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

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


def sky_weights(product, model: str, sun_layout: np.ndarray, *, turbidity: float, radiance: float,
                direct_normal: float = 0.0, diffuse_horizontal: float = 0.0, day_of_year: int = 172,
                efficacy: str = "perez") -> np.ndarray:
    """(N, 3) Lhat_j * dw_j for the product's patches; ``sun_layout`` is the sun in the layout's ENU frame.
    The Perez sky (solar W/m^2 from the weather's DHI) is turned into visible-equivalent watts by
    ``visible_factors``; the other models are visible already."""
    values = patch_radiance(product.patches, model, sun_layout, turbidity=turbidity, radiance=radiance,
                            direct_normal=direct_normal, diffuse_horizontal=diffuse_horizontal,
                            day_of_year=day_of_year)
    if model == "perez":
        values = values * visible_factors(efficacy, direct_normal, diffuse_horizontal, sun_layout, day_of_year)[1]
    return (values * product.patches.patch_solid_angles[:, None]).astype(np.float32)


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


def add_interreflection(irradiance: np.ndarray, interreflection: InterreflectionProduct | None, patches,
                        weights: np.ndarray, sun_layout: np.ndarray, e_normal: np.ndarray | None) -> np.ndarray:
    """``irradiance`` (F, 3) plus the sky's and the sun's light after 1..k bounces and the ground outside the
    model (``interreflection`` module: sum_j D_ij (w_j + s_j) + (pi g_i + D^g_i) L_g); unchanged without a
    product."""
    if interreflection is None:
        return irradiance
    bounced = weights if e_normal is None else weights + sun_patch_weights(patches, sun_layout, e_normal)
    ground = ground_radiance(patches, weights, sun_layout, e_normal, interreflection.ground_reflectance)
    for c in range(3):
        k = interreflection.channel(c)
        irradiance[:, c] += interreflection.sky_indirect[k] @ bounced[:, c]
        irradiance[:, c] += (interreflection.ground_direct + interreflection.ground_indirect[k]) * ground[c]
    return irradiance


def compute_daylight(tracer, scene: Scene, product, times: np.ndarray, *, latitude: float, longitude: float,
                     timezone: float, north: float = 0.0, sky: str = "preetham", turbidity: float = 3.0,
                     uniform_radiance: float = 1000.0, direct_normal: float = 600.0,
                     diffuse_horizontal: float = 150.0, sun: bool = True, sun_samples: int = 4, seed: int = 0,
                     interreflection: InterreflectionProduct | None = None, efficacy: str = "perez",
                     progress=lambda f: None) -> tuple[DaylightProduct, dict]:
    """Radiance of every refined face at every time (see the module docstring).

    Bosch, Besuievsky & Martin, Sec. 5 and 5.1: for each time, the sun position
    (kernels/solar.py), the sky patch radiances Lhat_j (W/(m^2 sr)), the sun's
    direct normal irradiance (W/m^2) and visibility S_i, then Eq. 1 reusing the
    precomputed V_ij (``relight_daylight``), plus the interreflected light and the ground of
    ``interreflection`` (``add_interreflection``). Returns (T, F, 3) float32 irradiance (W/m^2) and
    radiance (W/(m^2 sr)) in the product, and timing figures.
    """
    position = sun_position(times, latitude, longitude, timezone)
    turn = enu_to_world("Z", north)  # rotation about up: site ENU -> layout ENU
    faces = SunFaces(tracer, product.face_points[product.face_vertices], product.face_normals,
                     scene_glazing(scene, tracer)) if sun else None
    albedo = scene.tri_albedo[product.face_source]
    visibility = product.visibility_patch_major()
    out = np.zeros((len(times), product.num_faces, 3), np.float32)
    irradiance = np.zeros_like(out)
    relight_seconds = []
    sun_rays = 0
    for k, sun_site in enumerate(position.enu()):
        sun_layout = turn @ sun_site
        day = int(day_of_year(times[k])[0])
        weights = sky_weights(product, sky, sun_layout, turbidity=turbidity, radiance=uniform_radiance,
                              direct_normal=direct_normal, diffuse_horizontal=diffuse_horizontal, day_of_year=day,
                              efficacy=efficacy)
        direct = None
        e_normal = sun_normal(sky, sun_site, turbidity=turbidity, direct_normal=direct_normal, day_of_year=day,
                              diffuse_horizontal=diffuse_horizontal, efficacy=efficacy) if sun else None
        if e_normal is not None:
            sun_world = product.to_world @ sun_layout
            cos_i = np.maximum(product.face_normals @ sun_world.astype(np.float32), 0.0)
            seen = faces.visibility(sun_world, samples=sun_samples, seed=seed + k)
            sun_rays += int((cos_i > 0).sum()) * sun_samples
            direct = (cos_i * seen)[:, None] * e_normal[None, :].astype(np.float32)
        started = _time.perf_counter()
        irradiance[k] = add_interreflection(relight_daylight(visibility, weights, sun=direct, patch_major=True),
                                            interreflection, product.patches, weights, sun_layout, e_normal)
        out[k] = irradiance[k] * albedo * np.float32(1.0 / np.pi)
        relight_seconds.append(_time.perf_counter() - started)
        progress((k + 1) / len(times))
    stats = {"times": float(len(times)), "faces": float(product.num_faces),
             "relight_ms": 1000.0 * float(np.median(relight_seconds)) if relight_seconds else 0.0,
             "sun_rays": float(sun_rays)}
    return DaylightProduct(times, out, position.zenith, position.azimuth, irradiance), stats


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


def sun_table(tracer, product, *, latitude: float, north: float = 0.0,
              declination_step: float = 4.0, hour_step: float = 3.75, samples: int = 2, seed: int = 0,
              glazing=None, progress=lambda f: None) -> SunTable:
    """Shadow rays toward the sun at every node of a declination x hour-angle grid (``declination_step``
    and ``hour_step`` degrees at most; 3.75 degrees of hour angle = 15 minutes) that is above the horizon at
    ``latitude``, ``samples`` per face: the precompute of ``DaylightRelighter``. The sun's path depends on the
    latitude alone; the longitude and time zone only turn clock time into hour angle (``DaylightRelighter.at``)."""
    count = int(np.ceil(2 * MAX_DECLINATION / declination_step)) + 1
    declinations = np.linspace(-MAX_DECLINATION, MAX_DECLINATION, count)
    hours = int(np.ceil(360.0 / hour_step))
    hour_angles = -180.0 + np.arange(hours) * (360.0 / hours)
    dec, ha = np.meshgrid(declinations, hour_angles, indexing="ij")
    zenith, azimuth = horizontal_position(latitude, dec.ravel(), ha.ravel())
    suns = SunPosition(zenith, azimuth, dec.ravel(), np.zeros_like(zenith), ha.ravel()).enu()
    suns = suns @ enu_to_world("Z", north).T  # site ENU -> layout ENU
    up = suns[:, 2] > 0.0
    node_row = np.full(len(suns), -1, np.int64)
    node_row[up] = np.arange(int(up.sum()))
    corners = product.face_points[product.face_vertices].astype(np.float32)
    hits = sun_bin_hits(tracer, corners, product.face_normals, suns[up] @ product.to_world.T, samples=samples,
                        glazing=glazing,
                        seed=seed, progress=progress)
    return SunTable(declinations, hour_angles, node_row.reshape(dec.shape), hits, samples)


class DaylightRelighter:
    """Interactive relighting (Bosch, Besuievsky & Martin, Sec. 5, Eq. 1) of the refined faces for any time at
    one site, no rays: the sky by one BLAS product over V (patch-major float32), the sun from a ``SunTable``,
    and with an ``interreflection`` product the bounced light in the same product (V and the indirect
    coefficients D stacked patch-major, ``add_interreflection``'s terms).

    ``at(time)`` returns (F, 3) float32 radiance (W/(m^2 sr), with ``albedo``) or irradiance (W/m^2)."""

    def __init__(self, product, table: SunTable, *, latitude: float, longitude: float, timezone: float,
                 north: float = 0.0, albedo: np.ndarray | None = None,
                 interreflection: InterreflectionProduct | None = None):
        """``table`` from ``sun_table`` at the same latitude and north."""
        self.product, self.table, self.albedo = product, table, albedo
        self.interreflection = interreflection
        self.site = (latitude, longitude, timezone)
        self.turn = enu_to_world("Z", north)
        self.visibility = product.visibility_patch_major()
        if interreflection is not None:  # [V; D_1 ..; D_K], (N (1 + K), F): one pass over memory per time
            self.visibility = np.concatenate([self.visibility] + [np.ascontiguousarray(d.T)
                                                                  for d in interreflection.sky_indirect])

    def at(self, time: np.datetime64, *, sky: str = "preetham", turbidity: float = 3.0,
           uniform_radiance: float = 1000.0, direct_normal: float = 600.0, diffuse_horizontal: float = 150.0,
           sun: bool = True, efficacy: str = "perez") -> np.ndarray:
        """Eq. 1 at local standard ``time`` with the sky model's parameters (as ``compute_daylight``)."""
        times = np.atleast_1d(np.datetime64(time))
        position = sun_position(times, *self.site)
        sun_site = position.enu()[0]
        sun_layout = self.turn @ sun_site
        day = int(day_of_year(times)[0])
        patches = self.product.patches
        weights = sky_weights(self.product, sky, sun_layout, turbidity=turbidity, radiance=uniform_radiance,
                              direct_normal=direct_normal, diffuse_horizontal=diffuse_horizontal, day_of_year=day,
                              efficacy=efficacy)
        direct = None
        e_normal = sun_normal(sky, sun_site, turbidity=turbidity, direct_normal=direct_normal, day_of_year=day,
                              diffuse_horizontal=diffuse_horizontal, efficacy=efficacy) if sun else None
        if e_normal is not None:
            sun_world = (self.product.to_world @ sun_layout).astype(np.float32)
            seen = self.table.visibility(float(position.declination[0]), float(position.hour_angle[0]))
            cos_i = np.maximum(self.product.face_normals @ sun_world, 0.0) * seen
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


def _no_faces(times: np.ndarray, p) -> DaylightProduct:
    """The product of a run whose faces are not written (the texture target alone): no face rows."""
    empty = np.zeros((len(times), 0, 3), np.float32)
    position = sun_position(times, p.latitude, p.longitude, p.timezone)
    return DaylightProduct(times, empty, position.zenith, position.azimuth, empty)


def reinhard_tone_map(radiance: np.ndarray, exposure: float = 0.0) -> tuple[np.ndarray, float]:
    """Reinhard x / (1 + x) of radiance * k; k = exposure, or 1 / the 90th percentile of the luminance."""
    k = float(exposure)
    if k <= 0:
        luminance = radiance @ LUMINANCE.astype(np.float32)
        positive = luminance[luminance > 0]
        k = 1.0 / float(np.percentile(positive, 90)) if len(positive) else 1.0
    x = radiance * np.float32(k)
    return (x / (1.0 + x)).astype(np.float32), k


class Daylight(Processor):
    name = "daylight"
    version = "2"
    summary = "Sky (Preetham/Perez/CIE overcast/uniform) + sun relighting of the sky_visibility mesh, time-sampled."
    facets = ("geometry", "materials")
    writes = ("primvars:bake:daylight", "primvars:bake:daylightIrradiance", "primvars:displayColor",
              "bake:lightmap:daylightIrradiance:")
    requires = (SkyVisibilityProduct, InterreflectionProduct)
    provides = (DaylightProduct,)

    @dataclass(frozen=True)
    class Params(Params):
        times: str = param("2026-06-21T12:00", "ISO 8601 local time, list, or start/end/step "
                           "(e.g. 2026-06-21T06:00/18:00/PT30M)")
        latitude: float = param(41.98, "degrees north", low=-90.0, high=90.0)
        longitude: float = param(2.82, "degrees east", low=-180.0, high=180.0)
        timezone: float = param(1.0, "hours east of UTC of the local standard time", low=-12.0, high=14.0)
        north: float = param(0.0, "angle of north from the stage's default north (degrees, counter-clockwise)",
                             low=-360.0, high=360.0)
        sky: str = param("preetham", "sky model: preetham (turbidity), perez (all-weather, from direct_normal and "
                         "diffuse_horizontal), overcast (CIE), uniform", choices=("preetham", "perez", "overcast",
                                                                                   "uniform"))
        turbidity: float = param(3.0, "Preetham turbidity (2 clear .. 10 hazy)", low=1.7, high=10.0)
        uniform_radiance: float = param(1000.0, "radiance of the uniform sky, W/(m^2 sr)", low=0.0)
        direct_normal: float = param(600.0, "Perez sky: direct-normal irradiance, W/m^2 (e.g. from a weather file)",
                                     low=0.0)
        diffuse_horizontal: float = param(150.0, "Perez sky: diffuse-horizontal irradiance, W/m^2", low=0.0)
        sun: bool = param(True, "add the direct sun (Preetham and Perez skies)")
        sun_samples: int = param(4, "rays per face toward the solar disk", low=1, high=4096)
        efficacy: str = param("perez", "Perez sky: solar W/m^2 to light by the Perez et al. 1990 luminous efficacy "
                              "(perez, as gendaymtx -O0) or by Radiance's 179 lm/W (179, as gendaymtx -O1)",
                              choices=("perez", "179"))
        display_color: bool = param(False, "also write a tone-mapped primvars:displayColor")
        exposure: float = param(0.0, "tone-mapping scale for displayColor (0: automatic)", low=0.0)
        seed: int = param(0, "random seed of the sun rays", low=0)

        def __post_init__(self) -> None:
            super().__post_init__()
            try:
                parse_times(self.times)
            except ValueError as error:
                raise ParamError(f"times={self.times!r}: {error}") from None

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        product = ctx.products[SkyVisibilityProduct]
        try:
            times = parse_times(p.times)
        except ValueError as error:
            raise ParamError(f"times={p.times!r}: {error}") from None
        inter = ctx.products[InterreflectionProduct]
        receivers = receiver_sets(product, inter)
        computed = []
        for index, (faces, bounced) in enumerate(receivers):  # the refined faces, the lightmap texels, or both
            computed.append(compute_daylight(
                ctx.tracer, scene, faces, times, latitude=p.latitude, longitude=p.longitude, timezone=p.timezone,
                north=p.north, sky=p.sky, turbidity=p.turbidity, uniform_radiance=p.uniform_radiance,
                direct_normal=p.direct_normal, diffuse_horizontal=p.diffuse_horizontal, sun=p.sun,
                sun_samples=p.sun_samples, seed=p.seed, interreflection=bounced, efficacy=p.efficacy,
                progress=lambda f, index=index: ctx.progress((index + f) / len(receivers))))
        texel_light, texel_stats = computed.pop() if product.texels is not None else (None, {})
        daylight, stats = computed[0] if computed else (_no_faces(times, p), {})
        if texel_light is not None:
            stats = dict(stats, sun_rays=stats.get("sun_rays", 0.0) + texel_stats["sun_rays"])
        daylight = replace(daylight, texels=texel_light)
        result = Result(products={DaylightProduct: daylight}, stats=stats)
        if texel_light is not None:
            result.stats["texels"] = float(product.texels.count)
            for index in range(len(times)):
                result.outputs += texel_lightmaps(scene, product.texels, "daylightIrradiance",
                                                  texel_light.face_irradiance[index], units="W/m^2",
                                                  name=f"daylightIrradiance_{index}",
                                                  time=float(index) if len(times) > 1 else None)
        sampled = len(times) > 1
        mapped, k = (reinhard_tone_map(daylight.face_radiance.reshape(-1, 3), p.exposure) if p.display_color
                     else (None, 0))
        if mapped is not None:
            mapped = mapped.reshape(daylight.face_radiance.shape)
        for prim in product.prims if product.mesh_written else ():
            path = scene.prim_paths[prim]
            faces = np.flatnonzero(product.face_prim == prim)
            for index in range(len(times)):
                code = float(index) if sampled else None
                result.outputs.append(Primvar(path, "bake:daylight", daylight.face_radiance[index, faces],
                                              "color3f", "uniform", time=code))
                result.outputs.append(Primvar(path, "bake:daylightIrradiance", daylight.face_irradiance[index, faces],
                                              "color3f", "uniform", time=code))
                if mapped is not None:
                    result.outputs.append(Primvar(path, "displayColor", mapped[index, faces], "color3f", "uniform",
                                                  time=code))
        bounces = ctx.products[InterreflectionProduct].bounces
        result.messages.append(f"interreflected light: {bounces} bounce{'s' * (bounces != 1)}, ground outside the "
                               f"model of reflectance {ctx.products[InterreflectionProduct].ground_reflectance:g}")
        if sampled:
            result.messages.append(f"time codes 0..{len(times) - 1} are {times[0]} .. {times[-1]} (local time)")
        if p.display_color:
            result.stats["display_exposure"] = k
        return result
