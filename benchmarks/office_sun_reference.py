"""The LM-83 office's direct sunlight with a sharp sun (``radiance_sun``), its ASE, and the two-phase smeared sun
of ``daylight_references.office_reference`` for comparison (issue 29).

IES LM-83's ASE_{1000,250}: the share of sensors that receive direct sunlight (no sky, no interreflections) of
at least 1000 lux for at least 250 occupied hours of the year, occupied = local standard time 8:00-18:00
(``bench_daylight_bounces.OCCUPIED``: the mid-hour stamps 8.5 .. 17.5, ten hours a day).

``office_sun_reference`` computes the reference once per settings and caches it
(``harness.cached_reference``, benchmarks/cache/daylight_office_sun-<key>.npz): the sun as a 0.533-degree
source at each Reinhart MF:6 patch centre, the pane as Radiance ``glass`` of VLT 0.6, gendaymtx -5 0.533 -d -O0
(visible) on the Greensboro TMY3 file pvlib ships. ``office_smeared_sun`` is the two-phase figure the office
benchmark used before: ``office_reference``'s direct-only daylight coefficients (MF:4) times gendaymtx -d (the sun
spread over the 4 nearest MF:4 patches). ``python -m usdbake.benchmarks.office_sun_reference`` prints both.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import harness

OCCUPIED = (8.0, 18.0)
"""Local standard time, hours: occupied when the mid-hour stamp lies in [8, 18)."""
LUX_THRESHOLD = 1000.0
HOURS_THRESHOLD = 250
SUN_REFERENCE_VERSION = 1
"""Bump when the method of ``radiance_sun`` changes (part of the cache key)."""


def occupied_hours(times: np.ndarray, occupied: tuple[float, float] = OCCUPIED) -> np.ndarray:
    """(H,) bool: the hour-of-day of ``times`` (datetime64, local standard time) lies in [occupied)."""
    times = np.asarray(times).astype("datetime64[m]")
    hour = (times - times.astype("datetime64[D]")).astype(np.float64) / 60.0
    return (hour >= occupied[0]) & (hour < occupied[1])


def ase(lux: np.ndarray, times: np.ndarray, occupied: tuple[float, float] = OCCUPIED,
        lux_threshold: float = LUX_THRESHOLD, hours: int = HOURS_THRESHOLD) -> tuple[np.ndarray, float]:
    """(sun_hours (S,) int64, share): per sensor the occupied hours with direct-sun illuminance >= ``lux_threshold``
    (``lux`` (H, S), ``times`` (H,)), and the share of sensors with ``sun_hours >= hours`` (ASE as a fraction)."""
    lux = np.asarray(lux)
    sun_hours = (lux[occupied_hours(times, occupied)] >= lux_threshold).sum(axis=0).astype(np.int64)
    return sun_hours, float((sun_hours >= hours).mean())


def office_sun_reference(scene=None, *, mf: int = 6, weather_path: str | None = None, offset: float = 0.0,
                         processes: int | None = None) -> dict:
    """The office's hourly direct-sun illuminance, sharp sun (``radiance_sun.direct_sun_illuminance``), cached.

    ``scene``: ``daylight_scenes.lm83_office()`` by default (its 170 floor sensors, 1 mm above the floor, are
    traced as they are: ``offset`` 0, as ``office_reference``). Returns arrays: ``sensor_points``,
    ``sensor_normals`` (S, 3); ``times`` (H,) datetime64[m] mid-hour local standard time; ``illuminance`` (H, S)
    float64 lux; ``dc_sun`` (S, P, 3) float32 (irradiance per unit direct normal irradiance of the sun at each
    MF:``mf`` patch centre); ``sun_patches``, ``sun_hours_index`` (N,) int64 and ``sun_direct_normal`` (N, 3)
    (the sparse sun matrix: visible-equivalent W/m^2); ``rcontrib_seconds``, ``rcontrib_cpu_seconds``,
    ``gendaymtx_seconds``, ``seconds`` (wall, when first computed), ``processes``; ``command``,
    ``gendaymtx_command`` (0-d str).
    """
    from . import radiance_sky as rsky
    from . import radiance_sun as rs
    from .daylight_references import scene_fingerprint
    from .daylight_scenes import SCENES_VERSION, lm83_office

    scene = scene if scene is not None else lm83_office()
    weather_path = str(weather_path or rsky._tmy3_example())
    settings = {"scene": "lm83_office", "version": SCENES_VERSION, "fingerprint": scene_fingerprint(scene),
                "method": "sharp sun: rcontrib -ab 0 suns at MF patch centres x gendaymtx -5 0.533 -d -O0",
                "sun_version": SUN_REFERENCE_VERSION, "mf": mf, "offset": offset,
                "weather": Path(weather_path).name}

    def compute() -> dict:
        timings: dict = {}
        times, lux, dc, sun = rs.direct_sun_illuminance(
            scene.triangles, scene.albedo, scene.transmittance, scene.sensor_points, scene.sensor_normals,
            weather_path, mf=mf, offset=offset, processes=processes, timings=timings, return_coefficients=True)
        return {"sensor_points": scene.sensor_points, "sensor_normals": scene.sensor_normals, "times": times,
                "illuminance": lux, "dc_sun": dc.astype(np.float32), "sun_patches": sun.patches,
                "sun_hours_index": sun.hours, "sun_direct_normal": sun.direct_normal,
                "rcontrib_seconds": np.float64(timings["rcontrib_seconds"]),
                "rcontrib_cpu_seconds": np.float64(timings["rcontrib_cpu_seconds"]),
                "gendaymtx_seconds": np.float64(timings["gendaymtx_seconds"]),
                "seconds": np.float64(timings["seconds"]), "processes": np.int64(timings["processes"]),
                "command": np.str_(timings["command"]), "gendaymtx_command": np.str_(timings["gendaymtx_command"])}

    return harness.cached_reference("daylight_office_sun", settings, compute)


def office_smeared_sun(scene=None, *, weather_path: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(times (H,), lux (H, S)): the office's direct sun as the two-phase reference has it: ``office_reference``'s
    direct-only daylight coefficients (``dc_direct``, MF:4, cached; computed if not, minutes) times gendaymtx's
    sun-only matrix (``-d``, sun over the 4 nearest MF:4 patches, ``-O0``)."""
    from . import radiance_reference as rr
    from . import radiance_sky as rsky
    from .daylight_references import office_reference
    from .daylight_scenes import lm83_office

    scene = scene if scene is not None else lm83_office()
    weather_path = str(weather_path or rsky._tmy3_example())
    reference = office_reference(scene, weather_path=weather_path)
    times, sun_only = rsky.annual_sky_matrix(weather_path, mf=4, output="visible", ground_reflectance=0.0,
                                             sun_only=True)
    return times, rr.illuminance_from(reference["dc_direct"], sun_only)


def _summary(label: str, lux: np.ndarray, times: np.ndarray) -> str:
    hours, share = ase(lux, times)
    p10, p50, p90 = np.percentile(hours, [10, 50, 90])
    return (f"{label}: ASE {share:.4f} ({int((hours >= HOURS_THRESHOLD).sum())} of {len(hours)} sensors), "
            f"sun hours p10 / p50 / p90 {p10:.0f} / {p50:.0f} / {p90:.0f}")


if __name__ == "__main__":
    import sys

    processes = int(sys.argv[1]) if len(sys.argv) > 1 else None
    sharp = office_sun_reference(processes=processes)
    print(_summary("sharp sun (MF:6 suns, rcontrib -ab 0)", sharp["illuminance"], sharp["times"]))
    print(f"  rcontrib {float(sharp['rcontrib_seconds']):.1f} s wall ({int(sharp['processes'])} processes), "
          f"gendaymtx {float(sharp['gendaymtx_seconds']):.1f} s, all {float(sharp['seconds']):.1f} s")
    times, smeared = office_smeared_sun()
    print(_summary("smeared sun (two-phase, MF:4, 4 patches)", smeared, times))
