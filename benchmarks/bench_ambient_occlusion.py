"""AO on atrium.usda: error against a 16x-samples run, per sample count; end-to-end bake time."""

from __future__ import annotations

import time

import numpy as np

from . import harness

NAME = "ambient_occlusion"
DESCRIPTION = ("Per-vertex AO on `atrium.usda`. Error = RMS difference (AO in [0, 1]) from a run at 16x the "
               "default samples (4096 rays per vertex, different seed), cached. Also the end-to-end "
               "`usdbake bake samples/atrium.usda` wall time at default settings (kernels already compiled).")
DEFAULT_SAMPLES = 256


def run(quick: bool = False) -> dict:
    from usdbake.geometry.mesh import vertex_normals
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.occlusion.ambient_occlusion import AmbientOcclusion, compute_vertex_ao

    scene = harness.load_scene("atrium")
    tracer = Tracer.from_scene(scene)
    normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
    points = scene.points
    if quick:  # a fixed subset of vertices keeps the quick sweep short
        subset = np.random.default_rng(3).choice(len(points), min(4000, len(points)), replace=False)
        points, normals = points[subset], normals[subset]
    reference_samples = 16 * DEFAULT_SAMPLES
    reference = harness.cached_reference(
        "ao_atrium", {"samples": reference_samples, "seed": 99, "quick": quick, "points": len(points),
                      "version": AmbientOcclusion.version},
        lambda: {"ao": compute_vertex_ao(tracer, points, normals, samples=reference_samples, seed=99)})["ao"]
    compute_vertex_ao(tracer, points[:100], normals[:100], samples=4)  # compile outside the timing
    rows = []
    for samples in ([16, 64, 256] if quick else [16, 64, 256, 1024]):
        started = time.perf_counter()
        ao = compute_vertex_ao(tracer, points, normals, samples=samples, seed=0)
        seconds = time.perf_counter() - started
        rms = float(np.sqrt(np.mean((ao - reference) ** 2)))
        rows.append({"label": samples, "samples": samples, "seconds": seconds, "error": rms,
                     "mrays_per_s": len(points) * samples / seconds / 1e6, "default": samples == DEFAULT_SAMPLES})
    figures = {"vertices": len(points), "rms_at_default_vs_16x": round(next(r["error"] for r in rows
                                                                              if r["default"]), 5)}
    if not quick:
        figures["bake_wall_seconds_default"] = round(harness.bake_wall_seconds(harness.SAMPLES / "atrium.usda"), 3)
    table = harness.markdown_table(rows, ["samples", "seconds", "error", "mrays_per_s"])
    return harness.result(NAME, description=DESCRIPTION, settings={"reference_samples": reference_samples},
                          points=rows, figures=figures, table=table, knob="samples per vertex",
                          error_label="AO RMS vs 16x samples")

