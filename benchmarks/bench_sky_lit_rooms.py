"""Radiosity, irradiance_grid and light_probes at CLI defaults in sky-lit furnished rooms, against Radiance."""

from __future__ import annotations

import tempfile
import time

import numpy as np

from . import harness

NAME = "sky_lit_rooms"
DESCRIPTION = (
    "radiosity, irradiance_grid and light_probes, each baked alone at CLI defaults (`usdbake.bake(stage, "
    "processors=[name])`, a fresh cache, timed), read back with `usdbake.irradiance_at`, against Radiance "
    "`rtrace -I -ab 8 -aa 0` in two independent halves (`benchmarks/sky_lit_references.py`; the sky converted "
    "by `benchmarks/radiance_dome.py`: the dome's lat-long EXR through `colorpict`, the sun a `source` of the "
    "DistantLight's angle and radiance). Rooms (`benchmarks/sky_lit_scenes.py`): the furnished daylight room of "
    "issue 29 with its four windows open (~129k triangles, 200 m ground; the three techniques do not model "
    "glass) and the furnished room of the benchmarks, each with a probe volume on the room. Skies: a uniform "
    "DomeLight, and `usdbake sky --model perez` (Greensboro NC, 21 March 14:00, DNI 600, DHI 150: sun through "
    "the south and west windows). Rows (fixed seeds): surface points inside the room (radiosity; Radiance 1 mm "
    "off the face), free-space points >= 10 cm from geometry x 6 axis normals and points 5 cm off surfaces "
    "(grid, probes). Error = |relative error| of the irradiance luminance (Rec. 709), median over the rows; "
    "bias = mean estimate / mean reference - 1; ref. noise = median |a - b| / (a + b) of Radiance's halves.")
TECHNIQUES = ("radiosity", "irradiance_grid", "light_probes")
KINDS = {"radiosity": ("surface",), "irradiance_grid": ("free", "near"), "light_probes": ("free", "near")}
"""The rows each technique is read at: radiosity stores irradiance on the surfaces, the others in space."""
FULL = {"scenes": ("daylight_room", "furnished_room"), "skies": ("uniform", "perez"), "surface": 100, "free": 100,
        "near": 100, "ambient_divisions": 4096, "params": {}}
QUICK = {"scenes": ("furnished_room",), "skies": ("perez",), "surface": 8, "free": 2, "near": 4,
         "ambient_divisions": 64,
         "params": {"radiosity": {"form_factors": {"target_patches": 64, "rays": 64},
                                  "radiosity": {"sky_samples": 16, "gather_rays": 16}},
                    "irradiance_grid": {"irradiance_grid": {"vertices": 64, "rays": 16}},
                    "light_probes": {"light_probes": {"probes": 16, "rays": 16, "sky_rays": 16, "placement_rays": 4,
                                                      "iterations": 1}}}}
"""QUICK is a smoke test only: small parameters ({technique: usdbake.bake params}), not the defaults."""


def run(quick: bool = False) -> dict:
    import usdbake
    from usdbake.kernels.lights import LUMINANCE  # Rec. 709 weights only

    from . import radiance_binaries, radiance_dome
    from . import sky_lit_references as references
    from . import sky_lit_scenes as scenes

    settings = QUICK if quick else FULL
    with_radiance = not quick and radiance_binaries.radiance_available()  # the smoke run bakes and reads only
    rows, figures, checks = [], {}, {}
    for name in settings["scenes"]:
        with tempfile.TemporaryDirectory(prefix=f"sky_lit_{name}_") as folder:
            stages = {sky: scenes.room_stage(name, sky, folder) for sky in settings["skies"]}
            points = scenes.test_points(name, scenes.room_stage(name, "uniform", folder), surface=settings["surface"],
                                        free=settings["free"], near=settings["near"])
            query = points.rows()
            for sky, stage in stages.items():
                if not with_radiance:
                    figures.update(_bakes_only(usdbake, name, sky, stage, query, settings["params"]))
                    continue
                ref = references.reference(name, sky, stage, points, ambient_divisions=settings["ambient_divisions"])
                reference = ref["irradiance"] @ LUMINANCE
                noise = references.noise(ref, LUMINANCE)
                sky_lights = radiance_dome.read_stage_sky(stage)
                check = radiance_dome.horizontal_check(sky_lights, folder) if sky_lights.texture is not None else {}
                if check:
                    checks[f"{name}_{sky}"] = check
                    figures[f"{name}_{sky}_sky_check_max_abs_error"] = round(check["max_abs_relative_difference"], 5)
                figures[f"{name}_{sky}_reference_seconds"] = round(float(ref["rtrace_seconds"]), 1)
                for technique in TECHNIQUES:
                    path = stage.GetRootLayer().realPath
                    seconds, values, probes = _bake_and_read(usdbake, path, technique,
                                                             settings["params"].get(technique),
                                                             [query[kind] for kind in KINDS[technique]])
                    for kind, value in zip(KINDS[technique], values):
                        mask = ref["kind"] == kind
                        row = _row(name, sky, technique, kind, value @ LUMINANCE, reference[mask], noise[mask],
                                   seconds)
                        rows.append(row)
                        key = f"{name}_{sky}_{technique}_{kind}"
                        figures[f"{key}_median_abs_error"] = row["error"]
                        figures[f"{key}_bias"] = row["bias"]
                        figures[f"{name}_{sky}_{kind}_reference_noise"] = row["ref_noise"]
                    figures[f"{name}_{sky}_{technique}_seconds"] = round(seconds, 2)
                    if technique == "light_probes":
                        count, seconds, values = _equal_count_grid(
                            path, scenes.ROOM_BOXES[name], probes, [query[kind] for kind in KINDS[technique]],
                            settings["params"].get(technique, {}).get(technique, {}))
                        figures[f"{name}_{sky}_light_probes_probes"] = probes
                        for kind, value in zip(KINDS[technique], values):
                            mask = ref["kind"] == kind
                            row = _row(name, sky, f"uniform grid ({count} probes)", kind, value @ LUMINANCE,
                                       reference[mask], noise[mask], seconds)
                            rows.append(row)
                            probes = next(r for r in rows if r["technique"] == "light_probes"
                                          and r["scene"] == name and r["sky"] == sky and r["rows_at"] == kind)
                            figures[f"{name}_{sky}_light_probes_over_equal_grid_{kind}_error"] = round(
                                probes["error"] / max(row["error"], 1e-12), 3)
    if with_radiance:
        figures.update(_worst(figures, settings))
    table = harness.markdown_table(rows, ["scene", "sky", "technique", "rows_at", "rows", "seconds", "error",
                                          "bias", "mean_ratio_bias", "p90_error", "ref_noise"])
    table += ("\n\nSky conversion, empty scene, Radiance -ab 1 -ad 65536 vs the texture integrated texel by texel "
              "+ the sun (luminance, six axis normals): " + "; ".join(
                  f"{k}: max |diff| {v['max_abs_relative_difference']:.4f} "
                  f"(up {v['horizontal_relative_difference']:+.4f})" for k, v in checks.items()))
    return harness.result(NAME, description=DESCRIPTION,
                          settings={**settings, "perez": scenes.PEREZ,
                                    "radiance": {"ambient_bounces": references.AMBIENT_BOUNCES + 1,
                                                 "halves": 2, "sky_checks": checks}},
                          points=rows, figures=figures, table=table, knob="technique (defaults)",
                          error_label="median |rel. error| of irradiance luminance vs Radiance")


def _bake_and_read(usdbake, path: str, technique: str, params: dict | None,
                   queries: list) -> tuple[float, list, int]:
    """Bake ``technique`` alone into a freshly opened stage of ``path`` (its session layer; a fresh cache),
    timed, then read it at each (points, normals) of ``queries`` with ``usdbake.irradiance_at``: (seconds,
    [(N, 3) float64 per query], probes of the cloud or 0)."""
    from pxr import Usd

    stage = Usd.Stage.Open(path)
    with tempfile.TemporaryDirectory() as cache:
        started = time.perf_counter()
        usdbake.bake(stage, processors=[technique], params=params, cache_dir=cache,
                     texture_dir=cache, force=True)
        seconds = time.perf_counter() - started
        values = [np.asarray(usdbake.irradiance_at(stage, p, n, source=technique, allow_partial=True), np.float64)
                  for p, n in queries]
        if _direct_left_to_lookup(stage):
            values = [v + _lookup_direct(stage, p, n) for v, (p, n) in zip(values, queries)]
        probes = sum(len(prim.GetAttribute("probePositions").Get() or []) for prim in stage.Traverse()
                     if prim.GetTypeName() == "LightProbeCloud")
    return seconds, values, probes


def _equal_count_grid(path: str, box, count: int, queries: list, params: dict) -> tuple[int, float, list]:
    """The light_probes baseline of ``bench_light_probes``: a uniform lattice over the room's box (shrunk by
    ``probe_reference.ROOM_SHRINK``) of at most ``count`` probes (the baked cloud's), captured by the cloud's own
    ``compute_probe_sh`` at the processor's default rays, sky rays and bounces, read trilinearly, plus the
    lookup's direct light: (probes, capture seconds, [(N, 3) float64 per query])."""
    from pxr import Usd

    from usdbake.kernels.sh import sh_basis_np
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.light_probes.capture import compute_probe_sh, direct_light_irradiance
    from usdbake.processors.light_probes.light_probes import LightProbes
    from usdbake.stages.extract import extract_scene

    from . import probe_reference as ref

    defaults = LightProbes.Params(**params)
    stage = Usd.Stage.Open(path)
    scene = extract_scene(stage)
    tracer = Tracer.from_scene(scene)
    lo, hi = (np.asarray(b, np.float64) - scene.origin for b in box)
    lo, hi = lo + ref.ROOM_SHRINK, hi - ref.ROOM_SHRINK
    positions, dims = ref.grid_positions(lo, hi, count)
    started = time.perf_counter()
    sh = compute_probe_sh(tracer, scene, positions, rays=defaults.rays, seed=1_000_003, bounces=defaults.bounces,
                          direct_lights=False, sky_rays=defaults.sky_rays)
    seconds = time.perf_counter() - started
    out = []
    for points, normals in queries:
        local = np.asarray(points, np.float64) - scene.origin
        index, weights = ref.grid_weights(lo, hi, dims, local)
        interpolated = np.einsum("nv,nvkc->nkc", weights, sh[index].astype(np.float64))
        e = np.einsum("nk,nkc->nc", sh_basis_np(np.asarray(normals, np.float64)), interpolated)
        out.append(e + np.asarray(direct_light_irradiance(tracer, scene, local, normals), np.float64))
    return len(positions), seconds, out


def _direct_left_to_lookup(stage) -> bool:
    """Whether the stage's LightProbeCloud was baked with ``direct_lights=lookup`` (the default): its SH lack
    the distant light's (the sun's) direct light, which the lookup adds by shadow rays."""
    for prim in stage.Traverse():
        if prim.GetTypeName() == "LightProbeCloud":
            attribute = prim.GetAttribute("bake:directLights")
            return bool(attribute) and attribute.Get() == "excluded"
    return False


def _lookup_direct(stage, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(N, 3) float64 the lookup's direct light (``light_probes.capture.direct_light_irradiance``: the distant,
    sphere, rect and disk lights by shadow rays) at world points: the part of a default light_probes bake
    that ``usdbake.irradiance_at`` leaves out (``allow_partial``)."""
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.light_probes.capture import direct_light_irradiance
    from usdbake.stages.extract import extract_scene

    scene = extract_scene(stage)
    tracer = Tracer.from_scene(scene)
    local = np.asarray(points, np.float64) - scene.origin
    return np.asarray(direct_light_irradiance(tracer, scene, local, normals), np.float64)


def _bakes_only(usdbake, name: str, sky: str, stage, query: dict, params: dict) -> dict:
    """Without Radiance (the smoke run): each technique baked and read back, its time and mean luminance."""
    from usdbake.kernels.lights import LUMINANCE

    figures = {}
    for technique in TECHNIQUES:
        seconds, values, _ = _bake_and_read(usdbake, stage.GetRootLayer().realPath, technique,
                                            params.get(technique), [query[kind] for kind in KINDS[technique]])
        figures[f"{name}_{sky}_{technique}_seconds"] = round(seconds, 2)
        for kind, value in zip(KINDS[technique], values):
            figures[f"{name}_{sky}_{technique}_{kind}_mean_luminance"] = round(float((value @ LUMINANCE).mean()), 4)
    return figures


def _worst(figures: dict, settings: dict) -> dict:
    """Issue 30's figures over both rooms and both skies: the worst median error, |bias| and cloud / grid ratio."""
    cases = [f"{scene}_{sky}" for scene in settings["scenes"] for sky in settings["skies"]]
    worst = {}
    for technique, kind in (("radiosity", "surface"), ("irradiance_grid", "free"), ("irradiance_grid", "near"),
                            ("light_probes", "free"), ("light_probes", "near")):
        worst[f"worst_{technique}_{kind}_median_abs_error"] = max(
            figures[f"{case}_{technique}_{kind}_median_abs_error"] for case in cases)
        worst[f"worst_{technique}_{kind}_abs_bias"] = max(
            abs(figures[f"{case}_{technique}_{kind}_bias"]) for case in cases)
    for technique in TECHNIQUES:  # the bake times on the 129k-triangle daylight room (issue 30's time clause)
        worst[f"worst_{technique}_seconds"] = max(
            figures[f"{case}_{technique}_seconds"] for case in cases if case.startswith("daylight_room"))
    for kind in ("free", "near"):
        worst[f"worst_light_probes_over_equal_grid_{kind}_error"] = max(
            figures[f"{case}_light_probes_over_equal_grid_{kind}_error"] for case in cases)
    return worst


def _row(scene: str, sky: str, technique: str, kind: str, estimate: np.ndarray, reference: np.ndarray,
         noise: np.ndarray, seconds: float) -> dict:
    """Median and p90 |relative error|, bias (ratio of means - 1, and mean ratio - 1) of luminance at the rows."""
    ratio = estimate / np.maximum(reference, 1e-300)
    error = np.abs(ratio - 1.0)
    return {"scene": scene, "sky": sky, "technique": technique, "rows_at": kind, "rows": int(len(reference)),
            "label": f"{scene} {sky} {technique} {kind}", "default": True, "seconds": round(seconds, 2),
            "error": round(float(np.median(error)), 4), "p90_error": round(float(np.percentile(error, 90)), 4),
            "bias": round(float(estimate.mean() / reference.mean() - 1.0), 4),
            "mean_ratio_bias": round(float(ratio.mean() - 1.0), 4),
            "ref_noise": round(float(np.median(noise)), 4)}
