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
from ...kernels.daylight_relight import (MAX_DECLINATION, Receivers, Relighter, SunTable, ground_radiance,
                                        relight_daylight, sky_and_sun, sun_patch_weights)
from ...kernels.lights import LUMINANCE
from ...kernels.sky import enu_to_world
from ...kernels.solar import SunPosition, day_of_year, horizontal_position, parse_times, sun_position
from .glazing import scene_glazing
from .sun_visibility import SunFaces, sun_bin_hits
from .texel_receivers import receiver_sets, texel_lightmaps

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

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
        weights, e_normal = sky_and_sun(product.patches, sky, sun_site, sun_layout, day, sun=sun, turbidity=turbidity,
                                        uniform_radiance=uniform_radiance, direct_normal=direct_normal,
                                        diffuse_horizontal=diffuse_horizontal, efficacy=efficacy)
        direct = None
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


class DaylightRelighter(Relighter):
    """``Relighter`` (kernels/daylight_relight.py) of the sky visibility product's faces, with the
    interreflection product's coefficients when given."""

    def __init__(self, product: SkyVisibilityProduct, table: SunTable, *, latitude: float, longitude: float,
                 timezone: float, north: float = 0.0, albedo: np.ndarray | None = None,
                 interreflection: InterreflectionProduct | None = None):
        """``table`` from ``sun_table`` at the same latitude and north."""
        self.product = product
        super().__init__(Receivers(product.visibility_patch_major(), product.patches, product.to_world,
                                   product.face_normals), table, latitude=latitude, longitude=longitude,
                         timezone=timezone, north=north, albedo=albedo, indirect=interreflection)


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


@dataclass(frozen=True)
class SiteParams(Params):
    """Where the stage stands: the parameters of the processors that place the sun."""

    latitude: float = param(41.98, "degrees north", low=-90.0, high=90.0)
    longitude: float = param(2.82, "degrees east", low=-180.0, high=180.0)
    timezone: float = param(1.0, "hours east of UTC of the local standard time", low=-12.0, high=14.0)
    north: float = param(0.0, "angle of north from the stage's default north (degrees, counter-clockwise)",
                         low=-360.0, high=360.0)


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
    class Params(SiteParams):
        times: str = param("2026-06-21T12:00", "ISO 8601 local time, list, or start/end/step "
                           "(e.g. 2026-06-21T06:00/18:00/PT30M)")
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
