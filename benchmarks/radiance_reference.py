"""Independent Radiance reference for annual (climate-based) daylight illuminance.

A two-phase daylight-coefficient calculation with the Radiance binaries bundled
in ``pyradiance`` (``pip install pyradiance``), used to validate usdbake's
``annual_daylight`` processor in benchmarks. Nothing here imports usdbake's own
sky or solar code: the weather file is read with pvlib, written to a Radiance
``.wea`` file, and the rest is Radiance.

Pipeline
--------
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
3. Daylight coefficients: the geometry as ``polygon``s with grey ``plastic``
   materials plus a full-sphere glow source ``skyglow``, and
   ``rcontrib -h -faf -I+ -ab AB -ad AD -lw LW -n N -e MF:mf -f reinhart.cal
   -b rbin -bn Nrbins -m skyglow scene.oct < sensors`` (one line
   ``x y z nx ny nz`` per sensor): DC[s, p, c] = irradiance at sensor s per
   unit radiance of patch p (sr, cosine-weighted solid angle seen).
4. Illuminance: E[h, s] = 179 * sum_c w_c sum_p DC[s, p, c] * sky[p, h, c],
   w = (0.265, 0.670, 0.065) (Radiance's RGB luminance weights, 179 lm/W its
   luminous efficacy of "visible-equivalent" watts).

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

Bounces
-------
``ambient_bounces=0`` means the sky (and ground patch) as seen directly: rcontrib
``-ab 1`` (``-ab 0`` would give no sky at all, since the glow sky is reached
only by ambient sampling). The geometry then only occludes: whatever its
albedo, a hemisphere ray that hits it returns 0 (no further ambient bounce,
no light sources in the scene). ``ambient_bounces=n`` runs ``-ab n+1``: n
diffuse interreflections off the geometry, Monte-Carlo with ``-ad`` samples per
bounce (rcontrib never caches: ``-aa 0``). Plastic polygons reflect on both
sides.

Glass, colour, single skies, seeds, timings
-------------------------------------------
``write_scene`` takes a per-triangle ``transmittance`` (normal-incidence VLT; > 0 -> Radiance ``glass`` with
tn from the manual's conversion, ``glass_transmissivity``; ``glass_transmittance`` is glass's angular model
in float64) and grey (T,) or RGB (T, 3) albedo; ``daylight_coefficients`` and ``annual_illuminance`` pass
them through. ``uniform_sky_irradiance`` is ``rtrace -I`` under one uniform sky (above the horizon) with an
optional ground glow of gendaymtx's convention below it. Radiance has no seed option: ``seed`` traces
throw-away rays first (``_dummy_rays``) for an independent draw, to judge noise by two seeds. ``timings``
(a dict) receives the Radiance wall time of a call (``radiance_seconds``) and its command line.
``reinhart_patches`` / ``cie_overcast_sky`` give the rows' directions and solid angles (from reinhart.cal)
and the CIE overcast sky over them, for daylight factors from the coefficients.

Frames
------
``up='Z'``: Radiance coordinates = the input (x east, y north, z up). ``up='Y'``:
x east, -z north, y up (usdbake's ``enu_to_world('Y')``). ``north`` (degrees)
turns north counter-clockwise about the up axis, seen from above, as usdbake's
``north`` parameter; it is applied to the sky with ``gendaymtx -r north``
(which rotates the sun, hence the whole sky, counter-clockwise).
"""

from __future__ import annotations

import os
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

LUMINOUS_EFFICACY = 179.0
"""lm/W of Radiance's visible-equivalent watt (WHTEFFICACY)."""
RGB_LUMINANCE = np.array([0.265, 0.670, 0.065])
"""Radiance's RGB -> luminance weights (``bright()`` with its default primaries)."""
TREGENZA_ROWS = 146

_CUMULATIVE_DAYS = np.array([0, 31, 59, 90, 120, 151, 181, 212, 243, 273, 304, 334])


# --------------------------------------------------------------------------- availability


def _pyradiance():
    import pyradiance  # noqa: F401  (its import puts its bin/ on PATH and its lib/ on RAYPATH)

    return pyradiance


def _binary(name: str) -> str:
    from pyradiance.anci import BINPATH

    return str(Path(BINPATH) / name)


def radiance_available() -> bool:
    """True when pyradiance imports and its bundled gendaymtx, oconv and rcontrib run."""
    try:
        _pyradiance()
        for name in ("gendaymtx", "oconv", "rcontrib"):
            if not os.access(_binary(name), os.X_OK):
                return False
        probe = subprocess.run([_binary("rcontrib"), "-defaults"], capture_output=True, timeout=30)
        return probe.returncode == 0 and b"-ab" in probe.stdout
    except Exception:  # noqa: BLE001 - any failure means "not available"
        return False


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


# --------------------------------------------------------------------------- scene and daylight coefficients


def _to_radiance(points: np.ndarray, up: str) -> np.ndarray:
    """Stage coordinates -> Radiance's (east, north, up) (before the north turn, which is the sky's)."""
    points = np.asarray(points, np.float64)
    if up == "Z":
        return points.copy()
    if up == "Y":
        return np.stack([points[..., 0], -points[..., 2], points[..., 1]], axis=-1)
    raise ValueError(f"up axis {up!r} is not 'Y' or 'Z'")


GLASS_A, GLASS_B, GLASS_C = 0.8402528435, 0.0072522239, 0.9166530661
GLASS_D = 0.0036261119
"""Radiance's conversion of a glass pane's normal-incidence visible transmittance (VLT, 'tau') to the
``glass`` material's transmissivity tn (Radiance reference manual, ``glass``: tn = (sqrt(.8402528435 +
.0072522239 tau^2) - .9166530661) / .0036261119 / tau, for a 6 mm pane of refractive index 1.52)."""


def glass_transmissivity(vlt) -> np.ndarray:
    """Radiance ``glass`` transmissivity tn for a normal-incidence visible transmittance ``vlt`` in (0, 1]
    (array or scalar, float64): the pane then transmits ``vlt`` of normally incident light, both
    surfaces' Fresnel reflections included (VLT 0.88 -> tn 0.96, the manual's clear-glass example)."""
    vlt = np.asarray(vlt, np.float64)
    if np.any(~np.isfinite(vlt)) or np.any(vlt <= 0.0) or np.any(vlt > 1.0):
        raise ValueError("visible transmittance must lie in (0, 1]")
    return (np.sqrt(GLASS_A + GLASS_B * vlt * vlt) - GLASS_C) / GLASS_D / vlt


def glass_normal_transmittance(tn) -> np.ndarray:
    """The inverse: normal-incidence transmittance of Radiance ``glass`` of transmissivity ``tn`` (n = 1.52),
    from its two Fresnel surfaces and internal multiple reflections (the model ``glass`` implements)."""
    tn = np.asarray(tn, np.float64)
    r = ((1.52 - 1.0) / (1.52 + 1.0)) ** 2
    return (1.0 - r) ** 2 * tn / (1.0 - (r * tn) ** 2)


def _material_rows(albedo: np.ndarray, count: int) -> np.ndarray:
    """(T, 3) float64 RGB reflectance from a scalar, (T,) grey or (T, 3) RGB albedo."""
    albedo = np.asarray(albedo, np.float64)
    if albedo.ndim == 2 and albedo.shape[1] == 3:
        return np.broadcast_to(albedo, (count, 3))
    grey = np.broadcast_to(albedo.reshape(-1) if albedo.ndim else albedo, (count,))
    return np.repeat(grey[:, None], 3, axis=1)


def write_scene(path: str | os.PathLike, triangles: np.ndarray, albedo: np.ndarray, *, up: str = "Z",
                transmittance: np.ndarray | None = None) -> int:
    """Write triangles (T, 3, 3) as Radiance polygons; returns the triangles written.

    ``albedo``: a scalar, (T,) grey or (T, 3) RGB reflectance -> ``plastic`` (no specular, both sides
    reflect). ``transmittance``: None or (T,) normal-incidence visible transmittance; triangles with a
    value > 0 become ``glass`` (``glass_transmissivity``, the same tn in all three channels; their albedo is
    ignored), 0 keeps them opaque plastic.
    """
    tris = _to_radiance(np.asarray(triangles, np.float64).reshape(-1, 3, 3), up)
    rgb = _material_rows(albedo, len(tris))
    tau = np.zeros(len(tris)) if transmittance is None else np.broadcast_to(
        np.asarray(transmittance, np.float64).reshape(-1), (len(tris),))
    glazed = tau > 0.0
    area2 = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    keep = area2 > 1e-12  # oconv rejects degenerate polygons
    # One material per distinct (kind, r, g, b): glass rows carry tn, plastic rows the reflectance.
    keys = np.where(glazed[:, None], np.repeat(glass_transmissivity(np.where(glazed, tau, 1.0))[:, None], 3, 1), rgb)
    keys = np.column_stack([glazed, np.round(keys, 6)])
    values, index = np.unique(keys, axis=0, return_inverse=True)
    index = index.reshape(-1)
    out = []
    for k, (is_glass, r, g, b) in enumerate(values):
        if is_glass:
            out.append(f"void glass mat{k}\n0\n0\n3 {r:.6g} {g:.6g} {b:.6g}\n")
        else:
            out.append(f"void plastic mat{k}\n0\n0\n5 {r:.6g} {g:.6g} {b:.6g} 0 0\n")
    for i in np.flatnonzero(keep):
        v = tris[i]
        out.append(f"mat{index[i]} polygon t{i}\n0\n0\n9 " + " ".join(f"{c:.9g}" for c in v.ravel()) + "\n")
    Path(path).write_text("".join(out))
    return int(keep.sum())


SKY_RAD = """# every direction: one glow source; reinhart.cal bins it (bin 0 = below the horizon)
void glow skyglow
0
0
4 1 1 1 0

skyglow source skydome
0
0
4 0 0 1 360
"""


def rcontrib_command(octree: str, *, mf: int = 1, ambient_bounces: int = 0, ambient_divisions: int = 16384,
                     limit_weight: float | None = None, processes: int = 1) -> list[str]:
    """The rcontrib command line ``daylight_coefficients`` runs (sensors on stdin)."""
    lw = limit_weight if limit_weight is not None else 0.2 / ambient_divisions
    cmd = ["rcontrib", "-h", "-faf", "-I+", "-ab", str(ambient_bounces + 1), "-ad", str(ambient_divisions),
           "-lw", f"{lw:.3g}"]
    if processes > 1:
        cmd += ["-n", str(processes)]
    cmd += ["-e", f"MF:{mf}", "-f", "reinhart.cal", "-b", "rbin", "-bn", "Nrbins", "-m", "skyglow", octree]
    return cmd


def _children_cpu() -> float:
    """CPU seconds (user + system) of this process's finished children: Radiance's own time, robust to other
    load on the machine (its wall time on an idle machine is about this over the processes used)."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _run(cmd: list[str], **kwargs) -> bytes:
    cmd = [_binary(cmd[0])] + cmd[1:]
    done = subprocess.run(cmd, capture_output=True, **kwargs)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({done.returncode}): {done.stderr.decode(errors='replace')}")
    return done.stdout


def _sensor_rays(sensors: np.ndarray, normals: np.ndarray, up: str, offset: float,
                 dummies: int = 0) -> tuple[np.ndarray, str]:
    """(S, 3) Radiance-frame sensor positions (offset along the unit normals) and the ray lines, after
    ``dummies`` throw-away rays (``_dummy_rays``)."""
    sensors = _to_radiance(np.asarray(sensors, np.float64).reshape(-1, 3), up)
    normals = _to_radiance(np.asarray(normals, np.float64).reshape(-1, 3), up)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    sensors = sensors + offset * normals
    rays = DUMMY_RAY * dummies + "".join(f"{p[0]:.9g} {p[1]:.9g} {p[2]:.9g} {n[0]:.9g} {n[1]:.9g} {n[2]:.9g}\n"
                                         for p, n in zip(sensors, normals))
    return sensors, rays


DUMMY_RAY = "0 0 1e6 0 0 1\n"
"""A sensor far above any scene, facing up: its ambient sampling draws random numbers and hits nothing."""


def _dummy_rays(seed: int | None, processes: int) -> int:
    """Throw-away rays traced before the sensors for ``seed`` (0 or None: none). Radiance has no seed option:
    each rcontrib / rtrace process draws from the same fixed random stream (``-u+``) in ray order, so a run
    repeats exactly. Tracing 3 x seed x processes dummy sensors first (each draws ``-ad`` hemisphere samples
    or more) moves every process to another part of its stream: an independent Monte-Carlo draw per seed, for
    judging noise by the spread of two seeds."""
    return 0 if not seed else 3 * int(seed) * processes


def _octree(tmp: str, sky_text: str, triangles, albedo, transmittance, up: str) -> str:
    scene, sky, octree = (os.path.join(tmp, n) for n in ("scene.rad", "sky.rad", "scene.oct"))
    Path(sky).write_text(sky_text)
    inputs = [sky]
    if triangles is not None and len(np.asarray(triangles)):
        if write_scene(scene, triangles, albedo if albedo is not None else 0.0, up=up, transmittance=transmittance):
            inputs.append(scene)
    with open(octree, "wb") as f:
        f.write(_run(["oconv", *inputs]))
    return octree


def daylight_coefficients(triangles: np.ndarray | None, albedo: np.ndarray | None, sensors: np.ndarray,
                          normals: np.ndarray, *, up: str = "Z", mf: int = 1, ambient_bounces: int = 0,
                          ambient_divisions: int = 16384, limit_weight: float | None = None,
                          offset: float = 0.0, processes: int | None = None,
                          workdir: str | os.PathLike | None = None, transmittance: np.ndarray | None = None,
                          seed: int | None = None, timings: dict | None = None) -> np.ndarray:
    """(S, P, 3) float64 daylight coefficients: irradiance (W/m^2) at each sensor per unit radiance
    (W/(m^2 sr)) of each Radiance patch (row 0 ground, rows 1.. Reinhart MF:mf sky), i.e. sr.

    ``triangles`` (T, 3, 3) metres (None or empty: no geometry), ``albedo`` (T,) grey or (T, 3) RGB
    reflectance, ``transmittance`` None or (T,) glazing VLT (``write_scene``: > 0 -> Radiance ``glass``),
    ``sensors`` (S, 3) points, ``normals`` (S, 3) (normalised here), both in stage coordinates with
    the ``up`` axis; ``offset`` moves each sensor along its normal (metres) off its surface. ``seed``: trace
    ``_dummy_rays`` first: an independent Monte-Carlo draw per seed (None or 0: Radiance's own, repeatable).
    ``timings``: a dict that receives ``radiance_seconds`` (oconv + rcontrib wall time),
    ``radiance_cpu_seconds`` (their CPU time, all processes), ``processes`` and the ``command``.
    """
    _pyradiance()
    if processes is None:
        processes = max(1, min(os.cpu_count() or 1, len(np.asarray(sensors).reshape(-1, 3))))
    dummies = _dummy_rays(seed, processes)
    sensors, rays = _sensor_rays(sensors, normals, up, offset, dummies)
    command = rcontrib_command("scene.oct", mf=mf, ambient_bounces=ambient_bounces,
                               ambient_divisions=ambient_divisions, limit_weight=limit_weight, processes=processes)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        started, cpu = time.perf_counter(), _children_cpu()
        octree = _octree(tmp, SKY_RAD, triangles, albedo, transmittance, up)
        out = _run(command[:-1] + [octree], input=rays.encode(), cwd=tmp)
        seconds, cpu = time.perf_counter() - started, _children_cpu() - cpu
    if timings is not None:
        timings.update(radiance_seconds=seconds, radiance_cpu_seconds=cpu, processes=processes,
                       command=" ".join(command) + " < sensors")
    values = np.frombuffer(out, dtype=np.float32)
    nrows = _reinhart_rows(mf)
    if values.size != (dummies + len(sensors)) * nrows * 3:
        raise RuntimeError(f"rcontrib wrote {values.size} floats, expected {dummies + len(sensors)} x {nrows} x 3")
    return values.reshape(-1, nrows, 3)[dummies:].astype(np.float64)


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
    module docstring for frames, units and the meaning of ``ambient_bounces``. With
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


# --------------------------------------------------------------------------- single uniform sky (rtrace)


def uniform_sky_rad(radiance: float, ground_radiance: float | None) -> str:
    """A uniform glow of ``radiance`` over the upper hemisphere and, unless None, a uniform ground glow of
    ``ground_radiance`` over the lower one (both reached only by ambient rays: glows, not light sources)."""
    text = f"void glow skyglow\n0\n0\n4 {radiance:.9g} {radiance:.9g} {radiance:.9g} 0\n\n" \
           "skyglow source sky\n0\n0\n4 0 0 1 180\n"
    if ground_radiance is not None:
        g = ground_radiance
        text += f"\nvoid glow groundglow\n0\n0\n4 {g:.9g} {g:.9g} {g:.9g} 0\n\n" \
                "groundglow source ground\n0\n0\n4 0 0 -1 180\n"
    return text


def rtrace_irradiance_command(octree: str, *, ambient_bounces: int = 5, ambient_divisions: int = 4096,
                              limit_weight: float | None = None, processes: int = 1) -> list[str]:
    """The rtrace command line ``uniform_sky_irradiance`` runs (points and normals on stdin): irradiance
    (``-I+``), ``-ab ambient_bounces + 1``, pure Monte Carlo (``-aa 0``: no ambient cache, no interpolation,
    ``-as 0``), Russian roulette below ``-lw`` (default 0.2 / ``-ad``, as ``rcontrib_command``)."""
    lw = limit_weight if limit_weight is not None else 0.2 / ambient_divisions
    cmd = ["rtrace", "-h", "-faf", "-I+", "-ab", str(ambient_bounces + 1), "-ad", str(ambient_divisions),
           "-aa", "0", "-as", "0", "-lw", f"{lw:.3g}"]
    if processes > 1:
        cmd += ["-n", str(processes)]
    return cmd + [octree]


def uniform_sky_irradiance(triangles: np.ndarray | None, albedo: np.ndarray | None, points: np.ndarray,
                           normals: np.ndarray, *, transmittance: np.ndarray | None = None, radiance: float = 1.0,
                           ambient_bounces: int = 5, ambient_divisions: int = 4096,
                           limit_weight: float | None = None, ground: bool = True, ground_reflectance: float = 0.2,
                           up: str = "Z", offset: float = 0.0, processes: int | None = None, seed: int | None = None,
                           workdir: str | os.PathLike | None = None, timings: dict | None = None) -> np.ndarray:
    """(N, 3) float64 RGB irradiance (W/m^2) at points under a uniform sky, by ``rtrace -I``.

    The sky: radiance ``radiance`` W/(m^2 sr) in every direction above the horizon. Below it, with
    ``ground``, a uniform ground of radiance ``ground_reflectance * radiance``: gendaymtx's convention
    (ground radiance = rho_g E_gh / pi) with E_gh = pi L for a uniform sky; without (a stage with a ground of
    its own), nothing. ``ambient_bounces`` = n diffuse interreflections off the geometry (``-ab n + 1``: the
    first ambient level reads the sky itself, as ``daylight_coefficients``); an open upward point gets
    pi L (1 + 0) whatever n. Geometry as ``write_scene`` (plastic, RGB albedo, glass of ``transmittance``).
    ``points`` (N, 3), ``normals`` (N, 3) in stage coordinates (``up``); ``offset`` moves each point along its
    normal (metres). ``seed``: an independent Monte-Carlo draw (``_dummy_rays``). ``timings`` receives
    ``radiance_seconds`` (oconv + rtrace wall time), ``radiance_cpu_seconds`` (their CPU time, all
    processes), ``processes`` and the ``command``.
    """
    _pyradiance()
    if processes is None:
        processes = max(1, min(os.cpu_count() or 1, len(np.asarray(points).reshape(-1, 3))))
    dummies = _dummy_rays(seed, processes)
    points, rays = _sensor_rays(points, normals, up, offset, dummies)
    command = rtrace_irradiance_command("scene.oct", ambient_bounces=ambient_bounces,
                                        ambient_divisions=ambient_divisions, limit_weight=limit_weight,
                                        processes=processes)
    sky_text = uniform_sky_rad(radiance, ground_reflectance * radiance if ground else None)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        started, cpu = time.perf_counter(), _children_cpu()
        octree = _octree(tmp, sky_text, triangles, albedo, transmittance, up)
        out = _run(command[:-1] + [octree], input=rays.encode(), cwd=tmp)
        seconds, cpu = time.perf_counter() - started, _children_cpu() - cpu
    if timings is not None:
        timings.update(radiance_seconds=seconds, radiance_cpu_seconds=cpu, processes=processes,
                       command=" ".join(command) + " < points")
    values = np.frombuffer(out, dtype=np.float32)
    if values.size != (dummies + len(points)) * 3:
        raise RuntimeError(f"rtrace wrote {values.size} floats, expected {dummies + len(points)} x 3")
    return values.reshape(-1, 3)[dummies:].astype(np.float64)


def glass_transmittance(tn: float, cos_incidence: np.ndarray) -> np.ndarray:
    """(N,) float64 transmittance of Radiance ``glass`` of transmissivity ``tn`` at incidence cosines
    (Radiance's m_glass.c: Fresnel at n = 1.52 for both polarisations, the pane's internal transmissivity
    raised to 1 / cos(refracted angle), multiple internal reflections summed)."""
    c = np.clip(np.asarray(cos_incidence, np.float64), 1e-12, 1.0)
    n = 1.52
    cos2 = np.sqrt(1.0 - (1.0 - c * c) / (n * n))
    re = ((c - n * cos2) / (c + n * cos2)) ** 2
    rm = ((1.0 / c - n / cos2) / (1.0 / c + n / cos2)) ** 2
    d = tn ** (1.0 / cos2)
    return 0.5 * (1 - re) ** 2 * d / (1 - (re * d) ** 2) + 0.5 * (1 - rm) ** 2 * d / (1 - (rm * d) ** 2)


def glass_diffuse_transmittance(tn: float, samples: int = 20001) -> float:
    """Cosine-weighted hemispherical transmittance of Radiance ``glass`` (``glass_transmittance``
    integrated over incidence: 2 int_0^1 T(mu) mu dmu, midpoint rule in mu): the share of a uniform sky's
    irradiance that passes a horizontal pane."""
    mu = (np.arange(samples) + 0.5) / samples
    return float(2.0 * np.sum(glass_transmittance(tn, mu) * mu) / samples)


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


def _tmy3_example() -> str:
    import pvlib

    return os.path.join(os.path.dirname(pvlib.__file__), "data", "723170TYA.CSV")


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
