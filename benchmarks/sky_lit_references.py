"""Radiance references of the sky-lit rooms (``sky_lit_scenes``): rtrace -I at the test rows, cached.

Independent of usdbake's lighting code: the geometry and materials are read back from the stage with pxr
(``stage_readback.stage_triangles``: ``plastic`` of the faces' diffuseColor, no specular, both sides
reflect), the sky from its UsdLux prims and the lat-long file (``radiance_dome``: ``colorpict`` on a 360
degree glow, the sun a ``light`` source of the DistantLight's angle and radiance). Irradiance by ``rtrace -I
-ab AMBIENT_BOUNCES + 1 -ad AD -aa 0 -as 0 -lw 0.2 / AD`` (pure Monte Carlo, no ambient cache) in two
independent halves (``radiance_scene._dummy_rays`` seeds 1 and 2): the reference is their mean, its noise
|a - b| / (a + b) per row (the mean's relative standard error, for Gaussian halves: |a - b| / 2 / mean is
sqrt(2 / pi) ~ 0.8 of it on average). Surface rows are traced 1 mm off their face, along its normal.

``reference(name, sky, stage, points)`` computes it once per settings (scene, sky and points fingerprints,
-ab, -ad) and keeps it in benchmarks/cache (``harness.cached_reference``).
"""

from __future__ import annotations

import hashlib
import tempfile
import time

import numpy as np

from . import harness
from .radiance_dome import horizontal_check, read_stage_sky, sky_irradiance, sky_rad
from .sky_lit_scenes import SURFACE_OFFSET, TestPoints
from .stage_readback import stage_triangles

VERSION = 1
"""Bumped when the reference's method changes (part of the cache key)."""
AMBIENT_BOUNCES = 7
"""rtrace -ab 8: the sky seen directly plus 7 diffuse interreflections (mean albedo ~0.5: 0.5^8 < 0.5% left)."""
AMBIENT_DIVISIONS = 4096
"""rtrace -ad per half (two halves: 8192 hemisphere samples per row in all)."""
QUICK_DIVISIONS = 256


def _digest(*arrays) -> str:
    digest = hashlib.sha256()
    for array in arrays:
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype}{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()[:16]


def reference(name: str, sky_name: str, stage, points: TestPoints, *, ambient_divisions: int = AMBIENT_DIVISIONS,
              ambient_bounces: int = AMBIENT_BOUNCES, processes: int | None = None) -> dict:
    """Radiance irradiance at the rows of ``points`` (``TestPoints.rows`` order: surface, free, near), cached
    (benchmarks/cache/sky_lit_<name>_<sky>-<key>.npz).

    Returns arrays: ``irradiance`` (R, 3) float64 RGB W/m^2 (mean of the halves), ``half_a``, ``half_b``
    (R, 3), ``kind`` (R,) str, ``rtrace_seconds`` and ``rtrace_cpu_seconds`` (both halves, 0-d), ``command``
    (0-d str), ``sky_check`` (0-d str, JSON of ``radiance_dome.horizontal_check``).
    """
    geometry = stage_triangles(stage)
    sky = read_stage_sky(stage)
    rows = points.rows()
    positions = np.concatenate([p + (SURFACE_OFFSET * n if kind == "surface" else 0.0)
                                for kind, (p, n) in rows.items()])
    normals = np.concatenate([n for _, n in rows.values()])
    kinds = np.concatenate([np.full(len(p), kind) for kind, (p, _) in rows.items()])
    sky_key = _digest(sky.dome_radiance, sky.texture if sky.texture is not None else np.zeros(0),
                      sky.world_to_dome, sky.sun_directions, sky.sun_radiance, sky.sun_angles)
    settings = {"version": VERSION, "scene": name, "sky": sky_name, "sky_fingerprint": sky_key,
                "geometry": _digest(geometry.triangles, geometry.albedo, geometry.transmittance),
                "rows": _digest(positions, normals), "ambient_bounces": ambient_bounces,
                "ambient_divisions": ambient_divisions, "offset": SURFACE_OFFSET}

    def compute() -> dict:
        import json

        opaque = geometry.transmittance == 0  # the rooms here hold no glass; a pane would be dropped, not lit
        with tempfile.TemporaryDirectory() as folder:
            text = sky_rad(sky, folder)
            check = horizontal_check(sky, folder) if sky.texture is not None or len(sky.sun_radiance) else {}
            halves, seconds, cpu, command = [], 0.0, 0.0, ""
            for seed in (1, 2):
                timings = {}
                halves.append(sky_irradiance(geometry.triangles[opaque], geometry.albedo[opaque], positions, normals,
                                             text, ambient_bounces=ambient_bounces,
                                             ambient_divisions=ambient_divisions, processes=processes, seed=seed,
                                             timings=timings))
                seconds += timings["radiance_seconds"]
                cpu += timings["radiance_cpu_seconds"]
                command = timings["command"]
        return {"irradiance": 0.5 * (halves[0] + halves[1]), "half_a": halves[0], "half_b": halves[1],
                "kind": kinds, "rtrace_seconds": np.float64(seconds), "rtrace_cpu_seconds": np.float64(cpu),
                "command": np.str_(command), "sky_check": np.str_(json.dumps(check))}

    started = time.perf_counter()
    out = harness.cached_reference(f"sky_lit_{name}_{sky_name}", settings, compute)
    out["lookup_seconds"] = np.float64(time.perf_counter() - started)
    return out


def noise(reference_arrays: dict, weights: np.ndarray) -> np.ndarray:
    """(R,) relative noise of the reference's luminance per row: |a - b| / (a + b) of the two halves."""
    a = reference_arrays["half_a"] @ weights
    b = reference_arrays["half_b"] @ weights
    return np.abs(a - b) / np.maximum(a + b, 1e-300)
