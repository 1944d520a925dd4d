"""Annual daylight (8760 hours) after sky visibility: wall time and memory on a ~100k-face daylit room."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom

from . import harness
from .city_stage import grid_quads
from usdbake.formats.weather import read_weather
from usdbake.kernels.sky import overcast_radiance, tregenza_patches
from usdbake.kernels.tracer import Tracer
from usdbake.processors.daylight.annual_daylight import compute_annual_daylight
from usdbake.processors.daylight.daylight import DaylightRelighter, compute_daylight, sun_table
from usdbake.processors.daylight.sky_visibility import compute_sky_visibility
from usdbake.stages.extract import extract_scene

NAME = "annual_daylight"
DESCRIPTION = (
    "`annual_daylight` on a generated room lit only through four windows (Z-up, metres, 8 x 6 x 3 m, floor and "
    "ceiling finely tessellated, a few furniture blocks), Greensboro NC typical year (the NREL TMY3 file pvlib "
    "ships), 8760 hours, defaults (sun bins Reinhart MF:4, 2 shadow rays per face and bin). Visibility "
    "(`sky_visibility`, Tregenza patches, 4 rays per face and patch, no refinement) is computed first and not "
    "timed. Seconds: wall time of compute_annual_daylight (sky matrix, sun rays, the hourly products and the "
    "metrics); peak_mb: growth of the process's peak resident memory during it. The issue's figure: <= 60 s on "
    "2 cores for 100k faces. Interactive relight of the same room (`daylight.DaylightRelighter`): the sun table's "
    "precompute (shadow rays on a 4 x 3.75 degree declination x hour-angle grid, 2 rays per face and node), its "
    "memory, and one new time (Perez sky + sun from the table, no rays; median and max over 48 times of a year) "
    "against one time of `compute_daylight` (4 sun rays per face). The issue's figure: <= 30 ms for 100k faces.")
ROOM = (8.0, 6.0, 3.0)
WINDOWS = ((0.25, 0.75), (0.3, 0.8))
"""Window openings as (u range, v range) shares of each wall."""
SMALL_WINDOWS = ((0.45, 0.55), (0.4, 0.7))
"""The Radiance comparison's room: narrow windows, so part of the floor stays below the DA threshold."""
SENSORS = 192
"""Floor faces compared with Radiance (their centroids, 1 mm above the floor)."""


def grid(origin, u, v, nu: int, nv: int, keep=None) -> list[np.ndarray]:
    """``city_stage.grid_quads`` as a list, without the cells whose centre shares (a along u, b along v) fail
    ``keep(a, b)`` (window openings)."""
    quads = grid_quads(origin, u, v, nu, nv)
    if keep is not None:
        a, b = np.meshgrid((np.arange(nu) + 0.5) / nu, (np.arange(nv) + 0.5) / nv, indexing="ij")
        quads = quads[np.vectorize(keep)(a, b).ravel()]
    return list(quads)


def room_stage(faces: int, windows=WINDOWS) -> Usd.Stage:
    """The room with about ``faces`` triangles: inward walls with four windows, floor, ceiling, furniture."""
    x, y, z = ROOM
    n = max(4, int(np.ceil(np.sqrt(faces / 4.0))))  # floor and ceiling: 4 n^2 triangles, nearly all of them
    wall = lambda a, b: not (windows[0][0] < a < windows[0][1] and windows[1][0] < b < windows[1][1])  # noqa: E731
    m = max(4, n // 3)
    quads = grid((0, 0, 0), (x, 0, 0), (0, y, 0), n, n)  # floor, facing up (u x v = +z)
    quads += grid((0, 0, z), (0, y, 0), (x, 0, 0), n, n)  # ceiling, facing down
    quads += grid((x, 0, 0), (-x, 0, 0), (0, 0, z), m, m // 2, wall)  # south wall (y = 0), facing +y
    quads += grid((0, y, 0), (x, 0, 0), (0, 0, z), m, m // 2, wall)  # north wall, facing -y
    quads += grid((0, 0, 0), (0, y, 0), (0, 0, z), m, m // 2, wall)  # west wall, facing +x
    quads += grid((x, y, 0), (0, -y, 0), (0, 0, z), m, m // 2, wall)  # east wall, facing -x
    for cx, cy in ((2.0, 2.0), (5.5, 4.0), (6.5, 1.5)):  # tables: a top and four sides
        lo, hi = np.array([cx - 0.6, cy - 0.4, 0.0]), np.array([cx + 0.6, cy + 0.4, 0.75])
        quads += grid((lo[0], lo[1], hi[2]), (hi[0] - lo[0], 0, 0), (0, hi[1] - lo[1], 0), 8, 8)
        quads += grid((lo[0], lo[1], 0), (hi[0] - lo[0], 0, 0), (0, 0, hi[2]), 8, 4)
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, "Z")
    points = np.concatenate(quads)
    mesh = UsdGeom.Mesh.Define(stage, "/World/Room")
    mesh.CreatePointsAttr(points.astype(np.float32))
    mesh.CreateFaceVertexCountsAttr([4] * len(quads))
    mesh.CreateFaceVertexIndicesAttr(np.arange(len(points), dtype=np.int32))
    return stage


def tmy3() -> Path:
    import pvlib

    return Path(pvlib.__file__).parent / "data" / "723170TYA.CSV"


def radiance_comparison(weather) -> dict:
    """Mean occupied-hour illuminance, DA, sDA and DF at floor faces against Radiance (rcontrib daylight
    coefficients x gendaymtx, ``radiance_reference``), black interior (both count the sky seen directly)."""
    from . import radiance_binaries, radiance_scene
    from . import radiance_reference as radiance

    if not radiance_binaries.radiance_available():
        return {"radiance": "not installed (pip install pyradiance: the bench extra)"}
    scene = extract_scene(room_stage(10_000, SMALL_WINDOWS))
    tracer = Tracer.from_scene(scene)
    product, _ = compute_sky_visibility(tracer, scene, patches=tregenza_patches(), samples=16, adaptive=False,
                                        max_face_area=0.0)
    # Radiance's solar units x 179 and a black interior, both sides: the direct-view check (the bounced,
    # photometric figures are bench_daylight_bounces's)
    metrics, _ = compute_annual_daylight(tracer, scene, product, weather, sun_samples=16, efficacy="179")
    corners = product.face_points[product.face_vertices]
    floor = np.flatnonzero((product.face_normals[:, 2] > 0.9) & (corners[:, :, 2].max(axis=1) < 0.01))
    picks = np.random.default_rng(1).choice(floor, SENSORS, replace=False)
    points = corners[picks].mean(axis=1) + scene.origin
    triangles = corners + scene.origin
    started = time.perf_counter()
    hourly = radiance.annual_illuminance(triangles, np.zeros(len(triangles)), points, product.face_normals[picks],
                                         str(tmy3()), up="Z", mf=1, output="solar", ground_reflectance=0.0,
                                         offset=1e-3)
    radiance_seconds = time.perf_counter() - started
    hour = (weather.times - weather.times.astype("datetime64[D]")).astype(np.float64) / 60.0
    occupied = hourly[(hour >= 8) & (hour < 18)]
    ours_mean, theirs_mean = metrics.mean_illuminance[picks], occupied.mean(axis=0)
    ours_da, theirs_da = metrics.autonomy[picks], (occupied >= 300).mean(axis=0)
    # Daylight factor: the same daylight coefficients under the CIE overcast sky, over an open horizontal sensor.
    dc = radiance_scene.daylight_coefficients(triangles, np.zeros(len(triangles)), points, product.face_normals[picks],
                                              up="Z", mf=1, offset=1e-3)[:, :, 1]
    open_dc = radiance_scene.daylight_coefficients(None, None, np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]),
                                                   up="Z", mf=1)[:, :, 1]
    overcast = np.r_[0.0, overcast_radiance(tregenza_patches().patch_directions, np.array([0, 0, 1.0]))[:, 0]]
    theirs_df = 100.0 * (dc @ overcast) / float((open_dc @ overcast)[0])
    ours_df = metrics.daylight_factor[picks]
    return {
        "radiance_sensors": SENSORS, "radiance_seconds": round(radiance_seconds, 1),
        "mean_illuminance_usdbake_lux": round(float(ours_mean.mean()), 1),
        "mean_illuminance_radiance_lux": round(float(theirs_mean.mean()), 1),
        "mean_illuminance_relative_difference": round(float(ours_mean.mean() / theirs_mean.mean() - 1), 4),
        "mean_illuminance_per_sensor_median_abs_relative": round(float(np.median(np.abs(ours_mean / theirs_mean - 1))), 4),
        "sda_usdbake": round(float((ours_da >= 0.5).mean()), 4), "sda_radiance": round(float((theirs_da >= 0.5).mean()), 4),
        "mean_da_usdbake": round(float(ours_da.mean()), 4), "mean_da_radiance": round(float(theirs_da.mean()), 4),
        "df_usdbake_percent": round(float(ours_df.mean()), 3), "df_radiance_percent": round(float(theirs_df.mean()), 3),
        "df_relative_difference": round(float(ours_df.mean() / theirs_df.mean() - 1), 4),
    }


def relight_figures(tracer, scene, product, weather) -> dict:
    """Sun table precompute and memory, then per-time relights of the room at the weather file's site."""
    site = {"latitude": weather.latitude, "longitude": weather.longitude, "timezone": weather.timezone}
    started = time.perf_counter()
    table = sun_table(tracer, product, latitude=weather.latitude)
    precompute = time.perf_counter() - started
    relighter = DaylightRelighter(product, table, **site, albedo=scene.tri_albedo[product.face_source])
    times = np.datetime64("2025-01-04T08:00") + np.arange(48) * np.timedelta64(7 * 24 * 60 + 37, "m")
    sky = {"sky": "perez", "direct_normal": 700.0, "diffuse_horizontal": 120.0}
    relighter.at(times[0], **sky)  # first touch of V's float32 copy
    seconds = []
    for when in times:
        started = time.perf_counter()
        relighter.at(when, **sky)
        seconds.append(time.perf_counter() - started)
    noon = np.array([np.datetime64("2025-06-21T12:00")])
    compute_daylight(tracer, scene, product, noon, **site, **sky)  # compile
    started = time.perf_counter()
    compute_daylight(tracer, scene, product, noon, **site, **sky)
    with_rays = time.perf_counter() - started
    return {"relight_sun_table_seconds": round(precompute, 1), "relight_sun_table_nodes": int(len(table.hits)),
            "relight_sun_table_mb": round(table.hits.nbytes / 2 ** 20, 1),
            "relight_visibility_float32_mb": round(relighter.visibility.nbytes / 2 ** 20, 1),
            "relight_ms_median": round(1000 * float(np.median(seconds)), 2),
            "relight_ms_max": round(1000 * float(np.max(seconds)), 2),
            "relight_with_sun_rays_ms": round(1000 * with_rays, 1)}


def run(quick: bool = False) -> dict:
    weather = read_weather(tmy3())
    target = 10_000 if quick else 100_000
    scene = extract_scene(room_stage(target))
    tracer = Tracer.from_scene(scene)
    started = time.perf_counter()
    product, _ = compute_sky_visibility(tracer, scene, patches=tregenza_patches(), samples=4, adaptive=False)
    visibility_seconds = time.perf_counter() - started
    compute_annual_daylight(tracer, scene, product, weather, sun_subdivision=1)  # compile and warm up
    with harness.measure() as m:
        metrics, stats = compute_annual_daylight(tracer, scene, product, weather)
    floor = product.face_normals[:, 2] > 0.9
    floor &= product.face_points[product.face_vertices][:, :, 2].max(axis=1) < 0.01
    figures = {
        "faces": int(product.num_faces), "hours": int(stats["hours"]), "sun_bins": int(stats["sun_bins"]),
        "annual_seconds": round(m.seconds, 2), "annual_peak_mb": round(m.peak_mb, 1),
        "sky_matrix_seconds": round(stats["sky_matrix_s"], 2), "sun_rays_seconds": round(stats["sun_rays_s"], 2),
        "metrics_seconds": round(stats["metrics_s"], 2), "sun_rays": int(stats["rays"]),
        "visibility_seconds": round(visibility_seconds, 2),
        "floor_mean_daylight_factor": round(float(metrics.daylight_factor[floor].mean()), 3),
        "floor_mean_autonomy": round(float(metrics.autonomy[floor].mean()), 3),
    }
    figures.update(relight_figures(tracer, scene, product, weather))
    if not quick:
        figures.update(radiance_comparison(weather))
    table = harness.markdown_table([figures], ["faces", "hours", "sun_bins", "annual_seconds", "annual_peak_mb",
                                               "sky_matrix_seconds", "sun_rays_seconds", "metrics_seconds"])
    table += "\n\n" + harness.markdown_table([figures], [
        "relight_sun_table_seconds", "relight_sun_table_nodes", "relight_sun_table_mb", "relight_visibility_float32_mb",
        "relight_ms_median", "relight_ms_max", "relight_with_sun_rays_ms"])
    if "df_radiance_percent" in figures:
        table += "\n\n" + harness.markdown_table([figures], [
            "mean_illuminance_usdbake_lux", "mean_illuminance_radiance_lux", "mean_illuminance_relative_difference",
            "sda_usdbake", "sda_radiance", "df_usdbake_percent", "df_radiance_percent", "df_relative_difference"])
    return harness.result(NAME, description=DESCRIPTION, settings={"faces": target, "quick": quick},
                          points=[{"label": "defaults", "seconds": figures["annual_seconds"], "error": 0.0,
                                   "default": True, "peak_mb": figures["annual_peak_mb"]}],
                          figures=figures, table=table, knob="defaults", error_label="-")
