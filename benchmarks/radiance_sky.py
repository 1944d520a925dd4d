"""Radiance's annual sky: weather file -> ``.wea`` -> gendaymtx sky matrix, and the patches its rows stand for.

Part of the independent Radiance reference (``radiance_reference``): the weather file is read with pvlib,
written to a Radiance ``.wea`` file, and the rest is Radiance (gendaymtx through ``pyradiance``); nothing here
imports usdbake's own sky or solar code.

Weather and sky matrix
----------------------
1. Weather: ``pvlib.iotools.read_tmy3`` (NREL TMY3 CSV) or ``read_epw`` (EPW)
   -> ``.wea`` (``write_wea``): header ``place City_Region`` (gendaymtx needs
   the underscore), ``latitude`` (deg north), ``longitude`` (deg **west**
   positive: the negated file value), ``time_zone`` (deg **west** positive:
   -15 * UTC offset in hours), ``site_elevation`` (m),
   ``weather_data_file_units 1`` (DNI, DHI in W/m^2), then one row per hour
   ``month day hour DNI DHI`` with the hour at the middle of the hour (both
   formats stamp the hour *ending*: 01:00 .. 24:00 -> 0.5 .. 23.5, same day).
   29 February is dropped (8760 rows).
2. Sky matrix: ``gendaymtx -m MF [-r north] [-O0|-O1] [-g g g g] [-s|-d] -h -of sky.wea``
   through ``pyradiance.gendaymtx``: the Perez all-weather sky per hour,
   rows in Radiance order (below).

Patch order (Radiance's, identical in gendaymtx rows and reinhart.cal bins)
--------------------------------------------------------------------------
Row/bin 0 is the **ground** (every direction below the horizon, a uniform
radiance ``g * E_global_horizontal / pi`` with ``g`` = ``ground_reflectance``,
0.2 by default). Rows 1 .. Nrbins-1 are the sky patches of Reinhart MF:mf
(Tregenza for mf = 1: 145 patches, 146 rows in all; 577 + 1 for mf = 2; 2305 +
1 for mf = 4), ring by ring from the horizon up, each ring starting at north
(patch centred on azimuth 0) and going **east** (clockwise seen from above),
the zenith cap last. Azimuth is atan2(x, y): x = east, y = north, z = up. So
Radiance row p + 1 is usdbake's ``reinhart_patches`` patch p.
``reinhart_patches`` / ``cie_overcast_sky`` give the rows' directions and solid angles (from reinhart.cal)
and the CIE overcast sky over them, for daylight factors from the coefficients.

Units
-----
``annual_sky_matrix`` returns radiance per patch in W/(m^2 sr), RGB. With
``output='visible'`` (``-O0``, the default, what daylighting studies use)
these are visible-equivalent watts: the Perez luminous-efficacy model turns
DNI/DHI into illuminance and Radiance divides by 179 lm/W, so 179 * luminance
gives cd/m^2. With ``output='solar'`` (``-O1``) they are solar watts:
179 * (DHI + DNI cos z) exactly reproduces the weather file's global horizontal
irradiance at 179 lm/W; use this one to compare with a model that, like
usdbake's ``processors/daylight/sky_matrix.py``, scales the sky to the file's DHI. A .wea
carries no dew point, so gendaymtx's luminous efficacy (``-O0`` only) uses its
default 11 degC dew point. The sky colour is gendaymtx's default (0.96, 1.004,
1.118), whose luminance weight is 1.000.

The sun
-------
gendaymtx spreads each hour's direct sun over the 4 patches nearest the sun
(weights 1/(1.002 - cos angle)), dividing by the patch solid angle: the
two-phase method. This differs from a sun-ray method (usdbake traces the sun
separately) by this smearing: shadows of the sun are soft over ~a patch width
(12 degrees for Tregenza), and cos(incidence) is taken at patch centres.
``sky_only=True`` (``gendaymtx -s``) drops the sun; the diffuse sky alone is
the cleaner comparison for a processor that handles the sun separately.

North
-----
``north`` (degrees) turns north counter-clockwise about the up axis, seen from above, as usdbake's
``north`` parameter; it is applied to the sky with ``gendaymtx -r north``
(which rotates the sun, hence the whole sky, counter-clockwise). The scene's own frame: ``radiance_scene``.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .radiance_binaries import _pyradiance

TREGENZA_ROWS = 146

_CUMULATIVE_DAYS = np.array([0, 31, 59, 90, 120, 151, 181, 212, 243, 273, 304, 334])


# --------------------------------------------------------------------------- weather


@dataclass(frozen=True)
class WeatherRows:
    """The hourly rows of a typical year as written to the .wea file."""

    place: str
    latitude: float
    """Degrees north."""
    longitude: float
    """Degrees **east** (as in the weather file; the .wea gets the negation)."""
    timezone: float
    """Hours east of UTC (as in the weather file; the .wea gets -15 times it)."""
    elevation: float
    month: np.ndarray
    day: np.ndarray
    hour: np.ndarray
    """Local standard time at the middle of the hour, 0.5 .. 23.5."""
    direct_normal: np.ndarray
    diffuse_horizontal: np.ndarray

    @property
    def times(self) -> np.ndarray:
        """(H,) datetime64[m]: local standard time at mid-hour, in the non-leap year 2025."""
        days = _CUMULATIVE_DAYS[self.month - 1] + self.day - 1
        minutes = np.rint((days * 24 + self.hour) * 60).astype(np.int64)
        return np.datetime64("2025-01-01T00:00", "m") + minutes.astype("timedelta64[m]")


def read_weather_rows(weather_path: str | os.PathLike) -> WeatherRows:
    """Hourly DNI/DHI and site of an EPW (``.epw``) or TMY3 CSV file, read with pvlib."""
    from pvlib import iotools

    path = Path(weather_path)
    if path.suffix.lower() == ".epw":
        frame, meta = iotools.read_epw(str(path))
        month = frame["month"].to_numpy(int)
        day = frame["day"].to_numpy(int)
        hour_end = frame["hour"].to_numpy(float)  # hour ending, 1..24 (minute field ignored)
        place = f"{str(meta.get('city', 'site')).strip()}_{str(meta.get('country', '')).strip()}"
    else:
        frame, meta = iotools.read_tmy3(str(path), map_variables=True)
        mdy = frame["Date (MM/DD/YYYY)"].str.split("/")
        month = mdy.str[0].astype(int).to_numpy()
        day = mdy.str[1].astype(int).to_numpy()
        hm = frame["Time (HH:MM)"].str.split(":")
        hour_end = hm.str[0].astype(int).to_numpy() + hm.str[1].astype(int).to_numpy() / 60.0
        place = f"{str(meta.get('Name', 'site')).strip().strip(chr(34))}_{str(meta.get('State', '')).strip()}"
    keep = ~((month == 2) & (day == 29))
    place = "".join(c if (c.isalnum() or c in "-_") else "-" for c in place)
    if "_" not in place:
        place += "_site"
    return WeatherRows(
        place=place,
        latitude=float(meta["latitude"]),
        longitude=float(meta["longitude"]),
        timezone=float(meta["TZ"]),
        elevation=float(meta["altitude"]),
        month=month[keep],
        day=day[keep],
        hour=(hour_end - 0.5)[keep],
        direct_normal=frame["dni"].to_numpy(float)[keep],
        diffuse_horizontal=frame["dhi"].to_numpy(float)[keep],
    )


def write_wea(weather_path: str | os.PathLike, wea_path: str | os.PathLike) -> WeatherRows:
    """Convert an EPW / TMY3 CSV file to a Radiance .wea (W/m^2, DNI and DHI); returns the rows written."""
    rows = read_weather_rows(weather_path)
    lines = [
        f"place {rows.place}",
        f"latitude {rows.latitude:.4f}",
        f"longitude {-rows.longitude:.4f}",  # Radiance: degrees WEST positive
        f"time_zone {-15.0 * rows.timezone:.1f}",  # standard meridian, degrees WEST positive
        f"site_elevation {rows.elevation:.1f}",
        "weather_data_file_units 1",  # 1: direct normal + diffuse horizontal irradiance, W/m^2
    ]
    lines += [f"{m:d} {d:d} {h:.3f} {dn:.1f} {df:.1f}" for m, d, h, dn, df in
              zip(rows.month, rows.day, rows.hour, rows.direct_normal, rows.diffuse_horizontal)]
    Path(wea_path).write_text("\n".join(lines) + "\n")
    return rows


# --------------------------------------------------------------------------- sky matrix


def _reinhart_rows(mf: int) -> int:
    return 144 * mf * mf + 2  # sky patches (incl. zenith) + ground


def gendaymtx_command(wea_path: str, *, mf: int = 1, north: float = 0.0, output: str = "visible",
                      ground_reflectance: float = 0.2, sky_only: bool = False, sun_only: bool = False) -> list[str]:
    """The gendaymtx command line ``annual_sky_matrix`` runs (for reports)."""
    cmd = ["gendaymtx", "-m", str(mf)]
    if sun_only:
        cmd.append("-d")
    elif sky_only:
        cmd.append("-s")
    if not sun_only:
        cmd += ["-g", *(f"{ground_reflectance:g}",) * 3]
    cmd.append("-O1" if output == "solar" else "-O0")
    if north:
        cmd += ["-r", f"{north:g}"]
    cmd += ["-h", "-of", str(wea_path)]
    return cmd


def annual_sky_matrix(weather_path: str | os.PathLike, *, mf: int = 1, north: float = 0.0,
                      output: str = "visible", ground_reflectance: float = 0.2, sky_only: bool = False,
                      sun_only: bool = False, workdir: str | os.PathLike | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(times, matrix): Radiance's Perez all-weather sky matrix for every hour of the year.

    ``times`` (H,) datetime64[m], local standard time at the middle of each hour (year 2025,
    H = 8760). ``matrix`` (P, H, 3) float32 RGB radiance per patch, W/(m^2 sr) (``output``:
    'visible' = ``-O0`` visible-equivalent watts, 179 lm/W; 'solar' = ``-O1`` solar watts),
    P = 144 mf^2 + 2 rows in Radiance order: row 0 the ground, rows 1.. the Reinhart MF:mf sky
    patches (Tregenza for mf = 1: 145), horizon ring first, each ring from north towards east,
    zenith last. Night hours are zero columns. The sun is included in the patches (4 nearest)
    unless ``sky_only``; ``sun_only`` gives the sun alone (no sky, no ground).
    """
    if output not in ("visible", "solar"):
        raise ValueError(f"output {output!r} is not 'visible' or 'solar'")
    pr = _pyradiance()
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        wea = os.path.join(tmp, "sky.wea")
        rows = write_wea(weather_path, wea)
        data = pr.gendaymtx(
            wea, mfactor=mf, header=False, outform="f", solar_radiance=(output == "solar"),
            sky_only=sky_only and not sun_only, sun_only=sun_only,
            ground_color=None if sun_only else [ground_reflectance] * 3,
            rotate=north if north else None)
    nrows, hours = _reinhart_rows(mf), len(rows.month)
    matrix = np.frombuffer(data, dtype=np.float32)
    if matrix.size != nrows * hours * 3:
        raise RuntimeError(f"gendaymtx wrote {matrix.size} floats, expected {nrows} x {hours} x 3")
    return rows.times, matrix.reshape(nrows, hours, 3).copy()


def reinhart_patches(mf: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) float64 unit ENU centre directions and (P,) solid angles (sr) of Radiance's rows, ground first:
    row 0 the ground (direction (0, 0, -1), 2 pi sr), then reinhart.cal's MF:mf sky patches (rings of
    alpha = 90 / (7 mf + 0.5) degrees from the horizon up, ``mf`` x (30, 30, 24, 24, 18, 12, 6) patches per
    Tregenza ring, patch j of a ring centred on azimuth j 360 / n from north towards east; the zenith cap
    last). Written from reinhart.cal, not from usdbake's sky code."""
    alpha = np.radians(90.0 / (7 * mf + 0.5))
    counts = [mf * n for n in (30, 30, 24, 24, 18, 12, 6) for _ in range(mf)]
    dirs, omegas = [np.array([0.0, 0.0, -1.0])], [2.0 * np.pi]
    for r, n in enumerate(counts):
        alt = (r + 0.5) * alpha
        az = np.arange(n) * 2.0 * np.pi / n
        dirs += list(np.column_stack([np.cos(alt) * np.sin(az), np.cos(alt) * np.cos(az), np.full(n, np.sin(alt))]))
        omegas += [2.0 * np.pi * (np.sin((r + 1) * alpha) - np.sin(r * alpha)) / n] * n
    dirs.append(np.array([0.0, 0.0, 1.0]))
    omegas.append(2.0 * np.pi * (1.0 - np.sin(len(counts) * alpha)))
    return np.array(dirs), np.array(omegas)


def cie_overcast_sky(mf: int = 1, *, ground_reflectance: float = 0.2) -> tuple[np.ndarray, float]:
    """(P,) CIE overcast radiance per Radiance row (zenith radiance 1: L = (1 + 2 sin altitude) / 3 at each
    patch centre; row 0 the ground, ``ground_reflectance`` x E_h / pi as gensky -c and gendaymtx) and E_h,
    the unobstructed horizontal irradiance of the same patches: daylight factor = 100 DC @ sky / E_h."""
    dirs, omegas = reinhart_patches(mf)
    sky = (1.0 + 2.0 * dirs[:, 2]) / 3.0
    e_h = float(np.sum((sky * omegas * dirs[:, 2])[1:]))
    sky[0] = ground_reflectance * e_h / np.pi
    return sky, e_h


def _tmy3_example() -> str:
    import pvlib

    return os.path.join(os.path.dirname(pvlib.__file__), "data", "723170TYA.CSV")
