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
    "are compared on equal terms. Refinement criteria (`share`, `any`: knob `tolerance`; `paper`, Bosch et al. "
    "Sec. 4.2: knob `min_area`), other parameters at the processor's defaults (incl. max_face_area 1e-3): "
    "triangles, seconds and the RMS difference of sky exposure (the open-sky share) at the same fixed surface "
    "points and reference (the refined face containing each point, found by its source triangle and "
    "barycentric coordinates), then the triangles each criterion needs for the error `share` reaches at its "
    "default tolerance, and the error each reaches at `share`'s triangle count (log-log interpolation on its "
    "curve). Relight: "
    "one evaluation of Eq. 1 for 100,000 faces x 256 patches (float32 patch-major V, BLAS). Times exclude Warp's "
    "one-time kernel compilation.")
DEFAULT_SAMPLES = 4
CRITERIA = ("share", "any", "paper")
CRITERION_KNOBS = {"share": "tolerance", "any": "tolerance", "paper": "min_area"}
"""The knob each refinement criterion is swept by (``paper`` ignores tolerance; min_area is its A_min)."""
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


def _point_sources(scene, points: np.ndarray, *, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The source triangle of each of ``harness.surface_points(scene, len(points), seed=seed)`` and the
    point's (N, 3) float64 barycentric coordinates in it, by drawing the same random numbers again (the
    points are checked against them, so a change of the sampling there is caught here)."""
    from usdbake.geometry.mesh import receiver_prims

    count = len(points)
    tris = np.flatnonzero(np.isin(scene.tri_prim, receiver_prims(scene)) & (scene.tri_areas > 0))
    rng = np.random.default_rng(seed)  # harness.surface_points' draws, in its order
    pick = rng.choice(tris, count, p=scene.tri_areas[tris] / scene.tri_areas[tris].sum())
    u = np.stack([rng.random(count), rng.random(count)], axis=1).astype(np.float32).astype(np.float64)
    r1 = np.sqrt(u[:, 0])  # triangle_point: (1 - r1) a + r1 (1 - u2) b + r1 u2 c
    bary = np.stack([1.0 - r1, r1 * (1.0 - u[:, 1]), r1 * u[:, 1]], axis=1)
    again = np.einsum("nk,nkd->nd", bary, scene.points[scene.tri_vertices[pick]].astype(np.float64))
    if np.abs(again - points).max(initial=0.0) > 1e-5 * scene.diagonal:
        raise RuntimeError("harness.surface_points no longer draws its points as _point_sources assumes")
    return pick, bary


LOCATE_PAIRS = 1 << 21
"""(point, candidate face) pairs per batch of _containing_faces."""


def _containing_faces(product, sources: np.ndarray, bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The refined face containing each test point, and the smallest of the point's barycentric coordinates
    in it (>= -1e-6 when it contains the point).

    Among the faces refined from the point's source triangle (``face_source``), the one whose smallest
    barycentric coordinate is largest. Coordinates are solved in the source triangle's barycentric frame
    (``face_corner_weights``: the faces' corners there, exact), not from float32 positions."""
    order = np.argsort(product.face_source, kind="stable")
    first = np.searchsorted(product.face_source[order], sources, "left")
    counts = np.searchsorted(product.face_source[order], sources, "right") - first
    if (counts == 0).any():
        raise RuntimeError("a test point's source triangle has no refined face")
    # Per face, the affine map from a point's first two source coordinates to its first two in the face:
    # (l0, l1) = inverse([w0 - w2, w1 - w2]) (b - w2), w_i its corners' first two source coordinates.
    w = product.face_corner_weights[:, :, :2]
    e0, e1 = w[:, 0] - w[:, 2], w[:, 1] - w[:, 2]
    det = e0[:, 0] * e1[:, 1] - e0[:, 1] * e1[:, 0]
    good = np.abs(det) > 1e-300
    inv = np.stack([e1[:, 1], -e1[:, 0], -e0[:, 1], e0[:, 0]], axis=1) / np.where(good, det, 1.0)[:, None]
    shift = -np.stack([inv[:, 0] * w[:, 2, 0] + inv[:, 1] * w[:, 2, 1],
                       inv[:, 2] * w[:, 2, 0] + inv[:, 3] * w[:, 2, 1]], axis=1)
    maps = np.concatenate([inv, shift], axis=1)[order]  # (F, 6) in face_source order: contiguous per source
    maps[~good[order]] = np.nan  # degenerate faces never win
    face = np.zeros(len(sources), np.int64)
    best = np.full(len(sources), -np.inf)
    lo = 0
    while lo < len(sources):  # batches of points bound the pair arrays
        hi = lo + max(1, int(np.searchsorted(np.cumsum(counts[lo:]), LOCATE_PAIRS)))
        n = counts[lo:hi]
        owner = np.repeat(np.arange(lo, hi), n)
        slot = np.arange(len(owner)) + np.repeat(first[lo:hi] - (np.cumsum(n) - n), n)
        m, b0, b1 = maps[slot], bary[owner, 0], bary[owner, 1]
        l0 = m[:, 0] * b0 + m[:, 1] * b1 + m[:, 4]
        l1 = m[:, 2] * b0 + m[:, 3] * b1 + m[:, 5]
        low = np.minimum(np.minimum(l0, l1), 1.0 - l0 - l1)
        low[np.isnan(low)] = -np.inf
        starts = np.cumsum(n) - n
        top = np.maximum.reduceat(low, starts)
        hit = np.flatnonzero(low == np.repeat(top, n))
        keep = np.r_[True, owner[hit][1:] != owner[hit][:-1]]  # the first best candidate of each point
        face[lo:hi], best[lo:hi] = order[slot[hit[keep]]], top
        lo = hi
    return face, best


def _exposure_error(product, sources: np.ndarray, bary: np.ndarray, reference: np.ndarray) -> dict:
    """Exposure of the refined face containing each fixed test point against the point reference: RMS and
    mean absolute difference (the points are area-uniform, so these are area-weighted over the receivers)."""
    face, low = _containing_faces(product, sources, bary)
    diff = product.exposure[face].astype(np.float64) - reference
    return {"error": float(np.sqrt(np.mean(diff ** 2))), "mean_abs": float(np.mean(np.abs(diff))),
            "outside": int((low < -1e-6).sum())}


def run(quick: bool = False) -> dict:
    from usdbake.kernels.sky import uniform_patches
    from usdbake.kernels.tracer import Tracer
    from usdbake.kernels.daylight_relight import relight_daylight
    from usdbake.processors.daylight.daylight import compute_daylight
    from usdbake.processors.daylight.sky_visibility import SkyVisibility, compute_sky_visibility

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

    # -- refinement criteria at equal error and triangle count (the same fixed surface points) -----------
    sources, bary = _point_sources(scene, points, seed=5)
    criteria_kw = {**kw, "max_face_area": defaults.max_face_area}  # the processor's defaults
    sweeps = {"tolerance": [0.3, 0.1] if quick else [0.3, 0.1, 0.03, 0.01],
              "min_area": [1e-3, 3e-4, 1e-4] if quick else [1e-3, 3e-4, 1e-4, 3e-5, 1e-5]}
    criteria_rows = []
    for criterion in CRITERIA:
        knob = CRITERION_KNOBS[criterion]
        for value in sweeps[knob]:
            started = time.perf_counter()
            product, stats = compute_sky_visibility(tracer, scene, patches=patches, samples=DEFAULT_SAMPLES,
                                                    criterion=criterion, **{**criteria_kw, knob: value})
            seconds = time.perf_counter() - started
            criteria_rows.append({"criterion": criterion, "knob": f"{knob} {value:g}", "value": value,
                                  "triangles": int(stats["triangles_out"]), "seconds": seconds,
                                  **_exposure_error(product, sources, bary, surface_ref.astype(np.float64))})
    figures.update(_criteria_figures(criteria_rows, defaults.tolerance))
    figures["criteria_scene"] = sweep_scene
    figures["criteria_points_outside_face_max"] = max(r.pop("outside") for r in criteria_rows)
    p_sky = np.clip(surface_ref.astype(np.float64), 0.0, 1.0)  # binomial bound on the reference's own noise
    figures["criteria_reference_noise_rms_bound"] = round(float(np.sqrt(np.mean(p_sky * (1 - p_sky))
                                                                         / surface_samples)), 5)
    comparison_rows = _criteria_comparison(criteria_rows, figures)

    # -- relight 100k faces x 256 patches ----------------------------------------------------------------
    rng = np.random.default_rng(0)  # fixed: timing does not depend on the values
    faces = 100_000
    v8 = rng.integers(0, 256, (faces, 256), dtype=np.uint8)
    v_patch_major = np.ascontiguousarray(v8.T).astype(np.float32) / 255
    weights = rng.random((256, 3)).astype(np.float32)
    albedo = rng.random((faces, 3)).astype(np.float32)
    figures["relight_ms_100k_x_256"] = round(_median_ms(lambda: relight_daylight(v_patch_major, weights, albedo=albedo,
                                                                        patch_major=True), 20), 2)
    figures["relight_ms_100k_x_256_uint8_path"] = round(_median_ms(lambda: relight_daylight(v8, weights, scale=1 / 255,
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
        f"Refinement criteria on `{sweep_scene}` (error: RMS difference of sky exposure at the fixed surface "
        "points; mean_abs: mean absolute difference):\n\n"
        + harness.markdown_table(criteria_rows, ["criterion", "knob", "triangles", "seconds", "error", "mean_abs"]),
        f"Criteria at equal error (the RMS error {figures['criteria_target_error']:.4g} of `share` at its default "
        f"tolerance {defaults.tolerance:g}) and at equal triangle count ({figures['criteria_equal_triangles']}, "
        "`share`'s count there); log-log interpolation on each curve, `<=` / `>=` where the target lies outside "
        "the sweep:\n\n"
        + harness.markdown_table(comparison_rows, ["criterion", "triangles at equal error", "x share triangles",
                                                   "error at equal triangles", "x share error"]),
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


def _curve(rows: list[dict], criterion: str) -> tuple[np.ndarray, np.ndarray]:
    """(triangles, error) of one criterion's runs, by triangle count (ties: lower error first)."""
    runs = sorted((r["triangles"], r["error"]) for r in rows if r["criterion"] == criterion)
    return (np.array([t for t, _ in runs], np.float64),
            np.maximum(np.array([e for _, e in runs], np.float64), 1e-12))


def _triangles_at_error(tris: np.ndarray, errors: np.ndarray, goal: float) -> tuple[float, str]:
    """Triangles at which a curve first reaches ``goal`` (log-log interpolation), and '=' or, when the goal
    lies outside the sweep, '<=' (the coarsest run already reaches it) / '>=' (not even the finest does)."""
    below = np.flatnonzero(errors <= goal)
    if len(below) == 0:
        return float(tris[-1]), ">="
    k = int(below[0])
    if k == 0:
        return float(tris[0]), "<=" if errors[0] < goal else "="
    t = (np.log(goal) - np.log(errors[k - 1])) / (np.log(errors[k]) - np.log(errors[k - 1]))
    return float(np.exp(np.log(tris[k - 1]) + t * (np.log(tris[k]) - np.log(tris[k - 1])))), "="


def _error_at_triangles(tris: np.ndarray, errors: np.ndarray, count: float) -> tuple[float, str]:
    """A curve's error at ``count`` triangles (log-log interpolation between the runs around it), and '=' or,
    outside the sweep, '>=' (count below the coarsest run) / '<=' (above the finest)."""
    if count < tris[0]:
        return float(errors[0]), ">="
    if count > tris[-1]:
        return float(errors[-1]), "<="
    same = tris == count
    if same.any():
        return float(errors[same].min()), "="
    k = int(np.searchsorted(tris, count))
    t = (np.log(count) - np.log(tris[k - 1])) / (np.log(tris[k]) - np.log(tris[k - 1]))
    return float(np.exp(np.log(errors[k - 1]) + t * (np.log(errors[k]) - np.log(errors[k - 1])))), "="


def _criteria_figures(rows: list[dict], default_tolerance: float) -> dict:
    """Per criterion its (knob, triangles, error, seconds) curve, the triangles it needs for the error of
    ``share`` at its default tolerance, and its error at that run's triangle count."""
    target = next(r for r in rows if r["criterion"] == "share" and r["knob"] == f"tolerance {default_tolerance:g}")
    figures = {"criteria_target_error": round(target["error"], 5), "criteria_equal_triangles": target["triangles"]}
    for criterion in CRITERIA:
        figures[f"criteria_{criterion}_curve"] = [
            [r["value"], r["triangles"], round(r["error"], 5), round(r["seconds"], 3)]
            for r in rows if r["criterion"] == criterion]
    for criterion in CRITERIA:
        tris, errors = _curve(rows, criterion)
        needed, bound = _triangles_at_error(tris, errors, target["error"])
        figures[f"criteria_{criterion}_triangles_at_target_error"] = round(needed)
        figures[f"criteria_{criterion}_triangles_at_target_error_bound"] = bound
        figures[f"criteria_{criterion}_triangles_vs_share"] = round(needed / target["triangles"], 3)
        error, bound = _error_at_triangles(tris, errors, target["triangles"])
        figures[f"criteria_{criterion}_error_at_equal_triangles"] = round(error, 5)
        figures[f"criteria_{criterion}_error_at_equal_triangles_bound"] = bound
        figures[f"criteria_{criterion}_error_vs_share"] = round(error / target["error"], 3)
    return figures


def _criteria_comparison(rows: list[dict], figures: dict) -> list[dict]:
    """The equal-error / equal-triangles table rows from ``_criteria_figures``' figures."""
    def shown(key):
        bound = figures[f"{key}_bound"]
        value = figures[key]
        return ("" if bound == "=" else f"{bound} ") + (str(value) if isinstance(value, int) else f"{value:.4g}")

    return [{"criterion": c,
             "triangles at equal error": shown(f"criteria_{c}_triangles_at_target_error"),
             "x share triangles": figures[f"criteria_{c}_triangles_vs_share"],
             "error at equal triangles": shown(f"criteria_{c}_error_at_equal_triangles"),
             "x share error": figures[f"criteria_{c}_error_vs_share"]} for c in CRITERIA]


def _median_ms(function, repeats: int) -> float:
    """Median milliseconds of ``repeats`` calls after one warm-up call."""
    function()
    return 1000.0 * float(np.median(harness.timings(function, repeats)))
