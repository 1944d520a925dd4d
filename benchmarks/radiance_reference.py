"""Independent Radiance reference for annual (climate-based) daylight illuminance.

A two-phase daylight-coefficient calculation with the Radiance binaries bundled
in ``pyradiance`` (``pip install pyradiance``), used to validate usdbake's
``annual_daylight`` processor in benchmarks. Nothing here imports usdbake's own
sky or solar code: the weather file is read with pvlib, written to a Radiance
``.wea`` file, and the rest is Radiance.

Pipeline
--------
1. Weather: EPW / TMY3 CSV -> ``.wea`` (``radiance_sky.write_wea``).
2. Sky matrix: gendaymtx's Perez all-weather sky per hour (``radiance_sky.annual_sky_matrix``; its
   docstring: patch order, units, the sun, north).
3. Daylight coefficients: rcontrib over the geometry (``radiance_scene.daylight_coefficients``; its
   docstring: bounces, glass, colour, seeds, timings, frames).
4. Illuminance (here, ``illuminance_from``): E[h, s] = 179 * sum_c w_c sum_p DC[s, p, c] * sky[p, h, c],
   w = (0.265, 0.670, 0.065) (Radiance's RGB luminance weights, 179 lm/W its
   luminous efficacy of "visible-equivalent" watts).

``annual_illuminance`` runs the four; the self-check (``horizontal_check_details``, ``python -m
usdbake.benchmarks.radiance_reference [weather]``) compares an unobstructed upward sensor with
179 (DHI + DNI cos z) of the weather file. The binaries: ``radiance_binaries``.
"""

from __future__ import annotations

import os
import time

import numpy as np

from .radiance_binaries import radiance_available
from .radiance_scene import daylight_coefficients, rcontrib_command
from .radiance_sky import _tmy3_example, annual_sky_matrix, gendaymtx_command, read_weather_rows

LUMINOUS_EFFICACY = 179.0
"""lm/W of Radiance's visible-equivalent watt (WHTEFFICACY)."""
RGB_LUMINANCE = np.array([0.265, 0.670, 0.065])
"""Radiance's RGB -> luminance weights (``bright()`` with its default primaries)."""


# --------------------------------------------------------------------------- two-phase illuminance


def illuminance_from(dc: np.ndarray, sky: np.ndarray) -> np.ndarray:
    """(H, S) lux = 179 * luminance(DC (S, P, 3) @ sky (P, H, 3)) per channel."""
    total = np.zeros((sky.shape[1], dc.shape[0]))
    for c in range(3):
        total += RGB_LUMINANCE[c] * (sky[:, :, c].T.astype(np.float64) @ dc[:, :, c].T)
    return LUMINOUS_EFFICACY * total


def annual_illuminance(triangles: np.ndarray | None, albedo: np.ndarray | None, sensors: np.ndarray,
                       normals: np.ndarray, weather_path: str | os.PathLike, *, up: str = "Z", mf: int = 1,
                       north: float = 0.0, ambient_bounces: int = 0, ambient_divisions: int = 16384,
                       limit_weight: float | None = None, output: str = "visible",
                       ground_reflectance: float = 0.2, sky_only: bool = False, offset: float = 0.0,
                       processes: int | None = None, return_times: bool = False,
                       transmittance: np.ndarray | None = None, seed: int | None = None,
                       timings: dict | None = None):
    """(H, S) float64 illuminance in lux at each sensor for every hour of the weather file's year.

    Two-phase: ``daylight_coefficients`` (rcontrib, ``-ab ambient_bounces + 1``) times
    ``annual_sky_matrix`` (gendaymtx, sun in the patches unless ``sky_only``), 179 lm/W. See the
    docstrings of ``radiance_scene`` (frames, the meaning of ``ambient_bounces``) and ``radiance_sky`` (units). With
    ``return_times`` returns (times (H,) datetime64[m] mid-hour local standard time, E). ``timings``
    receives ``radiance_seconds`` (rcontrib), ``sky_matrix_seconds`` (gendaymtx) and ``seconds`` (all).
    """
    started = time.perf_counter()
    times, sky = annual_sky_matrix(weather_path, mf=mf, north=north, output=output,
                                   ground_reflectance=ground_reflectance, sky_only=sky_only)
    sky_seconds = time.perf_counter() - started
    dc = daylight_coefficients(triangles, albedo, sensors, normals, up=up, mf=mf,
                               ambient_bounces=ambient_bounces, ambient_divisions=ambient_divisions,
                               limit_weight=limit_weight, offset=offset, processes=processes,
                               transmittance=transmittance, seed=seed, timings=timings)
    e = illuminance_from(dc, sky)
    if timings is not None:
        timings.update(sky_matrix_seconds=sky_seconds, seconds=time.perf_counter() - started)
    return (times, e) if return_times else e


# --------------------------------------------------------------------------- self-check


def global_horizontal_reference(weather_path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """(times, lux): 179 * (DHI + DNI max(0, cos zenith)) from the weather file, the zenith from
    pvlib's solar position (geometric, no refraction) at the middle of each hour."""
    import pandas as pd
    from pvlib import solarposition

    rows = read_weather_rows(weather_path)
    tz = f"Etc/GMT{-int(rows.timezone):+d}" if rows.timezone == int(rows.timezone) else None
    local = pd.DatetimeIndex(rows.times.astype("datetime64[ns]"))
    when = local.tz_localize(tz) if tz else (local - pd.Timedelta(hours=rows.timezone)).tz_localize("UTC")
    sun = solarposition.get_solarposition(when, rows.latitude, rows.longitude, altitude=rows.elevation)
    cosz = np.maximum(0.0, np.cos(np.radians(sun["zenith"].to_numpy())))
    return rows.times, LUMINOUS_EFFICACY * (rows.diffuse_horizontal + rows.direct_normal * cosz)


def horizontal_check_details(weather_path: str | os.PathLike, *, output: str = "solar", mf: int = 1,
                             ambient_divisions: int = 16384, min_lux: float = 1790.0) -> dict:
    """Unobstructed upward sensor (no geometry) against 179 (DHI + DNI cos z); see the return keys."""
    t0 = time.perf_counter()
    times, e = annual_illuminance(None, None, np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), weather_path,
                                  mf=mf, output=output, ambient_divisions=ambient_divisions, return_times=True)
    seconds = time.perf_counter() - t0
    _, ref = global_horizontal_reference(weather_path)
    e = e[:, 0]
    lit = ref >= min_lux
    rel = (e[lit] - ref[lit]) / ref[lit]
    return {
        "output": output,
        "hours_compared": int(lit.sum()),
        "mean_relative_difference": float(rel.mean()),
        "mean_abs_relative_difference": float(np.abs(rel).mean()),
        "annual_sum_relative_difference": float(e.sum() / ref.sum() - 1.0),
        "max_abs_relative_difference": float(np.abs(rel).max()),
        "annual_radiance_klxh": float(e.sum() / 1000.0),
        "annual_reference_klxh": float(ref.sum() / 1000.0),
        "seconds": seconds,
    }


def unobstructed_horizontal_check(weather_path: str | os.PathLike, *, output: str = "solar",
                                  min_lux: float = 1790.0) -> float:
    """Mean relative difference (E_radiance - E_ref) / E_ref over the hours with E_ref >= ``min_lux``
    (10 W/m^2) for one upward sensor with no geometry, E_ref = 179 (DHI + DNI cos z) of the same file.

    With ``output='solar'`` (``-O1``) both sides use 179 lm/W, so the difference is Radiance's sun
    smearing over patches, sun position and Monte-Carlo noise; with ``'visible'`` it is the Perez
    luminous efficacy relative to 179 lm/W as well.
    """
    return horizontal_check_details(weather_path, output=output, min_lux=min_lux)["mean_relative_difference"]


if __name__ == "__main__":
    import sys

    weather = sys.argv[1] if len(sys.argv) > 1 else _tmy3_example()
    if not radiance_available():
        sys.exit("pyradiance / Radiance binaries not available: pip install pyradiance")
    print(f"weather: {weather}")
    print("gendaymtx:", " ".join(gendaymtx_command("sky.wea", output="solar")))
    print("rcontrib: ", " ".join(rcontrib_command("scene.oct", processes=os.cpu_count() or 1)), "< sensors")
    for out in ("solar", "visible"):
        d = horizontal_check_details(weather, output=out)
        print(f"unobstructed horizontal, {out:7s}: mean rel. diff {d['mean_relative_difference']:+.4f}, "
              f"mean |rel| {d['mean_abs_relative_difference']:.4f}, annual sum {d['annual_sum_relative_difference']:+.4f} "
              f"over {d['hours_compared']} h ({d['seconds']:.1f} s)")
