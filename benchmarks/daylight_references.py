"""The cached Radiance references of the daylight scenes of issue 29 (``daylight_scenes``,
``furnished_daylight_room``).

``office_reference``: the LM-83 office's annual two-phase reference (rcontrib daylight coefficients x
gendaymtx); ``furnished_reference``: the furnished room's single-uniform-sky reference (rtrace). Each is
computed once per settings and kept in benchmarks/cache by ``harness.cached_reference``; the settings carry
``SCENES_VERSION`` and ``scene_fingerprint`` of the arrays the Radiance side reads, so a changed scene misses
the cache.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from . import harness
from .daylight_scenes import SCENES_VERSION, SENSOR_OFFSET, DaylightScene, lm83_office
from .furnished_daylight_room import SKY_RADIANCE, furnished_daylight_room

OFFICE_AMBIENT_DIVISIONS = 65536
"""rcontrib -ad of the office reference (-ab 6, -aa 0, -lw 0.2 / -ad = 3.05e-6, MF:4). Noise judged by two seeds
(``radiance_scene._dummy_rays``), per run = |a - b| / mean / sqrt 2 over the 170 sensors, Greensboro TMY3,
occupied 8-18 h: mean occupied illuminance median 0.45% (p90 1.4%, max 3.0%), daylight factor (CIE overcast)
median 0.28% (p90 1.2%), sDA 0.694 in both. At MF:1 the same measure gave 4.6% / 1.9% / 0.8% (median) at
-ad 1024 / 4096 / 16384. Cost: ~160 CPU-s of rcontrib (2 processes; 156-165 s wall on the shared 2-core dev
machine, ~80 s if idle) + 38 s for the direct-only coefficients + 3 s gendaymtx."""
ROOM_AMBIENT_DIVISIONS = 65536
"""rtrace -ad of the furnished room's uniform-sky reference (-ab 6, -aa 0, -as 0, -lw 0.2 / -ad = 3.05e-6). Noise
by two seeds, per run, luminance-weighted irradiance at the 150 points: median 0.42%, p90 1.5% (-ad 16384: 0.9%,
3.0%; no bias between them: mean ratio 0.999). 6 of the 150 points lie in crevices (between books, sofa seat
and back) below 1% of the median. Cost: ~390-440 CPU-s of rtrace (2 processes; 416-439 s wall on the shared
2-core dev machine) + ~45 s for the direct-only run (-ab 1, 4 x -ad)."""


def scene_fingerprint(scene: DaylightScene) -> str:
    """sha256 (16 hex) of the arrays the Radiance side reads: triangles, albedo, transmittance, sensors
    (dtype, shape and bytes)."""
    import hashlib

    digest = hashlib.sha256()
    for array in (scene.triangles, scene.albedo, scene.transmittance, scene.sensor_points, scene.sensor_normals):
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype}{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()[:16]


def office_reference(scene: DaylightScene | None = None, *, mf: int = 4, ambient_bounces: int = 5,
                     ambient_divisions: int = OFFICE_AMBIENT_DIVISIONS, limit_weight: float | None = None,
                     seed: int = 1, weather_path: str | None = None, processes: int | None = None) -> dict:
    """The office's annual Radiance reference, computed once per settings and cached (``harness.cached_reference``,
    benchmarks/cache/daylight_office-<key>.npz).

    Two-phase (``radiance_reference``): rcontrib daylight coefficients at the floor sensors, glass as Radiance
    ``glass`` of the pane's VLT, ``-ab ambient_bounces + 1 -ad ambient_divisions -aa 0 -lw 0.2/-ad``, Reinhart
    MF:``mf`` + ground row; and the same with ``ambient_bounces`` 0 (the sky and ground seen directly, through
    the glass: for ASE and the direct / interreflected split), -ad 4 x ``ambient_divisions``. Times gendaymtx -O0
    (visible, Perez luminous efficacy, ground 0.2, sun in the patches) of ``weather_path`` (default the
    Greensboro TMY3 file pvlib ships) x 179 lm/W.

    Returns arrays: ``sensor_points`` (S, 3), ``sensor_normals`` (S, 3); ``dc`` and ``dc_direct`` (S, P, 3)
    float32 (sr); ``times`` (H,) datetime64[m] mid-hour local standard time; ``illuminance`` (H, S) float32 lux
    from ``dc``; ``rcontrib_seconds``, ``rcontrib_direct_seconds``, ``gendaymtx_seconds`` (0-d wall times
    when first computed), ``rcontrib_cpu_seconds``, ``rcontrib_direct_cpu_seconds`` (CPU time of all
    Radiance processes: robust to other load), ``processes``; ``command`` (0-d str).
    """
    from . import radiance_reference as rr
    from . import radiance_scene as rscene
    from . import radiance_sky as rsky

    scene = scene if scene is not None else lm83_office()
    weather_path = str(weather_path or rsky._tmy3_example())
    settings = {"scene": "lm83_office", "version": SCENES_VERSION, "fingerprint": scene_fingerprint(scene),
                "mf": mf, "ambient_bounces": ambient_bounces, "ambient_divisions": ambient_divisions,
                "limit_weight": limit_weight, "seed": seed, "weather": Path(weather_path).name,
                "output": "visible", "ground_reflectance": 0.2}

    def compute() -> dict:
        common = dict(transmittance=scene.transmittance, mf=mf, limit_weight=limit_weight, seed=seed,
                      processes=processes)
        total, direct = {}, {}
        dc = rscene.daylight_coefficients(scene.triangles, scene.albedo, scene.sensor_points, scene.sensor_normals,
                                          ambient_bounces=ambient_bounces, ambient_divisions=ambient_divisions,
                                          timings=total, **common)
        dc_direct = rscene.daylight_coefficients(scene.triangles, scene.albedo, scene.sensor_points,
                                                 scene.sensor_normals, ambient_bounces=0,
                                                 ambient_divisions=4 * ambient_divisions, timings=direct, **common)
        started = time.perf_counter()
        times, sky = rsky.annual_sky_matrix(weather_path, mf=mf, output="visible", ground_reflectance=0.2)
        sky_seconds = time.perf_counter() - started
        return {"sensor_points": scene.sensor_points, "sensor_normals": scene.sensor_normals,
                "dc": dc.astype(np.float32), "dc_direct": dc_direct.astype(np.float32), "times": times,
                "illuminance": rr.illuminance_from(dc, sky).astype(np.float32),
                "rcontrib_seconds": np.float64(total["radiance_seconds"]),
                "rcontrib_cpu_seconds": np.float64(total["radiance_cpu_seconds"]),
                "rcontrib_direct_seconds": np.float64(direct["radiance_seconds"]),
                "rcontrib_direct_cpu_seconds": np.float64(direct["radiance_cpu_seconds"]),
                "gendaymtx_seconds": np.float64(sky_seconds), "processes": np.int64(total["processes"]),
                "command": np.str_(total["command"])}

    return harness.cached_reference("daylight_office", settings, compute)


def furnished_reference(scene: DaylightScene | None = None, *, ambient_bounces: int = 5,
                        ambient_divisions: int = ROOM_AMBIENT_DIVISIONS, limit_weight: float | None = None,
                        seed: int = 1, radiance: float = SKY_RADIANCE, processes: int | None = None) -> dict:
    """The furnished room's single-uniform-sky Radiance reference at its random surface points, cached
    (benchmarks/cache/daylight_furnished-<key>.npz).

    ``rtrace -I`` (``radiance_scene.uniform_sky_irradiance``) 1 mm off each surface along its normal: sky
    of ``radiance`` W/(m^2 sr) above the horizon (1000 W/m^2 on an open horizontal), the stage's own 200 m
    ground and nothing below the horizon beyond it (no ground glow), glass of VLT 0.7, plastic RGB
    materials; ``-ab ambient_bounces + 1 -ad ambient_divisions -aa 0 -lw 0.2/-ad``, and ``ambient_bounces`` 0
    (the sky seen directly) at 4 x the divisions, for the interreflected share.

    Returns arrays: ``points`` (N, 3), ``normals`` (N, 3), ``prims`` (N,) str; ``irradiance`` and
    ``irradiance_direct`` (N, 3) float64 RGB W/m^2; ``rtrace_seconds``, ``rtrace_direct_seconds`` (wall),
    ``rtrace_cpu_seconds``, ``rtrace_direct_cpu_seconds`` (CPU, all processes), ``processes``,
    ``sky_radiance`` (0-d); ``command`` (0-d str).
    """
    from . import radiance_scene as rscene

    scene = scene if scene is not None else furnished_daylight_room()
    settings = {"scene": "furnished_daylight_room", "version": SCENES_VERSION,
                "fingerprint": scene_fingerprint(scene), "ambient_bounces": ambient_bounces,
                "ambient_divisions": ambient_divisions, "limit_weight": limit_weight, "seed": seed,
                "radiance": radiance, "offset": SENSOR_OFFSET}

    def compute() -> dict:
        common = dict(transmittance=scene.transmittance, radiance=radiance, ground=False,
                      limit_weight=limit_weight, offset=SENSOR_OFFSET, seed=seed, processes=processes)
        total, direct = {}, {}
        e = rscene.uniform_sky_irradiance(scene.triangles, scene.albedo, scene.sensor_points, scene.sensor_normals,
                                          ambient_bounces=ambient_bounces, ambient_divisions=ambient_divisions,
                                          timings=total, **common)
        e_direct = rscene.uniform_sky_irradiance(scene.triangles, scene.albedo, scene.sensor_points,
                                                 scene.sensor_normals, ambient_bounces=0,
                                                 ambient_divisions=4 * ambient_divisions, timings=direct, **common)
        return {"points": scene.sensor_points, "normals": scene.sensor_normals,
                "prims": np.array(scene.sensor_prims, dtype=str), "irradiance": e, "irradiance_direct": e_direct,
                "rtrace_seconds": np.float64(total["radiance_seconds"]),
                "rtrace_cpu_seconds": np.float64(total["radiance_cpu_seconds"]),
                "rtrace_direct_seconds": np.float64(direct["radiance_seconds"]),
                "rtrace_direct_cpu_seconds": np.float64(direct["radiance_cpu_seconds"]),
                "processes": np.int64(total["processes"]), "sky_radiance": np.float64(radiance),
                "command": np.str_(total["command"])}

    return harness.cached_reference("daylight_furnished", settings, compute)
