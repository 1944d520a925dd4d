"""Annual, climate-based daylight from a weather file by daylight coefficients.

The per-face sky visibility factors V_ij of ``sky_visibility`` (Bosch, Besuievsky & Martin, Sec. 4.1)
are daylight coefficients: with Lhat_j(h) the radiance of sky patch j at hour h (the Perez
all-weather model driven by the hour's direct-normal and diffuse-horizontal irradiance of a
typical-year weather file, ``processors/daylight/sky_matrix.py``, as Radiance's ``gendaymtx``), the sky
illuminance of face i at every hour of the year is one matrix product (their Eq. 1 without the
reflectance, times the luminous efficacy K = 179 lm/W of Radiance's visible-equivalent units)::

    E_sky(i, h) = K sum_j V_ij Lhat_j(h) dw_j

The direct sun adds E_sun(i, h) = K DNI(h) max(0, n_i . s_h) S_i(b(h)), where S_i(b) is the share
of the solar disk face i sees (shadow rays, ``processors/daylight/sun_visibility.py``) for the sun bin b(h):
the hour's sun direction snapped to the nearest patch of a fine Reinhart layout (MF:``sun_bins``),
so a year's ~4400 daylight hours need only the few hundred bins the sun path crosses. The
cosine uses the hour's exact sun direction.

Metrics, per face (occupied hours: ``occupied``, local standard time, every day):

- daylight factor DF: 100 E / E_h under the CIE overcast sky, sky only, E_h the illuminance of an
  unobstructed horizontal face;
- daylight autonomy DA: share of occupied hours with E_sky + E_sun >= ``threshold`` lux;
- useful daylight illuminance UDI: shares of occupied hours below ``udi_low``, between, and above
  ``udi_high``;
- annual sunlight hours: occupied hours with E_sun >= ``ase_lux``;
- mean occupied illuminance.

Over the sensor faces (``sensors``: faces facing up, the work plane; or all), area-weighted:
spatial daylight autonomy sDA (share with DA >= ``sda_share``) and annual sunlight exposure ASE
(share with at least ``ase_hours`` sunlight hours), as IES LM-83.

USD written (bake layer):

================================== ========== ============= ==========================================
property                           type       interpolation meaning
================================== ========== ============= ==========================================
primvars:bake:daylightFactor       float[]    uniform       DF, percent
primvars:bake:daylightAutonomy     float[]    uniform       DA, share of occupied hours
primvars:bake:usefulDaylight       float[]    uniform, x3   UDI shares: below, within, above the band
primvars:bake:annualSunHours       float[]    uniform       occupied hours with E_sun >= ase_lux
primvars:bake:meanIlluminance      float[]    uniform       lux, over occupied hours
/usdbake/AnnualDaylight            Scope                    sDA, ASE, site, weather, report file
================================== ========== ============= ==========================================

Parameters: ``usdbake list annual_daylight``, generated from ``Params`` below.
"""

from __future__ import annotations

import json
import time as _time
from dataclasses import dataclass, replace

import numpy as np

from ...core import Attribute, Context, File, ParamError, Params, Prim, Primvar, Processor, Result, param
from .products import AnnualDaylightProduct, InterreflectionProduct, SkyVisibilityProduct
from ...core.scene import Scene
from ...formats.weather import Weather, check_site, read_weather
from ...kernels.lights import LUMINANCE
from ...kernels.luminous_efficacy import perez_efficacy
from ...kernels.sky import LUMINOUS_EFFICACY, enu_to_world, overcast_radiance, patch_samples
from .glazing import scene_glazing
from .sky_matrix import perez_sky_matrix
from ...kernels.solar import day_of_year, sun_position
from ...kernels.daylight_relight import SUN_PATCHES, horizontal_cosines, sun_levels
from .sun_visibility import sun_bin_hits, sun_bins
from .texel_receivers import receiver_sets, texel_lightmaps

REPORT_PRIM = "/usdbake/AnnualDaylight"
REPORT_FILE = "annual_daylight.json"
FACE_CHUNK = 2048
"""Faces per chunk of the hourly product: a (2048, 8760) float32 block is 72 MB."""
SENSOR_COS = 0.9
"""A face is a work-plane sensor (``sensors = up``) when its normal is within ~26 degrees of up."""


@dataclass(frozen=True)
class AnnualMetrics:
    """Per-face metrics, in the product's face order."""

    daylight_factor: np.ndarray
    autonomy: np.ndarray
    useful: np.ndarray
    """(F, 3) shares of occupied hours below, within and above the UDI band."""
    sun_hours: np.ndarray
    mean_illuminance: np.ndarray


def overcast_factors(product: SkyVisibilityProduct, bounced: "BouncedLight | None" = None) -> np.ndarray:
    """(F,) daylight factor in percent: E under the CIE overcast sky (with the interreflected light and the
    ground outside the model of ``bounced``) over E of an open horizontal face (sky only)."""
    patches = product.patches
    samples = patch_samples(patches, 3)
    radiance = overcast_radiance(samples, np.array([0.0, 0.0, 1.0]))[..., 0]  # its shape is the sun's altitude's
    weights = radiance.mean(axis=1) * patches.patch_solid_angles
    horizontal = float((radiance * np.maximum(samples[..., 2], 0.0)).mean(axis=1) @ patches.patch_solid_angles)
    illuminance = product.visibility_float() @ weights
    if bounced is not None:
        illuminance = illuminance + bounced.sky @ weights + bounced.ground * (bounced.reflectance * horizontal / np.pi)
    return (100.0 * illuminance / horizontal).astype(np.float32)


@dataclass(frozen=True)
class BouncedLight:
    """The interreflection product reduced to luminance, for a grey sky (as gendaymtx's, and every hour's)."""

    sky: np.ndarray
    """(F, N) float32 sum_c Y_c D_c: luminance of the indirect daylight coefficients."""
    ground: np.ndarray
    """(F,) float32 pi g_i + sum_c Y_c D^g_c: irradiance per unit radiance of the ground outside the model."""
    reflectance: float
    bounces: int

    @classmethod
    def of(cls, product: InterreflectionProduct) -> "BouncedLight":
        weights = [float(LUMINANCE[c]) for c in range(3)]
        sky = sum(weights[c] * product.sky_indirect[product.channel(c)] for c in range(3))
        ground = product.ground_direct + sum(weights[c] * product.ground_indirect[product.channel(c)]
                                             for c in range(3))
        return cls(np.asarray(sky, np.float32), np.asarray(ground, np.float32), product.ground_reflectance,
                   product.bounces)


def luminous_efficacies(weather: Weather, zenith: np.ndarray, days: np.ndarray, efficacy: str
                        ) -> tuple[np.ndarray, np.ndarray]:
    """(H,) lm/W of the beam and of the diffuse sky for every hour: ``perez`` (Perez et al. 1990, gendaymtx -O0
    with its default dew point, as from a .wea file), ``weather`` (the file's own illuminance columns over its
    irradiance) or ``179`` (Radiance's visible-equivalent factor, gendaymtx -O1 x 179)."""
    hours = len(weather)
    if efficacy == "179":
        return np.full(hours, LUMINOUS_EFFICACY), np.full(hours, LUMINOUS_EFFICACY)
    if efficacy == "weather":
        return (_ratio(weather.direct_normal_illuminance, weather.direct_normal),
                _ratio(weather.diffuse_horizontal_illuminance, weather.diffuse_horizontal))
    return perez_efficacy(weather.direct_normal, weather.diffuse_horizontal, zenith, days)


def _ratio(light: np.ndarray, irradiance: np.ndarray) -> np.ndarray:
    light = np.nan_to_num(np.asarray(light, np.float64), nan=0.0)
    return np.where(irradiance > 0, light / np.maximum(irradiance, 1e-300), 0.0)


def sun_patch_matrix(patches, suns: np.ndarray, direct_normal: np.ndarray) -> np.ndarray:
    """(N, H) float32 each hour's direct normal illuminance spread over the ``SUN_PATCHES`` patches nearest the
    sun, weights 1 / (1.002 - cos) (``interreflection.sun_patch_weights`` for every hour at once)."""
    out = np.zeros((len(patches), len(suns)), np.float32)
    up = np.flatnonzero((suns[:, 2] > 0) & (direct_normal > 0))
    if len(up) == 0:
        return out
    cosines = suns[up] @ patches.patch_directions.T  # (H', N)
    nearest = np.argpartition(-cosines, SUN_PATCHES - 1, axis=1)[:, :SUN_PATCHES]
    weights = 1.0 / (1.002 - np.take_along_axis(cosines, nearest, axis=1))
    weights *= (direct_normal[up] / weights.sum(axis=1))[:, None]
    out[nearest, up[:, None]] = weights
    return out


def compute_annual_daylight(tracer, scene: Scene, product: SkyVisibilityProduct, weather: Weather, *,
                            north: float = 0.0, occupied: tuple[float, float] = (8.0, 18.0),
                            threshold: float = 300.0, udi: tuple[float, float] = (100.0, 3000.0),
                            ase_lux: float = 1000.0, sun: bool = True, sun_samples: int = 2, sun_subdivision: int = 4,
                            seed: int = 0, interreflection: InterreflectionProduct | None = None,
                            efficacy: str = "perez", progress=lambda f: None) -> tuple[AnnualMetrics, dict]:
    """Hourly illuminance of every face over the weather file's year, reduced to the module's metrics."""
    started = _time.perf_counter()
    position = sun_position(weather.times, weather.latitude, weather.longitude, weather.timezone)
    suns = position.enu() @ enu_to_world("Z", north).T  # site ENU -> layout ENU (north turned about up)
    days = day_of_year(weather.times)
    sky = perez_sky_matrix(product.patches, suns, weather.direct_normal, weather.diffuse_horizontal, days)
    beam, diffuse = luminous_efficacies(weather, position.zenith, days, efficacy)
    weights = sky * product.patches.patch_solid_angles[:, None].astype(np.float32) * diffuse[None, :].astype(np.float32)
    sun_light = np.where(suns[:, 2] > 0.0, weather.direct_normal * beam, 0.0)  # direct normal illuminance, lux
    bounced = BouncedLight.of(interreflection) if interreflection is not None else None
    sky_seconds = _time.perf_counter() - started
    progress(0.1)

    up = (suns[:, 2] > 0.0) & (weather.direct_normal > 0.0) & sun
    bins, bin_directions = sun_bins(suns, up, sun_subdivision)
    corners = product.face_points[product.face_vertices].astype(np.float32)
    normals = product.face_normals
    rays_before = tracer.rays_cast
    glazing = scene_glazing(scene, tracer)
    hits = sun_bin_hits(tracer, corners, normals, bin_directions @ product.to_world.T, samples=sun_samples,
                        glazing=glazing,
                        seed=seed, progress=lambda f: progress(0.1 + 0.6 * f))
    sun_seconds = _time.perf_counter() - started - sky_seconds

    hour = (weather.times - weather.times.astype("datetime64[D]")).astype(np.float64) / 60.0
    occupied_hours = (hour >= occupied[0]) & (hour < occupied[1])
    sun_world = (suns @ product.to_world.T).astype(np.float32)
    direct = np.where(up, sun_light, 0.0).astype(np.float32)
    count = max(1, int(occupied_hours.sum()))
    autonomy = np.zeros(product.num_faces, np.float32)
    useful = np.zeros((product.num_faces, 3), np.float32)
    sun_hours = np.zeros(product.num_faces, np.float32)
    mean = np.zeros(product.num_faces, np.float32)
    hours = np.flatnonzero(occupied_hours)
    weights_occupied = np.ascontiguousarray(weights[:, hours])
    if bounced is not None:  # [V | D] @ [sky; sky + sun in patches], and the ground outside the model
        sun_in_patches = sun_patch_matrix(product.patches, suns[hours], sun_light[hours] * up[hours] if sun
                                          else np.zeros(len(hours)))
        weights_occupied = np.concatenate([weights_occupied, weights_occupied + sun_in_patches])
        horizontal = horizontal_cosines(product.patches) @ weights[:, hours] + sun_light[hours] * np.maximum(
            suns[hours, 2], 0.0) * sun
        ground_light = (bounced.reflectance * horizontal / np.pi).astype(np.float32)
    for lo in range(0, product.num_faces, FACE_CHUNK):
        faces = slice(lo, min(product.num_faces, lo + FACE_CHUNK))
        coefficients = product.visibility[faces].astype(np.float32) * np.float32(product.visibility_scale)
        if bounced is not None:
            coefficients = np.concatenate([coefficients, bounced.sky[faces]], axis=1)
        illuminance = coefficients @ weights_occupied  # (chunk, occupied hours) sky illuminance, lux
        if bounced is not None:
            illuminance += bounced.ground[faces, None] * ground_light[None, :]
        cos_sun = np.maximum(normals[faces] @ sun_world[hours].T, 0.0)
        lit_bins = bins[hours]
        if len(bin_directions):
            seen = hits[:, faces][np.maximum(lit_bins, 0)].T.astype(np.float32) / np.float32(sun_levels(sun_samples))
            sun_share = np.where(lit_bins >= 0, seen, 0.0)
            sunlight = cos_sun * sun_share * direct[hours][None, :]
            illuminance += sunlight
        else:
            sunlight = np.zeros_like(illuminance)
        autonomy[faces] = (illuminance >= threshold).sum(axis=1) / count
        useful[faces, 0] = (illuminance < udi[0]).sum(axis=1) / count
        useful[faces, 2] = (illuminance > udi[1]).sum(axis=1) / count
        useful[faces, 1] = 1.0 - useful[faces, 0] - useful[faces, 2]
        sun_hours[faces] = (sunlight >= ase_lux).sum(axis=1)
        mean[faces] = illuminance.mean(axis=1)
        progress(0.7 + 0.3 * faces.stop / max(1, product.num_faces))
    metrics = AnnualMetrics(overcast_factors(product, bounced), autonomy, useful, sun_hours, mean)
    stats = {"hours": float(len(weather)), "bounces": float(bounced.bounces if bounced else 0), "occupied_hours": float(count), "sun_bins": float(len(bin_directions)),
             "faces": float(product.num_faces), "rays": float(tracer.rays_cast - rays_before),
             "sky_matrix_s": sky_seconds, "sun_rays_s": sun_seconds,
             "metrics_s": _time.perf_counter() - started - sky_seconds - sun_seconds}
    return metrics, stats


def sensor_faces(scene: Scene, product: SkyVisibilityProduct, which: str, prims: str = "") -> np.ndarray:
    """(F,) bool: the faces sDA and ASE are taken over: facing up (or all), of the named prims (paths or
    names, comma-separated; '' for every prim)."""
    mask = np.ones(product.num_faces, bool) if which == "all" else product.face_normals @ scene.up_vector >= SENSOR_COS
    names = {name.strip() for name in prims.split(",") if name.strip()}
    if names:
        chosen = [index for index, path in enumerate(scene.prim_paths)
                  if path in names or path.rsplit("/", 1)[-1] in names]
        mask &= np.isin(product.face_prim, chosen)
    return mask


def spatial_share(values: np.ndarray, areas: np.ndarray, mask: np.ndarray) -> float:
    """Area-weighted share of the masked faces where ``values`` is true (0 without sensor area)."""
    total = float(areas[mask].sum())
    return float(areas[mask & values].sum()) / total if total > 0 else 0.0


def parse_hours(text: str) -> tuple[float, float]:
    try:
        start, end = (float(part) for part in text.split("-"))
    except ValueError:
        raise ParamError(f"occupied={text!r}: expected 'start-end' hours, e.g. '8-18'") from None
    if not 0.0 <= start < end <= 24.0:
        raise ParamError(f"occupied={text!r}: hours must satisfy 0 <= start < end <= 24")
    return start, end


class AnnualDaylight(Processor):
    name = "annual_daylight"
    version = "1"
    summary = "Climate-based annual daylight from a weather file (EPW / TMY3): DF, DA, sDA, UDI, ASE."
    facets = ("geometry",)
    writes = ("primvars:bake:daylightFactor", "primvars:bake:daylightAutonomy", "primvars:bake:usefulDaylight",
              "primvars:bake:annualSunHours", "primvars:bake:meanIlluminance", "bake:lightmap:daylightFactor:",
              "bake:lightmap:daylightAutonomy:", "bake:lightmap:usefulDaylight:", "bake:lightmap:annualSunHours:",
              "bake:lightmap:meanIlluminance:")
    requires = (SkyVisibilityProduct, InterreflectionProduct)
    provides = (AnnualDaylightProduct,)

    @dataclass(frozen=True)
    class Params(Params):
        weather: str = param("", "typical-year weather file: EnergyPlus .epw or NREL TMY3 .csv")
        north: float = param(0.0, "angle of north from the stage's default north (degrees, counter-clockwise)",
                             low=-360.0, high=360.0)
        occupied: str = param("8-18", "occupied hours, local standard time, every day ('start-end')")
        threshold: float = param(300.0, "daylight autonomy threshold, lux", low=0.0)
        sda_share: float = param(0.5, "sDA counts faces with DA at least this", low=0.0, high=1.0)
        udi_low: float = param(100.0, "UDI band, lower edge, lux", low=0.0)
        udi_high: float = param(3000.0, "UDI band, upper edge, lux", low=0.0)
        ase_lux: float = param(1000.0, "direct sunlight counted for ASE, lux", low=0.0)
        ase_hours: float = param(250.0, "ASE counts faces with at least this many sunlit hours", low=0.0)
        sensors: str = param("up", "faces sDA and ASE are taken over: up (facing up: the work plane) or all",
                             choices=("up", "all"))
        sensor_prims: str = param("", "only faces of these prims count as sensors (comma-separated paths or "
                                  "names, e.g. Floor); '' for every receiver")
        sun: bool = param(True, "add the direct sun")
        sun_samples: int = param(2, "shadow rays per face and sun bin", low=1, high=255)
        sun_bins: int = param(4, "sun positions snapped to Reinhart MF:n patches (4: 2305, ~3 degrees)",
                              low=1, high=16)
        seed: int = param(0, "random seed of the sun rays", low=0)
        efficacy: str = param("perez", "solar W/m^2 to lux: perez (the Perez et al. 1990 luminous efficacy model, as "
                              "gendaymtx -O0), weather (the file's own illuminance columns) or 179 (Radiance's "
                              "visible-equivalent factor, as gendaymtx -O1 x 179)", choices=("perez", "weather", "179"))

        def __post_init__(self) -> None:
            super().__post_init__()
            parse_hours(self.occupied)
            if self.udi_low >= self.udi_high:
                raise ParamError(f"udi_low={self.udi_low} must be below udi_high={self.udi_high}")

    def applies(self, ctx: Context) -> tuple[bool, str]:
        """Reads the weather file, so a broken one, or one from another place than the stage's (a
        ``usdbake sky`` layer records it), is refused before any compute."""
        if not self.params.weather:
            return False, "no weather file: set annual_daylight.weather=FILE.epw (or an NREL TMY3 .csv)"
        self.weather = read_weather(self.params.weather)
        check_site(self.weather, ctx.scene.site)
        if self.params.efficacy == "weather" and (self.weather.direct_normal_illuminance is None
                                                  or self.weather.diffuse_horizontal_illuminance is None):
            raise ParamError(f"annual_daylight.efficacy=weather: {self.weather.source} has no direct normal and "
                             f"diffuse horizontal illuminance columns; use efficacy=perez")
        return True, ""

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        product = ctx.products[SkyVisibilityProduct]
        weather = getattr(self, "weather", None) or read_weather(p.weather)
        inter = ctx.products[InterreflectionProduct]
        receivers = receiver_sets(product, inter)
        computed = []
        for index, (faces, bounced) in enumerate(receivers):  # the refined faces, the lightmap texels, or both
            metrics, stats = compute_annual_daylight(
                ctx.tracer, scene, faces, weather, north=p.north, occupied=parse_hours(p.occupied),
                threshold=p.threshold, udi=(p.udi_low, p.udi_high), ase_lux=p.ase_lux, sun=p.sun,
                sun_samples=p.sun_samples, sun_subdivision=p.sun_bins, seed=p.seed, interreflection=bounced,
                efficacy=p.efficacy, progress=lambda f, index=index: ctx.progress((index + f) / len(receivers)))
            sensors = sensor_faces(scene, faces, p.sensors, p.sensor_prims)
            areas = faces.face_areas.astype(np.float64)
            computed.append((AnnualDaylightProduct(
                metrics.daylight_factor, metrics.autonomy, metrics.useful, metrics.sun_hours,
                metrics.mean_illuminance, sensors, spatial_share(metrics.autonomy >= p.sda_share, areas, sensors),
                spatial_share(metrics.sun_hours >= p.ase_hours, areas, sensors)), stats))
        texel_metrics = computed[-1][0] if product.texels is not None else None
        annual, stats = computed[0]
        stats = dict(stats, rays=sum(figures.get("rays", 0.0) for _, figures in computed))
        annual = replace(annual, texels=texel_metrics if product.mesh_written else None)
        # sDA and ASE are taken over the refined faces, or over the texels (footprint-weighted) without them
        sensor_set = product if product.mesh_written else product.texels.view
        sensors, sda, ase = annual.sensors, annual.sda, annual.ase
        areas = sensor_set.face_areas.astype(np.float64)
        result = Result(products={AnnualDaylightProduct: annual}, stats=stats)
        if texel_metrics is not None:
            result.outputs += self._texel_outputs(scene, product.texels, texel_metrics)
            result.stats["texels"] = float(product.texels.count)
        report = {"weather": weather.source, "bounces": inter.bounces, "ground_reflectance": inter.ground_reflectance,
                  "efficacy": p.efficacy, "latitude": weather.latitude, "longitude": weather.longitude,
                  "timezone": weather.timezone, "occupied": p.occupied, "sensor_faces": int(sensors.sum()),
                  "sensor_area": float(areas[sensors].sum()), "sDA": sda, "ASE": ase, "prims": {}}
        for prim in product.prims:
            path = scene.prim_paths[prim]
            faces = np.flatnonzero(sensor_set.face_prim == prim)
            mine = sensors[faces]
            report["prims"][path] = {
                "mean_daylight_factor": _area_mean(annual.daylight_factor[faces], areas[faces]),
                "mean_autonomy": _area_mean(annual.autonomy[faces], areas[faces]),
                "sDA": spatial_share(annual.autonomy[faces] >= p.sda_share, areas[faces], mine),
                "ASE": spatial_share(annual.sun_hours[faces] >= p.ase_hours, areas[faces], mine)}
            if not product.mesh_written:
                continue
            result.outputs += [
                Primvar(path, "bake:daylightFactor", annual.daylight_factor[faces], "float", "uniform"),
                Primvar(path, "bake:daylightAutonomy", annual.autonomy[faces], "float", "uniform"),
                Primvar(path, "bake:usefulDaylight", annual.useful[faces].ravel(), "float", "uniform",
                        element_size=3),
                Primvar(path, "bake:annualSunHours", annual.sun_hours[faces], "float", "uniform"),
                Primvar(path, "bake:meanIlluminance", annual.mean_illuminance[faces], "float", "uniform"),
            ]
        result.outputs += [
            Prim("/usdbake", "Scope"), Prim(REPORT_PRIM, "Scope"),
            Attribute(REPORT_PRIM, "bake:annual:sDA", float(sda), "float"),
            Attribute(REPORT_PRIM, "bake:annual:ASE", float(ase), "float"),
            Attribute(REPORT_PRIM, "bake:annual:weather", weather.source, "string"),
            Attribute(REPORT_PRIM, "bake:annual:latitude", float(weather.latitude), "float"),
            Attribute(REPORT_PRIM, "bake:annual:longitude", float(weather.longitude), "float"),
            Attribute(REPORT_PRIM, "bake:annual:sensorArea", float(areas[sensors].sum()), "float"),
            Attribute(REPORT_PRIM, "bake:annual:report", f"./{REPORT_FILE}", "asset"),
            File(REPORT_FILE, json.dumps(report, indent=2).encode()),
        ]
        if not sensors.any():
            result.messages.append(f"no sensor faces (sensors={p.sensors}, sensor_prims={p.sensor_prims!r}): "
                                   f"sDA and ASE are 0")
        result.messages.append(f"sDA {100 * sda:.1f}% (DA >= {p.sda_share:g} at {p.threshold:g} lx), ASE "
                               f"{100 * ase:.1f}% ({p.ase_lux:g} lx for {p.ase_hours:g} h) over "
                               f"{int(sensors.sum())} sensor {'faces' if product.mesh_written else 'texels'}; weather {weather.source}; {inter.bounces} bounces, "
                               f"ground {inter.ground_reflectance:g}, efficacy {p.efficacy}")
        return result

    @staticmethod
    def _texel_outputs(scene: Scene, texels, metrics: AnnualDaylightProduct) -> list:
        """The texture target: one lightmap per metric (``LightmapAPI:<metric>``, the primvars' names)."""
        channels = (("daylightFactor", metrics.daylight_factor, "percent", False),
                    ("daylightAutonomy", metrics.autonomy, "fraction", True),
                    ("usefulDaylight", metrics.useful, "fraction", True),
                    ("annualSunHours", metrics.sun_hours, "hours", False),
                    ("meanIlluminance", metrics.mean_illuminance, "lux", False))
        records = []
        for channel, values, units, unit_range in channels:
            records += texel_lightmaps(scene, texels, channel, values, units=units, unit_range=unit_range)
        return records


def _area_mean(values: np.ndarray, areas: np.ndarray) -> float:
    total = float(areas.sum())
    return float((values * areas).sum() / total) if total > 0 else 0.0
