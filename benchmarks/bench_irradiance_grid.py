"""Irradiance vector grid on cornell_box.usda: grid size / rays against the error of the reconstructed
irradiance, quantized vs float memory, and the progressive-streaming curve with push-pull."""

from __future__ import annotations

import time

import numpy as np

from . import harness
from .references import point_irradiance
from usdbake.kernels.lights import LUMINANCE
from usdbake.kernels.direction24 import AXES, dequantize_vectors

NAME = "irradiance_grid"
DESCRIPTION = (
    "`irradiance_grid` on `cornell_box.usda`. Error = relative RMS of the luminance of the reconstructed "
    "irradiance E(p, n) (paper 3.2, default normal offset) against a brute-force per-point reference "
    "(cosine-weighted rays at 16x the default 256, same one-bounce light model, different seed, cached), "
    "divided by the reference's mean, at area-uniform random surface points with their face normals (the "
    "box's mesh has only 89 vertices, all on quad corners; the error at those is reported too). `total` "
    "= direct + one-bounce light (the default), `indirect` = the paper's indirect-only grid "
    "(include_direct=false). Knob: grid vertices (cell size) and rays per vertex.")
DEFAULT_VERTICES = 20000
DEFAULT_RAYS = 256


def _relative_rms(estimate: np.ndarray, reference: np.ndarray) -> float:
    e, r = estimate @ LUMINANCE, reference @ LUMINANCE
    return float(np.sqrt(np.mean((e - r) ** 2)) / max(float(np.mean(r)), 1e-30))


SRGB_TO_XYZ = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
"""Linear sRGB (D65) to CIE XYZ."""
D65_WHITE = SRGB_TO_XYZ.sum(axis=1)


def _lab(rgb: np.ndarray) -> np.ndarray:
    """CIELAB (D65) of linear sRGB colours."""
    t = (rgb @ SRGB_TO_XYZ.T) / D65_WHITE
    f = np.where(t > (6 / 29) ** 3, np.cbrt(t), t / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.stack([116 * f[:, 1] - 16, 500 * (f[:, 0] - f[:, 1]), 200 * (f[:, 1] - f[:, 2])], axis=1)


def _shared_direction(vectors: np.ndarray) -> np.ndarray:
    """The paper's representation in float: per hemisphere one direction d (of I^R + I^G + I^B) and the
    colour c = I . delta / (d . delta), vectors c d -- what the 42 bytes quantize."""
    v = np.asarray(vectors, np.float64)
    axes = AXES[None, :, :].astype(np.float64)
    total = v.sum(axis=2)
    d = total / np.maximum(np.linalg.norm(total, axis=2, keepdims=True), 1e-300)
    d = np.where(np.linalg.norm(total, axis=2, keepdims=True) > 0, d, axes)
    along = np.einsum("vhci,hi->vhc", v, AXES.astype(np.float64))
    c = np.maximum(along, 0.0) / np.maximum(np.einsum("vhi,hi->vh", d, AXES.astype(np.float64)), 1e-300)[..., None]
    return (c[..., None] * d[:, :, None, :]).astype(np.float32)


def _mean_delta_e(estimate: np.ndarray, reference: np.ndarray) -> float:
    """Mean CIE76 Delta E between two sets of irradiance colours, both scaled so the reference's brightest
    luminance is white (L* 100): Delta E 0.1 is 0.1 % of the lightness range, the paper's measure."""
    scale = 1.0 / max(float((reference @ SRGB_TO_XYZ[1]).max()), 1e-30)
    lab_e, lab_r = _lab(np.maximum(estimate, 0) * scale), _lab(np.maximum(reference, 0) * scale)
    return float(np.linalg.norm(lab_e - lab_r, axis=1).mean())


def run(quick: bool = False) -> dict:
    from usdbake.formats import streaming
    from usdbake.geometry.mesh import vertex_normals
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.irradiance_grid import irradiance_grid as ig
    from usdbake.processors.irradiance_grid.vector_grid import grid_layout, reconstruct_irradiance

    scene = harness.load_scene("cornell_box")
    tracer = Tracer.from_scene(scene)
    count = 1000 if quick else 4000
    points, normals = harness.surface_points(scene, count, seed=5)  # every receiver of the box: all its faces
    vertex_n = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
    reference_rays = 16 * DEFAULT_RAYS
    references = {}
    for mode, direct in (("total", True), ("indirect", False)):
        references[mode] = harness.cached_reference(
            f"irradiance_grid_cornell_{mode}",
            {"rays": reference_rays, "seed": 99, "points": count, "version": ig.IrradianceGrid.version,
             "include_direct": direct, "light_model": "sampled area lights, emission seen only without UsdLux"},
            lambda direct=direct: {
                "surface": point_irradiance(tracer, scene, points, normals, rays=reference_rays, seed=99,
                                            include_direct=direct),
                "vertices": point_irradiance(tracer, scene, scene.points, vertex_n, rays=reference_rays, seed=99,
                                             include_direct=direct)})
    lo, hi = scene.bounds
    ig.bake_grid(tracer, scene, grid_layout(lo, hi, vertices=64), rays=4)  # compile outside the timing
    point_irradiance(tracer, scene, points[:10], normals[:10], rays=4)
    # The reference's own noise: the same estimator at the same rays with another seed (heavy-tailed:
    # one light sample per bounce hit, large for hits close to the big ceiling light).
    reference_noise = {}
    for mode, direct in (("total", True), ("indirect", False)):
        again = point_irradiance(tracer, scene, points, normals, rays=reference_rays, seed=7, include_direct=direct)
        reference_noise[mode] = round(_relative_rms(again, references[mode]["surface"]), 4)
    # The per-point ray-casting noise floor at the default rays (what the grid's sampling competes with).
    direct_noise = _relative_rms(point_irradiance(tracer, scene, points, normals, rays=DEFAULT_RAYS, seed=1),
                                 references["total"]["surface"])

    settings = [(2000, 256), (8000, 256), (20000, 64), (20000, 256)] if quick else \
        [(2000, 256), (8000, 256), (20000, 64), (20000, 256), (20000, 1024), (60000, 256)]
    rows, grids = [], {}
    for vertices, rays in settings:
        layout = grid_layout(lo, hi, vertices=vertices)
        row = {"label": f"{layout.count} v / {rays} rays", "vertices": layout.count, "rays": rays,
               "cell_size": round(float(layout.cell_size[0]), 3),
               "default": vertices == DEFAULT_VERTICES and rays == DEFAULT_RAYS}
        for mode, direct in (("total", True), ("indirect", False)):
            with harness.measure() as m:
                grid = ig.bake_grid(tracer, scene, layout, rays=rays, include_direct=direct)
            estimate = reconstruct_irradiance(layout, dequantize_vectors(grid.directions, grid.colors), points,
                                                 normals)
            row[f"error_{mode}"] = _relative_rms(estimate, references[mode]["surface"])
            row[f"seconds_{mode}"] = m.seconds
            grids[(vertices, rays, mode)] = grid
        row["seconds"], row["error"] = row["seconds_total"], row["error_total"]
        rows.append(row)

    default = grids[(DEFAULT_VERTICES, DEFAULT_RAYS, "total")]
    layout = default.layout
    decoded = dequantize_vectors(default.directions, default.colors)
    ref = references["total"]["surface"]
    figures = {"surface_points": count, "reference_rays": reference_rays, "grid_vertices_default": layout.count,
               "cell_size_default": round(float(layout.cell_size[0]), 3),
               "valid_fraction_default": round(float(default.vertex_valid.mean()), 4),
               "error_total_default": round(next(r["error_total"] for r in rows if r["default"]), 4),
               "error_indirect_default": round(next(r["error_indirect"] for r in rows if r["default"]), 4),
               "per_point_raycast_error_at_256_rays": round(direct_noise, 4),
               "reference_seed_to_seed_error_total": reference_noise["total"],
               "reference_seed_to_seed_error_indirect": reference_noise["indirect"]}
    figures["error_total_at_mesh_vertices_default"] = round(_relative_rms(
        reconstruct_irradiance(layout, decoded, scene.points, vertex_n), references["total"]["vertices"]), 4)

    # Quantization: memory and the error it adds (float vectors vs 8:8:8 direction + RGB9E5).
    float_estimate = reconstruct_irradiance(layout, default.vectors, points, normals)
    quant_estimate = reconstruct_irradiance(layout, decoded, points, normals)
    quantized_bytes = default.directions[0].nbytes + default.colors[0].nbytes
    figures["quantized_bytes_per_vertex"] = quantized_bytes
    figures["float_bytes_per_vertex"] = 6 * 9 * 4
    figures["quantized_grid_kib_default"] = round(layout.count * quantized_bytes / 1024, 1)
    figures["float_grid_kib_default"] = round(layout.count * 216 / 1024, 1)
    figures["quantization_error_vs_float"] = round(_relative_rms(quant_estimate, float_estimate), 5)
    at_vertices = {name: reconstruct_irradiance(layout, vectors, scene.points, vertex_n) for name, vectors in
                   (("quantized", decoded), ("shared", _shared_direction(default.vectors)), ("full", default.vectors))}
    figures["quantization_mean_delta_e_at_mesh_vertices"] = round(_mean_delta_e(at_vertices["quantized"],
                                                                                at_vertices["shared"]), 5)
    figures["shared_direction_mean_delta_e_at_mesh_vertices"] = round(_mean_delta_e(at_vertices["shared"],
                                                                                    at_vertices["full"]), 5)
    figures["error_total_default_float_grid"] = round(_relative_rms(float_estimate, ref), 4)

    # Reconstruction variants at the default grid.
    variants = {}
    for reconstruction in ("paper", "normalized"):
        for offset in (0.0, 0.25, 0.5, 1.0):
            for cutoff in (False, True):
                estimate = reconstruct_irradiance(layout, decoded, points, normals, normal_offset=offset,
                                                     reconstruction=reconstruction, behind_cutoff=cutoff)
                key = f"{reconstruction}_offset_{offset:g}" + ("_behind_cutoff" if cutoff else "")
                variants[key] = round(_relative_rms(estimate, ref), 4)
    for key in ("paper_offset_0", "paper_offset_1", "normalized_offset_0.5", "paper_offset_0.5_behind_cutoff"):
        figures[f"error_total_{key}"] = variants[key]

    # Progressive streaming: the first fraction of the stream, the rest filled by push-pull.
    order = streaming.progressive_order(layout.resolution)
    order = order[default.vertex_valid[order]]
    raster = np.flatnonzero(default.vertex_valid)
    flat = decoded.reshape(layout.count, -1)
    curve = []
    for fraction in ([1 / 64, 1 / 8, 1 / 2, 1.0] if quick else [1 / 256, 1 / 64, 1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0]):
        row = {"fraction": fraction}
        for label, sequence, smooth in (("progressive_smooth", order, True), ("progressive", order, False),
                                        ("raster_smooth", raster, True)):
            known = np.zeros(layout.count, bool)
            known[sequence[:max(1, int(round(fraction * len(sequence))))]] = True
            started = time.perf_counter()
            filled = streaming.push_pull(flat, layout.resolution, known, smooth=smooth)
            seconds = time.perf_counter() - started
            estimate = reconstruct_irradiance(layout, filled.reshape(-1, 6, 3, 3), points, normals)
            row[f"error_{label}"] = round(_relative_rms(estimate, ref), 4)
            row[f"seconds_{label}"] = round(seconds, 3)
        curve.append(row)
    for row in curve:
        if row["fraction"] in (1 / 64, 1 / 8, 1 / 2):
            name = f"1/{round(1 / row['fraction'])}"
            figures[f"stream_error_at_{name}_progressive_smooth"] = row["error_progressive_smooth"]
            figures[f"stream_error_at_{name}_raster_smooth"] = row["error_raster_smooth"]
    figures["stream_bytes_default"] = len(ig.stream_bytes(default, scene.origin))

    table = harness.markdown_table(rows, ["label", "cell_size", "seconds_total", "error_total", "seconds_indirect",
                                          "error_indirect"])
    table += "\n\nProgressive streaming (default grid, total light): error vs fraction of the stream received, " \
             "the rest filled by push-pull.\n\n"
    table += harness.markdown_table(curve, ["fraction", "error_progressive_smooth", "error_progressive",
                                            "error_raster_smooth", "seconds_progressive_smooth"])
    table += "\n\nReconstruction variants on the default grid (error_total; offset in cells):\n\n"
    table += harness.markdown_table([{"variant": k, "error_total": v} for k, v in variants.items()],
                                    ["variant", "error_total"])
    data = harness.result(NAME, description=DESCRIPTION,
                          settings={"reference_rays": reference_rays, "surface_points": count, "quick": quick},
                          points=rows, figures=figures, table=table, knob="grid vertices / rays per vertex",
                          error_label="relative RMS of luminance vs brute-force reference")
    data["streaming_curve"] = curve
    data["reconstruction_variants"] = variants
    return data
