"""Sky visibility + daylight: refinement time, accuracy against brute force, adaptive vs uniform, relight speed."""

from __future__ import annotations

import hashlib
import time

import numpy as np

from . import harness

NAME = "sky_visibility"
DESCRIPTION = (
    "Sky visibility factors with adaptive crack-free refinement (`sky_visibility`) and relighting (`daylight`). "
    "Sweep: rays per (face, patch) pair on `building.usda` (uniform sky, black surfaces); error = area-weighted "
    "relative RMS of the face sky view sum_j V_ij dw_j / pi against an independent brute-force reference at the "
    "face centroids (4096 stratified cosine-weighted rays per point counting rays that escape above the horizon, "
    "full geometry), cached. Adaptive vs uniform: same error measure at 10,000 fixed random surface points "
    "(the value of the face containing each point; 16,384 reference rays per point), so meshes of any density "
    "are compared on equal terms. Relight: "
    "one evaluation of Eq. 1 for 100,000 faces x 256 patches (float32 patch-major V, BLAS). Times exclude Warp's "
    "one-time kernel compilation.")
DEFAULT_SAMPLES = 4
REFERENCE_VERSION = 2
"""Bump when the reference estimator changes (2: independent jitter per stratum in kernels.sampling)."""


def _centroid_error(product, reference) -> float:
    """Area-weighted relative RMS of the faces' sky view sum_j V_ij dw_j / pi against the reference."""
    estimate = product.visibility_float() @ product.patches.patch_solid_angles.astype(np.float32) / np.pi
    return harness.relative_rms(estimate, reference, product.face_areas)


def _surface_error(scene, product, points, normals, reference) -> float:
    """Relative RMS at fixed surface points of the exposure of the refined face containing each point."""
    from usdbake.kernels.tracer import Tracer

    locator = Tracer(product.face_points.astype(np.float32), product.face_vertices)
    lift = 1e-4 * scene.diagonal
    hits = locator.closest_hit(points + normals * lift, -normals, 4 * lift)
    found = hits.hit_triangle >= 0
    estimate = np.where(found, product.exposure[np.maximum(hits.hit_triangle, 0)], 0.0)
    return harness.relative_rms(estimate, reference)


def run(quick: bool = False) -> dict:
    from usdbake.kernels.sky import uniform_patches
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.daylight import compute_daylight, relight
    from usdbake.processors.sky_visibility import SkyVisibility, compute_sky_visibility

    from .references import compute_point_sky_view

    patches = uniform_patches(256)
    defaults = SkyVisibility.Params()
    kw = dict(tolerance=defaults.tolerance, min_area=defaults.min_area, max_level=defaults.max_level)
    figures: dict = {}

    # -- refinement time at defaults (warm kernels) -------------------------------------------------
    scenes = {}
    for name in ("window_room", "building"):
        scene = harness.load_scene(name)
        tracer = Tracer.from_scene(scene)
        scenes[name] = (scene, tracer)
        compute_sky_visibility(tracer, scene, patches=uniform_patches(4), adaptive=False)  # compile
        with harness.measure() as m:
            product, stats = compute_sky_visibility(tracer, scene, patches=patches, samples=DEFAULT_SAMPLES, **kw)
        figures[f"{name}_seconds"] = round(m.seconds, 3)
        figures[f"{name}_triangles_in"] = int(stats["triangles_in"])
        figures[f"{name}_triangles_out"] = int(stats["triangles_out"])
        figures[f"{name}_peak_mb"] = round(m.peak_mb, 1)
        figures[f"{name}_quantization_error_max"] = round(stats["quantization_error_max"], 5)

    # -- accuracy against brute force, sweeping rays per (face, patch) ----------------------------------
    sweep_scene = "window_room" if quick else "building"
    scene, tracer = scenes[sweep_scene]
    ref_samples = 1024 if quick else 4096
    rows = []
    for samples in ([4] if quick else [1, 4, 9, 16]):
        started = time.perf_counter()
        product, stats = compute_sky_visibility(tracer, scene, patches=patches, samples=samples, **kw)
        seconds = time.perf_counter() - started
        centroids = product.face_points[product.face_vertices].mean(axis=1).astype(np.float32)
        reference = harness.cached_reference(
            f"sky_view_{sweep_scene}", {"mesh": hashlib.sha256(centroids.tobytes()).hexdigest()[:16],
                                        "reference": ref_samples, "reference_version": REFERENCE_VERSION},
            lambda: {"view": compute_point_sky_view(tracer, centroids, product.face_normals, scene.up_vector,
                                                    samples=ref_samples, seed=99)})["view"]
        rows.append({"label": samples, "samples": samples, "seconds": seconds, "error": _centroid_error(product,
                                                                                                       reference),
                     "triangles": int(stats["triangles_out"]), "rays": stats["rays"],
                     "default": samples == DEFAULT_SAMPLES})
    figures[f"{sweep_scene}_relative_rms_at_default"] = round(next(r["error"] for r in rows if r["default"]), 5)
    figures["reference_rays_per_point"] = ref_samples

    # -- adaptive vs uniform at equal error (fixed surface points) --------------------------------------
    count = 4000 if quick else 10000
    surface_samples = 1024 if quick else 16384  # the reference's own noise must sit well below the errors compared
    points, normals = harness.surface_points(scene, count, seed=5)  # the same points for every mesh compared
    surface_ref = harness.cached_reference(
        f"sky_surface_{sweep_scene}", {"count": count, "reference": surface_samples, "seed": 5,
                                       "reference_version": REFERENCE_VERSION},
        lambda: {"view": compute_point_sky_view(tracer, points, normals, scene.up_vector,
                                                samples=surface_samples, seed=98)})["view"]
    adaptive_rows, uniform_rows = [], []
    for tolerance in ([0.2, 0.1] if quick else [0.4, 0.2, 0.1, 0.05, 0.025]):
        started = time.perf_counter()
        product, stats = compute_sky_visibility(tracer, scene, patches=patches, samples=DEFAULT_SAMPLES,
                                                **{**kw, "tolerance": tolerance})
        adaptive_rows.append({"mesh": f"adaptive tol {tolerance}", "triangles": int(stats["triangles_out"]),
                              "seconds": time.perf_counter() - started,
                              "error": _surface_error(scene, product, points, normals, surface_ref)})
    for level in (range(4) if quick else range(5)):
        started = time.perf_counter()
        product, stats = compute_sky_visibility(tracer, scene, patches=patches, samples=DEFAULT_SAMPLES,
                                                uniform=True, max_level=level)
        uniform_rows.append({"mesh": f"uniform level {level}", "triangles": int(stats["triangles_out"]),
                             "seconds": time.perf_counter() - started,
                             "error": _surface_error(scene, product, points, normals, surface_ref)})
    target = next(r for r in adaptive_rows if r["mesh"] == f"adaptive tol {defaults.tolerance}")
    figures["adaptive_default_triangles"] = target["triangles"]
    figures["adaptive_default_surface_error"] = round(target["error"], 5)
    figures["uniform_triangles_for_equal_error"], figures["adaptive_vs_uniform_triangle_ratio"] = \
        _equal_error_ratio(uniform_rows, target)

    # -- relight 100k faces x 256 patches ----------------------------------------------------------------
    rng = np.random.default_rng(0)  # fixed: timing does not depend on the values
    faces = 100_000
    v8 = rng.integers(0, 256, (faces, 256), dtype=np.uint8)
    v_patch_major = np.ascontiguousarray(v8.T).astype(np.float32) / 255
    weights = rng.random((256, 3)).astype(np.float32)
    albedo = rng.random((faces, 3)).astype(np.float32)
    figures["relight_ms_100k_x_256"] = round(_median_ms(lambda: relight(v_patch_major, weights, albedo=albedo,
                                                                        patch_major=True), 20), 2)
    figures["relight_ms_100k_x_256_uint8_path"] = round(_median_ms(lambda: relight(v8, weights, scale=1 / 255,
                                                                                   albedo=albedo), 5), 2)
    figures["visibility_mb_100k_x_256_uint8"] = round(v8.nbytes / 2 ** 20, 1)
    figures["visibility_mb_100k_x_256_float32"] = round(v_patch_major.nbytes / 2 ** 20, 1)

    # -- one daylight time step on the refined building (sun rays + relight) ------------------------------
    scene, tracer = scenes["building"]
    product, _ = compute_sky_visibility(tracer, scene, patches=patches, samples=DEFAULT_SAMPLES, **kw)
    times = np.array([np.datetime64("2026-04-07T12:30")])
    compute_daylight(tracer, scene, product, times, latitude=41.98, longitude=2.82, timezone=1.0)  # compile, cache V
    started = time.perf_counter()
    compute_daylight(tracer, scene, product, times, latitude=41.98, longitude=2.82, timezone=1.0)
    figures["building_daylight_ms_per_time"] = round(1000 * (time.perf_counter() - started), 1)

    table = "\n\n".join([
        harness.markdown_table(rows, ["samples", "triangles", "seconds", "error", "rays"]),
        "Adaptive vs uniform (error at fixed surface points):\n\n"
        + harness.markdown_table(adaptive_rows + uniform_rows, ["mesh", "triangles", "seconds", "error"]),
    ])
    return harness.result(NAME, description=DESCRIPTION,
                          settings={"patches": 256, "layout": "uniform", "sweep_scene": sweep_scene, **kw},
                          points=rows, figures=figures, table=table, knob="rays per (face, patch) pair",
                          error_label="relative RMS of sky view vs brute force")


def _equal_error_ratio(uniform_rows: list[dict], target: dict) -> tuple[float, float]:
    """Triangles a uniform mesh needs for the adaptive mesh's error (log-log interpolation), and the ratio.

    If even the finest uniform mesh is less accurate, its count is a lower bound (reported as such: the
    ratio is then 'at least')."""
    tris = np.array([r["triangles"] for r in uniform_rows], np.float64)
    errors = np.array([r["error"] for r in uniform_rows], np.float64)
    goal = target["error"]
    below = np.flatnonzero(errors <= goal)
    if len(below) == 0:
        return float(tris[-1]), round(float(tris[-1] / target["triangles"]), 2)
    k = int(below[0])
    if k == 0:
        needed = tris[0]
    else:
        t = (np.log(goal) - np.log(errors[k - 1])) / (np.log(errors[k]) - np.log(errors[k - 1]))
        needed = float(np.exp(np.log(tris[k - 1]) + t * (np.log(tris[k]) - np.log(tris[k - 1]))))
    return round(float(needed)), round(float(needed / target["triangles"]), 2)


def _median_ms(function, repeats: int) -> float:
    """Median milliseconds of ``repeats`` calls after one warm-up call."""
    function()
    return 1000.0 * float(np.median(harness.timings(function, repeats)))
