"""Light probes on atrium.usda: interpolated irradiance against direct capture at 16x rays."""

from __future__ import annotations

import time

import numpy as np

from . import harness
from usdbake.core.products import ProbeCloud

NAME = "light_probes"
DESCRIPTION = (
    "Light probe cloud on `atrium.usda`. Error = relative RMS of the irradiance interpolated from the cloud "
    "(tetrahedral walk, leak rule) at random free-space points, for 26 normals each (luminance clamped at 0, "
    "as `sample_irradiance` reads it), against a direct capture at those points with 16x the default rays "
    "(4096, different seed), cached; divided by "
    "the mean reference irradiance (`median`: the median over points of the per-point RMS). "
    "Knobs: probe budget (default 1024) and capture rays (default 256); "
    "seconds = the whole processor (placement, capture, tetrahedra, edge rays). The noise floor is the "
    "error of a direct capture at the points at default rays. Thin wall: two closed rooms with 5 cm of wall "
    "between them and lamps of 2000 and 100 W/sr; leak error = the same relative RMS at 400 points within "
    "10 cm of the wall on the dim room's side, with and without `leak_fix` (default 1024-probe budget); "
    "`thin_wall_error_*` at 800 points spread over both rooms.")
DEFAULT_PROBES = 1024
DEFAULT_RAYS = 256
POINT_CLEARANCE = 0.3
"""Test points keep 0.3 m from surfaces (where a character or a prop would be lit by the probes)."""


def run(quick: bool = False) -> dict:
    from usdbake.core import Context
    from usdbake.kernels.lights import scene_lighting
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors import light_probes as lp

    scene = harness.load_scene("atrium")
    tracer = Tracer.from_scene(scene)
    lighting = scene_lighting(scene, tracer.device)
    count = 150 if quick else 600
    points = _free_points(lp, tracer, lighting, scene, count)

    reference_rays = 16 * DEFAULT_RAYS
    reference = harness.cached_reference(
        "light_probes_atrium", {"rays": reference_rays, "seed": 99, "points": len(points), "quick": quick,
                                "version": lp.LightProbes.version, "clearance": POINT_CLEARANCE},
        lambda: {"sh": lp.compute_probe_sh(tracer, scene, points, rays=reference_rays, seed=99,
                                           lighting=lighting)})["sh"]
    e_ref = lp.sample_irradiance(reference)
    scale = float(e_ref.mean())

    def error(sh) -> float:
        return float(np.sqrt(np.mean((lp.sample_irradiance(sh) - e_ref) ** 2)) / scale)

    def median_error(sh) -> float:  # per point: RMS over its 26 normals / the mean reference irradiance
        return float(np.median(np.sqrt(np.mean((lp.sample_irradiance(sh) - e_ref) ** 2, axis=1)) / scale))

    processor = lp.LightProbes()

    def bake(**params):
        started = time.perf_counter()
        result = processor.run(Context(scene, processor.Params(**params), tracer))
        seconds = time.perf_counter() - started
        cloud = result.products[ProbeCloud]
        return cloud, seconds, result.stats

    bake(probes=16, rays=4, placement_rays=4, iterations=1)  # compile outside the timing
    rows = []
    budgets = [64, 1024] if quick else [64, 128, 256, 512, 1024, 2048, 4096]
    for probes in budgets:
        cloud, seconds, stats = bake(probes=probes)
        rows.append({"label": f"probes={probes}", "knob": "probes", "probes_budget": probes,
                     "probes": int(stats["probes"]), "rays": DEFAULT_RAYS, "seconds": seconds,
                     "error": error(lp.interpolate_sh(cloud, points)),
                     "median": median_error(lp.interpolate_sh(cloud, points)), "default": probes == DEFAULT_PROBES})
    for rays in ([64] if quick else [64, 1024]):
        cloud, seconds, stats = bake(rays=rays)
        rows.append({"label": f"rays={rays}", "knob": "rays", "probes_budget": DEFAULT_PROBES,
                     "probes": int(stats["probes"]), "rays": rays, "seconds": seconds,
                     "error": error(lp.interpolate_sh(cloud, points)),
                     "median": median_error(lp.interpolate_sh(cloud, points)), "default": False})

    default = next(r for r in rows if r["default"])
    floor = error(lp.compute_probe_sh(tracer, scene, points, rays=DEFAULT_RAYS, seed=7, lighting=lighting))
    grid_cloud, grid_seconds, grid_stats = bake(iterations=0)
    leaky_cloud, _, _ = bake(leak_fix=False)
    figures = {
        "test_points": len(points),
        "probes_at_default": default["probes"],
        "relative_rms_at_default": round(default["error"], 4),
        "median_point_error_at_default": round(default["median"], 4),
        "processor_seconds_default": round(default["seconds"], 3),
        "direct_capture_noise_floor": round(floor, 4),
        "relative_rms_grid_only_same_budget": round(error(lp.interpolate_sh(grid_cloud, points)), 4),
        "median_point_error_grid_only": round(median_error(lp.interpolate_sh(grid_cloud, points)), 4),
        "probes_grid_only": int(grid_stats["probes"]),
        "relative_rms_without_leak_fix": round(error(lp.interpolate_sh(leaky_cloud, points)), 4),
        "median_point_error_without_leak_fix": round(median_error(lp.interpolate_sh(leaky_cloud, points)), 4),
    }
    figures.update(thin_wall_leak())
    if not quick:
        figures["bake_wall_seconds_default"] = round(harness.bake_wall_seconds(harness.SAMPLES / "atrium.usda",
                                                                               "light_probes"), 3)
    table = harness.markdown_table(rows, ["label", "probes", "rays", "seconds", "error", "median"])
    return harness.result(NAME, description=DESCRIPTION,
                          settings={"reference_rays": reference_rays, "test_points": len(points),
                                    "point_clearance": POINT_CLEARANCE},
                          points=rows, figures=figures, table=table, knob="probe budget / capture rays",
                          error_label="relative RMS irradiance vs 16x-ray capture")


def _free_points(lp, tracer, lighting, scene, count: int) -> np.ndarray:
    """``count`` random points in the placement box, outside geometry and POINT_CLEARANCE from it."""
    rng = np.random.default_rng(2024)  # fixed seed: the same test points every run
    lo, hi = lp.placement_box(scene)
    found = []
    while sum(len(f) for f in found) < count:
        candidates = (lo + rng.random((4 * count, 3)) * (hi - lo)).astype(np.float32)
        inside, nearest = lp.classify_points(tracer, lighting, candidates)
        found.append(candidates[~inside & (nearest >= POINT_CLEARANCE)])
    return np.concatenate(found)[:count]



LEAK_BAND = 0.1
"""Leak points lie within this distance (m) of the wall, on its dark side."""


def thin_wall_stage():
    """Two closed 4 x 4 x 3 m rooms (walls facing in) side by side, 5 cm of wall between them; a 2000 W/sr
    lamp in room A, a 100 W/sr lamp in room B (Z up, metres)."""
    from pxr import Gf, Usd, UsdGeom, UsdLux

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    outward = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    for name, x0, intensity in (("A", 0.0, 2000.0), ("B", 4.05, 100.0)):
        room = UsdGeom.Mesh.Define(stage, f"/World/Room{name}")
        room.CreatePointsAttr([(x, y, z) for z in (0.0, 3.0) for y in (0.0, 4.0) for x in (x0, x0 + 4.0)])
        room.CreateFaceVertexCountsAttr([4] * 6)
        room.CreateFaceVertexIndicesAttr([i for face in outward for i in face[::-1]])
        lamp = UsdLux.SphereLight.Define(stage, f"/World/Lamp{name}")
        lamp.CreateIntensityAttr(intensity)
        lamp.CreateRadiusAttr(0.1)
        UsdGeom.Xformable(lamp).AddTranslateOp().Set(Gf.Vec3d(x0 + 2.0, 2.0, 2.5))
    return stage


def thin_wall_leak(probes: int = DEFAULT_PROBES, points: int = 400) -> dict:
    """Irradiance error at points within LEAK_BAND of the thin wall on the dim room's side, and at points
    spread over both rooms, with and without leak handling (``leak_fix``), against a 4096-ray capture."""
    from usdbake.core import Context
    from usdbake.kernels.lights import scene_lighting
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors import light_probes as lp
    from usdbake.stages.extract import extract_scene

    scene = extract_scene(thin_wall_stage())
    tracer = Tracer.from_scene(scene)
    lighting = scene_lighting(scene, tracer.device)
    rng = np.random.default_rng(5)  # fixed seed: the same points every run
    near = np.c_[rng.uniform(4.05 + 0.01, 4.05 + LEAK_BAND, points), rng.uniform(0.2, 3.8, points),
                 rng.uniform(0.2, 2.8, points)]
    spread = np.c_[np.r_[rng.uniform(0.2, 3.8, points), rng.uniform(4.25, 7.85, points)],
                   rng.uniform(0.2, 3.8, 2 * points), rng.uniform(0.2, 2.8, 2 * points)]
    at = (np.r_[near, spread] - scene.origin).astype(np.float32)
    reference = lp.sample_irradiance(lp.compute_probe_sh(tracer, scene, at, rays=16 * DEFAULT_RAYS, seed=99,
                                                         lighting=lighting))
    processor = lp.LightProbes()
    figures = {}
    for leak_fix in (False, True):
        result = processor.run(Context(scene, processor.Params(probes=probes, leak_fix=leak_fix), tracer))
        estimate = lp.sample_irradiance(lp.interpolate_sh(result.products[ProbeCloud], at))
        key = "with" if leak_fix else "without"
        figures[f"thin_wall_leak_error_{key}_leak_fix"] = round(float(
            np.sqrt(np.mean((estimate[:points] - reference[:points]) ** 2)) / reference[:points].mean()), 4)
        figures[f"thin_wall_error_{key}_leak_fix"] = round(float(
            np.sqrt(np.mean((estimate[points:] - reference[points:]) ** 2)) / reference[points:].mean()), 4)
    figures["thin_wall_leak_reduction"] = round(figures["thin_wall_leak_error_without_leak_fix"]
                                                / figures["thin_wall_leak_error_with_leak_fix"], 3)
    return figures
