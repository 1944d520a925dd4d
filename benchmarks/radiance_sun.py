"""Direct sunlight with a sharp sun, as IES LM-83's ASE and Radiance's five-phase method compute it.

``radiance_reference`` (two-phase) lets gendaymtx spread each hour's sun over the 4 Reinhart patches nearest
to it, divided by the patch solid angle: the sun becomes a ~4-patch blur (MF:4: ~3 degrees wide) and the
shadow edges of a window soften, so more floor sensors see some "sun" (in the LM-83 office ~5 more of 170
count towards ASE). LM-83 (ASE: direct sun only, no interreflections, >= 1000 lux for >= 250 occupied hours)
and the five-phase method instead trace the sun as a discrete source of 0.533 degrees. This module does that
with the Radiance binaries of ``pyradiance`` and nothing of usdbake's (weather -> .wea, scene file, patch
directions: ``radiance_reference``, itself independent of usdbake's code).

Pipeline
--------
1. Sun coefficients (``sun_coefficients``): one Radiance ``light`` + ``source`` of 0.533 degrees at the centre
   of every Reinhart MF:``mf`` sky patch (5185 for MF:6; directions ``radiance_sky.reinhart_patches``,
   Radiance's row order, row 0 the ground left out), each with its own modifier ``solar<row>``, radiance
   ``1 / omega`` with omega = 2 pi (1 - cos(0.2665 deg)) the disc's solid angle as Radiance's ``source``
   takes it: a sensor facing the source unobstructed receives exactly 1 W/m^2 (per unit direct normal
   irradiance). ``rcontrib -h -faf -I+ -V+ -ab 0 -dc 1 -dt 0 -dj 0 -ds 0 -dr 0 -M suns.mod scene.oct < sensors``
   (``-V+``: contributions, the radiance included, not coefficients per unit radiance; no ambient: only
   shadow rays to the suns; ``-dt 0 -dc 1``: every source's visibility tested; ``-dj 0``:
   the shadow ray goes to the disc's centre, a sharp sun) with the geometry as ``radiance_scene.
   write_scene`` writes it (opaque ``plastic``; ``glass`` of the pane's VLT, through which Radiance's shadow
   rays pass with glass's angular transmittance): DC_sun (S, P, 3), irradiance per unit DNI = cos(incidence)
   x the glazing's transmittance, 0 in shadow.
2. Sun matrix (``sun_matrix``): ``gendaymtx -5 0.533 -d -m MF -O0 -h -of sky.wea`` (``-d``: the sun alone, no
   sky or ground; ``-5 0.533``: each hour's sun put into its **one** nearest patch with radiance
   E_dn / (179 omega'), omega' = pi (0.533 pi / 360)^2 the disc's solid angle as gendaymtx takes it; ``-O0``:
   visible, Perez's luminous efficacy, E_dn the direct normal illuminance in lux). Rows: the ground, then the
   same MF:mf patches as the suns (checked in the tests: the patch of each hour is the one nearest to the
   sun). The (P + 1, H, 3) float32 matrix (545 MB for MF:6) is read from a file in blocks of rows and kept
   sparse: one (patch, hour, RGB visible-equivalent direct normal irradiance = radiance x omega') per sunny
   hour.
3. Illuminance: E[h, s] = 179 sum_c w_c DC_sun[s, p_h, c] E_dn,c(h), w = (0.265, 0.670, 0.065), lux.

Radiance's sun position (``sun.c``) is 0.3-0.7 degrees from pvlib's at Greensboro, and snapping the sun to a
patch centre moves it by up to ~1.4 degrees more (MF:6 patches are ~2 degrees): the five-phase method's own
approximation, far sharper than the two-phase blur.
"""

from __future__ import annotations

import os
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import radiance_binaries as rbin
from . import radiance_reference as rr
from . import radiance_scene as rscene
from . import radiance_sky as rsky

SUN_DIAMETER = 0.533
"""Degrees: the solar disc's angular diameter (gendaymtx ``-5``, the suns' ``source`` angle)."""
SOURCE_SOLID_ANGLE = 2.0 * np.pi * (1.0 - np.cos(np.radians(SUN_DIAMETER / 2.0)))
"""sr: the solid angle Radiance's ``source`` of ``SUN_DIAMETER`` degrees subtends (src.c: 2 pi (1 - cos(a/2)))."""
GENDAYMTX_SOLID_ANGLE = np.pi * (np.pi / 360.0 * SUN_DIAMETER) ** 2
"""sr: the solid angle gendaymtx ``-5 0.533`` divides the direct normal illuminance by (pi r^2, r the disc's
angular radius in radians; 5e-6 relative from ``SOURCE_SOLID_ANGLE``)."""
SUN_RCONTRIB_OPTIONS = ["-ab", "0", "-dc", "1", "-dt", "0", "-dj", "0", "-ds", "0", "-dr", "0"]
"""No ambient; every source tested, shadow rays to the disc's centre, no virtual sources (no mirrors)."""


# --------------------------------------------------------------------------- the suns


def suns_rad(mf: int = 6) -> tuple[str, list[str]]:
    """(Radiance text, modifier names) of one 0.533-degree sun of radiance ``1 / SOURCE_SOLID_ANGLE`` at the
    centre of every Reinhart MF:``mf`` patch, in Radiance's row order (``solar1`` .. ``solarP``; row 0, the
    ground, has none)."""
    dirs, _ = rsky.reinhart_patches(mf)
    radiance = 1.0 / SOURCE_SOLID_ANGLE
    text, names = [], []
    for row in range(1, len(dirs)):
        d = dirs[row]
        name = f"solar{row}"
        names.append(name)
        text.append(f"void light {name}\n0\n0\n3 {radiance:.9g} {radiance:.9g} {radiance:.9g}\n\n"
                    f"{name} source sun{row}\n0\n0\n4 {d[0]:.9f} {d[1]:.9f} {d[2]:.9f} {SUN_DIAMETER}\n\n")
    return "".join(text), names


def sun_rcontrib_command(octree: str, modifiers: str = "suns.mod", processes: int = 1) -> list[str]:
    """The rcontrib command line of ``sun_coefficients`` (sensors on stdin)."""
    cmd = ["rcontrib", "-h", "-faf", "-I+", "-V+", *SUN_RCONTRIB_OPTIONS]
    if processes > 1:
        cmd += ["-n", str(processes)]
    return cmd + ["-M", modifiers, octree]


def sun_coefficients(triangles: np.ndarray | None, albedo: np.ndarray | None, sensors: np.ndarray,
                     normals: np.ndarray, *, up: str = "Z", mf: int = 6, offset: float = 1e-3,
                     transmittance: np.ndarray | None = None, processes: int | None = None,
                     workdir: str | os.PathLike | None = None, timings: dict | None = None) -> np.ndarray:
    """(S, P, 3) float64 direct-sun coefficients: irradiance (W/m^2) at each sensor per unit direct normal
    irradiance of a sharp sun at the centre of each Reinhart MF:``mf`` patch p (column p = Radiance row p + 1).

    Geometry as ``radiance_scene.write_scene`` (``albedo`` is irrelevant without ambient bounces: the
    plastic only shades; ``transmittance`` > 0 -> Radiance ``glass``); ``sensors`` / ``normals`` (S, 3) in stage
    coordinates with the ``up`` axis, moved ``offset`` metres along their normal. ``timings`` receives
    ``rcontrib_seconds`` (oconv + rcontrib wall time), ``rcontrib_cpu_seconds``, ``processes``, ``command``.
    """
    rbin._pyradiance()
    count = len(np.asarray(sensors).reshape(-1, 3))
    if processes is None:
        processes = max(1, min(os.cpu_count() or 1, count))
    _, rays = rscene._sensor_rays(sensors, normals, up, offset)
    text, names = suns_rad(mf)
    command = sun_rcontrib_command("scene.oct", "suns.mod", processes)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        Path(tmp, "suns.mod").write_text("\n".join(names) + "\n")
        started, cpu = time.perf_counter(), rbin._children_cpu()
        octree = rscene._octree(tmp, text, triangles, albedo, transmittance, up)
        out = rbin._run(command[:-1] + [octree], input=rays.encode(), cwd=tmp)
        seconds, cpu = time.perf_counter() - started, rbin._children_cpu() - cpu
    if timings is not None:
        timings.update(rcontrib_seconds=seconds, rcontrib_cpu_seconds=cpu, processes=processes,
                       command=" ".join(command) + " < sensors")
    values = np.frombuffer(out, dtype=np.float32)
    if values.size != count * len(names) * 3:
        raise RuntimeError(f"rcontrib wrote {values.size} floats, expected {count} x {len(names)} x 3")
    return values.reshape(count, len(names), 3).astype(np.float64)


# --------------------------------------------------------------------------- the sun matrix


@dataclass(frozen=True)
class SunMatrix:
    """gendaymtx ``-5 0.533 -d`` kept sparse: one entry per (patch, hour) with sun."""

    times: np.ndarray
    """(H,) datetime64[m]: local standard time at mid-hour (``radiance_sky.WeatherRows.times``)."""
    hours: np.ndarray
    """(N,) int64: the hour (column) of each entry."""
    patches: np.ndarray
    """(N,) int64: the sky patch of each entry, 0-based (Radiance row ``patches + 1``; ``sun_coefficients``
    column)."""
    direct_normal: np.ndarray
    """(N, 3) float64: RGB direct normal irradiance of the sun, visible-equivalent W/m^2 (x 179: lux), i.e. the
    patch radiance times gendaymtx's disc solid angle."""
    mf: int
    seconds: float
    """gendaymtx's wall time."""

    def normal_illuminance(self) -> np.ndarray:
        """(N,) direct normal illuminance (lux) of each entry."""
        return rr.LUMINOUS_EFFICACY * self.direct_normal @ rr.RGB_LUMINANCE


def gendaymtx_sun_command(wea: str, mf: int = 6) -> list[str]:
    """The gendaymtx command line of ``sun_matrix``."""
    return ["gendaymtx", "-5", f"{SUN_DIAMETER}", "-d", "-m", str(mf), "-O0", "-h", "-of", wea]


def sun_matrix(weather_path: str | os.PathLike, *, mf: int = 6, block_rows: int = 256,
               workdir: str | os.PathLike | None = None) -> SunMatrix:
    """The sun alone, one patch per hour, of the weather file's year: ``gendaymtx -5 0.533 -d -m mf -O0``."""
    rbin._pyradiance()
    rows = 144 * mf * mf + 2
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        wea = os.path.join(tmp, "sky.wea")
        weather = rsky.write_wea(weather_path, wea)
        hours = len(weather.month)
        out = os.path.join(tmp, "sun.bin")
        command = gendaymtx_sun_command(wea, mf)
        started = time.perf_counter()
        with open(out, "wb") as f:
            done = subprocess.run([rbin._binary(command[0])] + command[1:], stdout=f, stderr=subprocess.PIPE)
        seconds = time.perf_counter() - started
        if done.returncode != 0:
            raise RuntimeError(f"{' '.join(command)} failed ({done.returncode}): "
                               f"{done.stderr.decode(errors='replace')[-2000:]}")
        size = os.path.getsize(out)
        if size != rows * hours * 3 * 4:
            raise RuntimeError(f"gendaymtx wrote {size} bytes, expected {rows} x {hours} x 3 float32")
        matrix = np.memmap(out, dtype=np.float32, mode="r", shape=(rows, hours, 3))
        found_p, found_h, found_v = [], [], []
        for r0 in range(0, rows, block_rows):
            block = np.asarray(matrix[r0:r0 + block_rows])
            p, h = np.nonzero(block.any(axis=2))
            found_p.append(p + r0)
            found_h.append(h)
            found_v.append(block[p, h].astype(np.float64))
        del matrix
    p, h, v = np.concatenate(found_p), np.concatenate(found_h), np.concatenate(found_v)
    if np.any(p == 0):
        raise RuntimeError("gendaymtx -d put sun into the ground row")
    order = np.lexsort((p, h))
    return SunMatrix(times=weather.times, hours=h[order].astype(np.int64), patches=(p[order] - 1).astype(np.int64),
                     direct_normal=v[order] * GENDAYMTX_SOLID_ANGLE, mf=mf, seconds=seconds)


def illuminance_from_sun(dc_sun: np.ndarray, sun: SunMatrix) -> np.ndarray:
    """(H, S) lux: 179 sum_c w_c DC_sun[s, p_h, c] E_dn,c(h), summed over each hour's entries."""
    dc_sun = np.asarray(dc_sun, np.float64)
    contribution = np.einsum("nsc,nc->ns", dc_sun[:, sun.patches, :].transpose(1, 0, 2),
                             sun.direct_normal * rr.RGB_LUMINANCE)
    lux = np.zeros((len(sun.times), dc_sun.shape[0]))
    np.add.at(lux, sun.hours, rr.LUMINOUS_EFFICACY * contribution)
    return lux


# --------------------------------------------------------------------------- the whole


def direct_sun_illuminance(triangles: np.ndarray | None, albedo: np.ndarray | None,
                           transmittance: np.ndarray | None, sensors: np.ndarray, normals: np.ndarray,
                           weather_path: str | os.PathLike, *, up: str = "Z", mf: int = 6, offset: float = 1e-3,
                           processes: int | None = None, timings: dict | None = None,
                           return_coefficients: bool = False):
    """(times (H,) datetime64[m] mid-hour local standard time, lux (H, S) float64): the hourly direct-sun
    illuminance at the sensors, a sharp 0.533-degree sun (module docstring), no sky, no interreflections.

    ``triangles`` (T, 3, 3) or None, ``albedo`` (T,) / (T, 3) (only shades), ``transmittance`` None or (T,) VLT
    (glass), ``sensors`` / ``normals`` (S, 3) in stage coordinates (``up``), ``offset`` metres along the normal.
    ``timings`` receives ``rcontrib_seconds``, ``rcontrib_cpu_seconds``, ``gendaymtx_seconds``, ``seconds``
    (everything), ``processes``, ``command`` and ``gendaymtx_command``. ``return_coefficients``: also return
    DC_sun (S, P, 3) and the ``SunMatrix``.
    """
    started = time.perf_counter()
    sun = sun_matrix(weather_path, mf=mf)
    local = {}
    dc = sun_coefficients(triangles, albedo, sensors, normals, up=up, mf=mf, offset=offset,
                          transmittance=transmittance, processes=processes, timings=local)
    lux = illuminance_from_sun(dc, sun)
    if timings is not None:
        timings.update(local, gendaymtx_seconds=sun.seconds, seconds=time.perf_counter() - started,
                       gendaymtx_command=" ".join(gendaymtx_sun_command("sky.wea", mf)))
    if return_coefficients:
        return sun.times, lux, dc, sun
    return sun.times, lux
