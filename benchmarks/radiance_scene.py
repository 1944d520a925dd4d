"""Radiance scenes from triangles, and the rcontrib / rtrace runs over them.

Part of the independent Radiance reference (``radiance_reference``): triangles and sensors in, Radiance's
daylight coefficients (rcontrib) or irradiance under one uniform sky (rtrace) out; nothing here imports
usdbake's code.

Daylight coefficients
---------------------
3. (of ``radiance_reference``'s pipeline) The geometry as ``polygon``s with grey ``plastic``
   materials plus a full-sphere glow source ``skyglow``, and
   ``rcontrib -h -faf -I+ -ab AB -ad AD -lw LW -n N -e MF:mf -f reinhart.cal
   -b rbin -bn Nrbins -m skyglow scene.oct < sensors`` (one line
   ``x y z nx ny nz`` per sensor): DC[s, p, c] = irradiance at sensor s per
   unit radiance of patch p (sr, cosine-weighted solid angle seen). The bins are gendaymtx's rows
   (``radiance_sky``: patch order).

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
in float64) and grey (T,) or RGB (T, 3) albedo; ``daylight_coefficients`` and
``radiance_reference.annual_illuminance`` pass them through. ``uniform_sky_irradiance`` is ``rtrace -I``
under one uniform sky (above the horizon) with an optional ground glow of gendaymtx's convention below it.
Radiance has no seed option: ``seed`` traces throw-away rays first (``_dummy_rays``) for an independent
draw, to judge noise by two seeds. ``timings`` (a dict) receives the Radiance wall time of a call
(``radiance_seconds``) and its command line.

Frames
------
``up='Z'``: Radiance coordinates = the input (x east, y north, z up). ``up='Y'``:
x east, -z north, y up (usdbake's ``enu_to_world('Y')``). North is the sky's: ``radiance_sky``
(``gendaymtx -r north``).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from .radiance_binaries import _children_cpu, _pyradiance, _run
from .radiance_sky import _reinhart_rows


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


def _timed_run(command: list[str], sky_text: str, triangles, albedo, transmittance, up: str, rays: str, *,
               processes: int, workdir, timings: dict | None, stdin: str) -> bytes:
    """Build the octree of the sky and the scene in a temporary folder, run ``command`` (its last argument, the
    octree, replaced) on ``rays``, and record wall and CPU seconds, processes and the command in ``timings``."""
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        started, cpu = time.perf_counter(), _children_cpu()
        octree = _octree(tmp, sky_text, triangles, albedo, transmittance, up)
        out = _run(command[:-1] + [octree], input=rays.encode(), cwd=tmp)
        seconds, cpu = time.perf_counter() - started, _children_cpu() - cpu
    if timings is not None:
        timings.update(radiance_seconds=seconds, radiance_cpu_seconds=cpu, processes=processes,
                       command=" ".join(command) + f" < {stdin}")
    return out


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
    out = _timed_run(command, SKY_RAD, triangles, albedo, transmittance, up, rays, processes=processes,
                     workdir=workdir, timings=timings, stdin="sensors")
    values = np.frombuffer(out, dtype=np.float32)
    nrows = _reinhart_rows(mf)
    if values.size != (dummies + len(sensors)) * nrows * 3:
        raise RuntimeError(f"rcontrib wrote {values.size} floats, expected {dummies + len(sensors)} x {nrows} x 3")
    return values.reshape(-1, nrows, 3)[dummies:].astype(np.float64)


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
    out = _timed_run(command, sky_text, triangles, albedo, transmittance, up, rays, processes=processes,
                     workdir=workdir, timings=timings, stdin="points")
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

