"""Daylight with interreflections, glazing and photometry (issue 29) against Radiance, and its speed.

Figures:
- the LM-83-style side-lit office (``daylight_scenes.lm83_office``: floor 0.2, walls 0.5, ceiling 0.7, window
  VLT 0.6, no ground in the stage): the whole `annual_daylight` bake from the stage (sky visibility,
  interreflection, the year; Greensboro TMY3) against Radiance (rcontrib -ab 6 daylight coefficients with
  glass x gendaymtx -O0 visible, ground 0.2, -ad 65536: Radiance's own noise 0.45% median) at the 170 floor
  sensors: mean occupied-hour illuminance, daylight factor, sDA, and ASE against Radiance's direct sun as
  discrete 0.533-degree sources (``office_sun_reference``: the 5-phase direct-sun method; the smeared two-phase
  sun counts 6 more sensors); run time against Radiance at equal error: rcontrib at -ad 1024..8192 on the same
  sensors, its error against the reference, its time interpolated (log-log) to usdbake's error, gendaymtx
  included;
- glazing: an open face under a wide pane of VLT 0.6: the overhead sun through it over the VLT (1 at normal
  incidence by definition), and the uniform sky through it against Radiance's rtrace with a ``glass`` pane;
- the furnished room (``furnished_daylight_room.furnished_daylight_room``: ~129k triangles, glazing VLT 0.7, on its own
  ground) under one uniform sky: `daylight`'s total irradiance at 150 random surface points against Radiance
  rtrace -ab 6;
- 100k faces x 8760 hours with bounces (``bench_annual_daylight.room_stage``): the annual run after visibility
  and interreflection, the interreflection precompute itself, and one new time of ``DaylightRelighter`` with
  bounces.
Quick mode (the smoke run): the office without Radiance and a 10k-face room.
"""

from __future__ import annotations

import time

import numpy as np

from . import harness
from .bench_annual_daylight import room_stage, tmy3
from .daylight_references import furnished_reference, office_reference
from .daylight_scenes import lm83_office
from .furnished_daylight_room import furnished_daylight_room
from .office_sun_reference import ase, office_sun_reference
from .stage_readback import sample_baked, stage_triangles
from usdbake.formats.weather import read_weather
from usdbake.kernels.sky import tregenza_patches
from usdbake.kernels.tracer import Tracer
from usdbake.processors.daylight.annual_daylight import compute_annual_daylight
from usdbake.processors.daylight.daylight import DaylightRelighter, sun_table
from usdbake.processors.daylight.interreflection import compute_interreflection
from usdbake.processors.daylight.sky_visibility import compute_sky_visibility
from usdbake.stages.extract import extract_scene

NAME = "daylight_bounces"
DESCRIPTION = __doc__.split("\n\n", 1)[1].strip()
RGB_LUMINANCE = np.array([0.265, 0.670, 0.065])
"""Radiance's luminance weights (the reference's own)."""
OCCUPIED = (8.0, 18.0)
SWEEP_DIVISIONS = (1024, 2048, 4096, 8192, 16384)
"""rcontrib -ad of the equal-error sweep (Radiance's error falls as 1 / sqrt(-ad))."""
FINE = {"sky_visibility": {"samples": 16}, "interreflection": {"gather_rays": 512}}
"""usdbake's second point of the equal-error comparison: 4x the visibility and gather rays."""


def _bake(stage, processors: list[str], params: dict):
    import usdbake

    started = time.perf_counter()
    usdbake.bake(stage, processors=processors, params=params)
    return time.perf_counter() - started


def _relative(ours: np.ndarray, theirs: np.ndarray) -> np.ndarray:
    return (ours - theirs) / np.maximum(np.abs(theirs), 1e-9)


def office_figures(with_radiance: bool) -> dict:
    """The office's LM-83 metrics from the stage, everything included, against Radiance."""
    scene = lm83_office()
    weather = str(tmy3())
    seconds = _bake(scene.stage, ["annual_daylight"], {"annual_daylight": {"weather": weather,
                                                                           "sensor_prims": "Floor"}})
    at = {name: sample_baked(scene.stage, f"bake:{name}", scene.sensor_points, scene.sensor_normals)[:, 0]
          for name in ("meanIlluminance", "daylightAutonomy", "daylightFactor", "annualSunHours")}
    figures = {"office_sensors": len(scene.sensor_points), "office_usdbake_seconds": round(seconds, 2),
               "office_sda_usdbake": round(float((at["daylightAutonomy"] >= 0.5).mean()), 4),
               "office_ase_usdbake": round(float((at["annualSunHours"] >= 250).mean()), 4),
               "office_mean_illuminance_usdbake_lux": round(float(np.nanmean(at["meanIlluminance"])), 1)}
    if not with_radiance:
        return figures
    from . import radiance_sky

    reference = office_reference(scene)
    hours = reference["times"]
    hour = (hours - hours.astype("datetime64[D]")).astype(np.float64) / 60.0
    occupied = (hour >= OCCUPIED[0]) & (hour < OCCUPIED[1])
    hourly = reference["illuminance"][occupied]
    theirs_mean, theirs_da = hourly.mean(axis=0), (hourly >= 300).mean(axis=0)
    sun = office_sun_reference(scene)
    _, ase_radiance = ase(sun["illuminance"], sun["times"])
    overcast, horizontal = radiance_sky.cie_overcast_sky(4, ground_reflectance=0.2)
    theirs_df = 100.0 * np.einsum("spc,p->sc", reference["dc"], overcast) @ RGB_LUMINANCE / horizontal
    error = np.abs(_relative(at["meanIlluminance"], theirs_mean))
    df_error = np.abs(_relative(at["daylightFactor"], theirs_df))
    radiance_seconds = float(reference["rcontrib_seconds"]) + float(reference["gendaymtx_seconds"])
    figures.update({
        "office_mean_illuminance_radiance_lux": round(float(theirs_mean.mean()), 1),
        "office_mean_illuminance_median_abs_error": round(float(np.nanmedian(error)), 4),
        "office_mean_illuminance_bias": round(float(np.nanmedian(_relative(at["meanIlluminance"], theirs_mean))), 4),
        "office_df_usdbake_percent": round(float(np.nanmean(at["daylightFactor"])), 3),
        "office_df_radiance_percent": round(float(theirs_df.mean()), 3),
        "office_df_median_abs_error": round(float(np.nanmedian(df_error)), 4),
        "office_sda_radiance": round(float((theirs_da >= 0.5).mean()), 4),
        "office_ase_radiance": round(ase_radiance, 4),
        "office_radiance_seconds": round(radiance_seconds, 1),
        "office_radiance_processes": int(reference["processes"]),
        "office_speedup": round(radiance_seconds / seconds, 1),
        "office_radiance_command": str(reference["command"]),
    })
    fine = lm83_office()
    fine_seconds = _bake(fine.stage, ["annual_daylight"], {**FINE, "annual_daylight": {"weather": weather,
                                                                                     "sensor_prims": "Floor"}})
    fine_mean = sample_baked(fine.stage, "bake:meanIlluminance", fine.sensor_points, fine.sensor_normals)[:, 0]
    fine_error = float(np.nanmedian(np.abs(_relative(fine_mean, theirs_mean))))
    figures.update({"office_fine_seconds": round(fine_seconds, 2), "office_fine_error": round(fine_error, 4)})
    figures.update(equal_error_time(scene, reference, occupied, {
        "": (seconds, float(np.nanmedian(error))), "_fine": (fine_seconds, fine_error)}))
    figures["office_sda_points"] = round(100 * abs(figures["office_sda_usdbake"] - figures["office_sda_radiance"]), 2)
    figures["office_ase_points"] = round(100 * abs(figures["office_ase_usdbake"] - figures["office_ase_radiance"]), 2)
    return figures


def equal_error_time(scene, reference, occupied: np.ndarray, ours: dict[str, tuple[float, float]]) -> dict:
    """Radiance's time at usdbake's error on the office: rcontrib at ``SWEEP_DIVISIONS`` (another seed than the
    reference's) plus gendaymtx, its median |relative error| of the mean occupied illuminance against the
    reference, the time interpolated log-log to the error of each of ``ours`` ({suffix: (seconds, error)})."""
    from . import radiance_reference as radiance
    from . import radiance_scene, radiance_sky

    started = time.perf_counter()
    _, sky = radiance_sky.annual_sky_matrix(str(tmy3()), mf=4, output="visible", ground_reflectance=0.2)
    sky_seconds = time.perf_counter() - started
    truth = reference["illuminance"][occupied].mean(axis=0)
    errors, times = [], []
    for divisions in SWEEP_DIVISIONS:
        timings = {}
        dc = radiance_scene.daylight_coefficients(scene.triangles, scene.albedo, scene.sensor_points,
                                                  scene.sensor_normals, transmittance=scene.transmittance, mf=4,
                                                  ambient_bounces=5, ambient_divisions=divisions, seed=7,
                                                  timings=timings)
        mean = radiance.illuminance_from(dc, sky)[occupied].mean(axis=0)
        errors.append(float(np.median(np.abs(_relative(mean, truth)))))
        times.append(timings["radiance_seconds"] + sky_seconds)
    order = np.argsort(errors)
    figures = {"office_radiance_sweep": [{"ad": d, "error": round(e, 4), "seconds": round(t, 2)}
                                         for d, e, t in zip(SWEEP_DIVISIONS, errors, times)]}
    for suffix, (seconds, error) in ours.items():
        at_error = float(np.exp(np.interp(np.log(error), np.log(np.asarray(errors)[order]),
                                          np.log(np.asarray(times)[order]))))
        figures[f"office_radiance_seconds_at_equal_error{suffix}"] = round(at_error, 2)
        figures[f"office_speedup_at_equal_error{suffix}"] = round(at_error / seconds, 2)
    return figures


def furnished_figures() -> dict:
    """Total irradiance under one uniform sky at the furnished room's random surface points."""
    scene = furnished_daylight_room()
    reference = furnished_reference(scene)
    radiance_value = float(reference["sky_radiance"])
    seconds = _bake(scene.stage, ["daylight"], {"daylight": {"sky": "uniform", "uniform_radiance": radiance_value,
                                                             "sun": False}})
    ours = sample_baked(scene.stage, "bake:daylightIrradiance", reference["points"], reference["normals"]) \
        @ RGB_LUMINANCE
    theirs = reference["irradiance"] @ RGB_LUMINANCE
    direct = reference["irradiance_direct"] @ RGB_LUMINANCE
    error = _relative(ours, theirs)
    return {"room_points": int(np.isfinite(ours).sum()), "room_usdbake_seconds": round(seconds, 2),
            "room_median_abs_error": round(float(np.nanmedian(np.abs(error))), 4),
            "room_bias": round(float(np.nanmedian(error)), 4),
            "room_abs_bias": round(abs(float(np.nanmedian(error))), 4),
            "room_mean_ratio": round(float(np.nansum(ours) / np.sum(theirs[np.isfinite(ours)])), 4),
            "room_interreflected_share_radiance": round(float(np.median(1 - direct / np.maximum(theirs, 1e-9))), 3),
            "room_radiance_seconds": round(float(reference["rtrace_seconds"]), 1)}


def glazing_figures(with_radiance: bool) -> dict:
    """An open upward 1 m square under a 400 m pane of VLT 0.6, 0.5 m above it: the overhead sun (normal
    incidence) through the pane over the open value, against the VLT; and the uniform sky seen through it
    (``sky_visibility``'s exposure) against Radiance's rtrace with a ``glass`` pane (sky seen directly)."""
    from pxr import Sdf, Usd, UsdGeom

    from usdbake.processors.daylight.glazing import scene_glazing
    from usdbake.processors.daylight.sun_visibility import compute_sun_visibility

    vlt = 0.6
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    for path, corners in (("/World/Floor", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]),
                          ("/World/Pane", [(-200, -200, 0.5), (200, -200, 0.5), (200, 200, 0.5), (-200, 200, 0.5)])):
        mesh = UsdGeom.Mesh.Define(stage, path)
        mesh.CreatePointsAttr(corners)
        mesh.CreateFaceVertexCountsAttr([4])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    stage.GetPrimAtPath("/World/Pane").CreateAttribute("bake:transmittance", Sdf.ValueTypeNames.Float).Set(vlt)
    scene = extract_scene(stage)
    tracer = Tracer.from_scene(scene)
    floor = np.flatnonzero(scene.tri_prim == scene.prim_paths.index("/World/Floor"))
    corners = scene.points[scene.tri_vertices[floor]]
    seen = compute_sun_visibility(tracer, corners, scene.tri_normals[floor], np.array([0.0, 0.0, 1.0]), samples=64,
                                  glazing=scene_glazing(scene, tracer))
    figures = {"glazing_sun_vs_vlt_error": round(float(np.abs(seen / vlt - 1).max()), 5)}
    if not with_radiance:
        return figures
    from . import radiance_scene

    product, _ = compute_sky_visibility(tracer, scene, patches=tregenza_patches(), samples=64, adaptive=False)
    ours = float(product.exposure[product.face_prim == scene.prim_paths.index("/World/Floor")].mean())
    read = stage_triangles(stage)
    theirs = radiance_scene.uniform_sky_irradiance(read.triangles, np.zeros(len(read.triangles)),
                                                   np.array([[0.5, 0.5, 0.0]]), np.array([[0.0, 0.0, 1.0]]),
                                                   transmittance=read.transmittance, radiance=1.0, ambient_bounces=0,
                                                   ambient_divisions=65536, ground=False, offset=1e-3)
    theirs = float(theirs[0] @ RGB_LUMINANCE) / np.pi
    figures.update({"glazing_sky_usdbake": round(ours, 4), "glazing_sky_radiance": round(theirs, 4),
                    "glazing_sky_error": round(abs(ours / theirs - 1), 4)})
    return figures


def large_room_figures(faces: int) -> dict:
    """100k faces x 8760 hours with bounces, and one relit time with bounces."""
    weather = read_weather(tmy3())
    scene = extract_scene(room_stage(faces))
    tracer = Tracer.from_scene(scene)
    product, _ = compute_sky_visibility(tracer, scene, patches=tregenza_patches(), samples=4, adaptive=False)
    started = time.perf_counter()
    inter, stats = compute_interreflection(tracer, scene, product)
    interreflection_seconds = time.perf_counter() - started
    with harness.measure() as m:
        compute_annual_daylight(tracer, scene, product, weather, interreflection=inter)
    latitude = weather.latitude
    table = sun_table(tracer, product, latitude=latitude)
    relighter = DaylightRelighter(product, table, latitude=latitude, longitude=weather.longitude,
                                  timezone=weather.timezone, albedo=scene.tri_albedo[product.face_source],
                                  interreflection=inter)
    seconds = []
    for hour in np.flatnonzero(weather.diffuse_horizontal > 0)[::180][:48]:
        started = time.perf_counter()
        relighter.at(weather.times[hour], sky="perez", direct_normal=float(weather.direct_normal[hour]),
                     diffuse_horizontal=float(weather.diffuse_horizontal[hour]))
        seconds.append(time.perf_counter() - started)
    return {"faces": int(product.num_faces), "annual_with_bounces_seconds": round(m.seconds, 2),
            "annual_with_bounces_peak_mb": round(m.peak_mb, 1),
            "interreflection_seconds": round(interreflection_seconds, 2),
            "interreflection_gather_seconds": round(stats["gather_s"], 2), "patches": int(stats["patches"]),
            "relight_with_bounces_ms_median": round(1000 * float(np.median(seconds)), 2),
            "relight_with_bounces_ms_max": round(1000 * float(np.max(seconds)), 2)}


def run(quick: bool = False) -> dict:
    from . import radiance_binaries

    with_radiance = not quick and radiance_binaries.radiance_available()
    figures = office_figures(with_radiance)
    figures.update(glazing_figures(with_radiance))
    if with_radiance:
        figures.update(furnished_figures())
    figures.update(large_room_figures(10_000 if quick else 100_000))
    columns = [c for c in ("office_usdbake_seconds", "office_radiance_seconds", "office_speedup",
                           "office_radiance_seconds_at_equal_error", "office_speedup_at_equal_error",
                           "office_fine_seconds", "office_fine_error", "office_speedup_at_equal_error_fine",
                           "office_mean_illuminance_median_abs_error", "office_mean_illuminance_bias",
                           "office_df_median_abs_error", "office_sda_usdbake", "office_sda_radiance",
                           "office_ase_usdbake", "office_ase_radiance") if c in figures]
    table = harness.markdown_table([figures], columns)
    if "room_median_abs_error" in figures:
        table += "\n\n" + harness.markdown_table([figures], [
            "room_points", "room_median_abs_error", "room_bias", "room_mean_ratio",
            "room_interreflected_share_radiance", "room_usdbake_seconds", "room_radiance_seconds"])
    table += "\n\n" + harness.markdown_table([figures], [
        "faces", "annual_with_bounces_seconds", "annual_with_bounces_peak_mb", "interreflection_seconds",
        "patches", "relight_with_bounces_ms_median", "relight_with_bounces_ms_max"])
    table += "\n\n" + harness.markdown_table([figures], [c for c in (
        "glazing_sun_vs_vlt_error", "glazing_sky_usdbake", "glazing_sky_radiance", "glazing_sky_error") if c in figures])
    error = figures.get("office_mean_illuminance_median_abs_error", 0.0)
    return harness.result(NAME, description=DESCRIPTION, settings={"quick": quick},
                          points=[{"label": "defaults", "seconds": figures["office_usdbake_seconds"], "error": error,
                                   "default": True}],
                          figures=figures, table=table, knob="defaults",
                          error_label="office mean illuminance, median |relative error| vs Radiance")
