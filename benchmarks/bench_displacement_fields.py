"""Displacement fields + instance_ao: accuracy vs ambient_occlusion, resolution table, per-ray scaling, memory."""

from __future__ import annotations

import time

import numpy as np

from . import harness
from usdbake.processors.instancing.products import DisplacementField, DisplacementFieldSet, InstanceOcclusionProduct
from usdbake.processors.occlusion.products import AmbientOcclusionProduct

NAME = "displacement_fields"
DESCRIPTION = (
    "`displacement_fields` + `instance_ao` on `instanced_props.usda` (60 vases of 6192 triangles, 20 crates, "
    "AO at the 256 floor vertices, 256 rays each). Error = RMS difference (AO in [0, 1]) from "
    "`ambient_occlusion` with the same rays (same seed and strata) against the exact BVH, so it is the field "
    "approximation alone. Seconds = field build (both prototypes) + AO. The per-ray scaling uses synthetic "
    "bumpy spheres from ~5k to ~500k triangles: field lookups vs BVH any-hit rays, same rays, 2 threads.")
DEFAULT = (4225, 32, "uint8")


def bumpy_sphere(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Latitude-longitude sphere with bumps: n bands x 2n sectors, 4n^2 - 4n triangles, outward winding."""
    theta = np.linspace(0, np.pi, n + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, 2 * n, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    r = 1.0 + 0.08 * np.sin(7 * t) * np.cos(9 * p)
    ring = np.stack([r * np.sin(t) * np.cos(p), r * np.cos(t), r * np.sin(t) * np.sin(p)], axis=-1).reshape(-1, 3)
    points = np.r_[ring, [[0, 1, 0], [0, -1, 0]]]
    top, bottom = len(ring), len(ring) + 1
    sectors = 2 * n
    i, j = np.meshgrid(np.arange(n - 2), np.arange(sectors), indexing="ij")
    a = (i * sectors + j).ravel()
    b = (i * sectors + (j + 1) % sectors).ravel()
    quads = np.c_[a, b, b + sectors, a + sectors]
    tris = [quads[:, [0, 2, 1]], quads[:, [0, 3, 2]]]
    k = np.arange(sectors)
    tris.append(np.c_[np.full(sectors, top), (k + 1) % sectors, k])
    last = (n - 2) * sectors
    tris.append(np.c_[np.full(sectors, bottom), last + k, last + (k + 1) % sectors])
    return points, np.concatenate(tris).astype(np.int32)


def run(quick: bool = False) -> dict:
    from usdbake import core
    from usdbake.processors.instancing.field_kernels import encode_field
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.occlusion.ambient_occlusion import AmbientOcclusion
    from usdbake.processors.instancing.displacement_fields import (
        DisplacementFields,
        compute_field_distances,
        prototype_geometry,
        side_for,
    )
    from usdbake.processors.instancing.instance_ao import InstanceAO

    scene = harness.load_scene("instanced_props")
    receivers = harness.receiver_points(scene)

    # reference: the exact AO with a BVH over all 372k triangles (BVH build included: per frame, it must be redone)
    started = time.perf_counter()
    tracer = Tracer.from_scene(scene)
    bvh_build = time.perf_counter() - started
    ctx = core.Context(scene=scene, params=AmbientOcclusion.Params(), tracer=tracer)
    AmbientOcclusion().run(ctx)  # compile outside the timing
    started = time.perf_counter()
    reference = AmbientOcclusion().run(ctx).products[AmbientOcclusionProduct].point_ao
    reference_seconds = time.perf_counter() - started + bvh_build

    def rms(ao) -> float:  # over the receivers' points, AO in [0, 1]
        return float(np.sqrt(np.mean((ao[receivers] - reference[receivers]) ** 2)))

    prototypes = {path: prototype_geometry(scene, index) for index, path in enumerate(scene.instances.prototype_paths)}
    sweep = ([(289, 16), (1089, 16), (1089, 32)] if quick else
             [(1089, 16), (1089, 32), (1089, 64), (2116, 16), (2116, 32), (2116, 64), (4225, 16), (4225, 32),
              (4225, 64)])
    rows = []
    for positional, size in sweep:
        side = side_for(positional)
        distances, build = {}, 0.0
        for path, (points, triangles, _) in prototypes.items():
            started = time.perf_counter()
            distances[path] = compute_field_distances(points, triangles, side=side, map_size=size)
            build += time.perf_counter() - started
        for encoding in ("uint8", "bit1"):
            fields = {}
            for path, (values, center, radius) in distances.items():
                texels, means = encode_field(values, encoding)
                fields[path] = DisplacementField(path, center, radius, side, size, encoding, texels, means,
                                                 len(prototypes[path][1]))
            ao_ctx = core.Context(scene=scene, params=InstanceAO.Params(), tracer=None,
                                  products={DisplacementFieldSet: DisplacementFieldSet(fields)})
            InstanceAO().run(ao_ctx)  # compile / warm
            started = time.perf_counter()
            ao = InstanceAO().run(ao_ctx).products[InstanceOcclusionProduct].point_ao_by_frame[None]
            query = time.perf_counter() - started
            vase = fields["/World/Scatter/Prototypes/Vase"]
            rows.append({"label": f"{side * side}x{size}^2 {encoding}", "positional": side * side, "map": size,
                         "encoding": encoding, "build_s": build, "ao_s": query, "seconds": build + query,
                         "error": rms(ao), "mb_per_prototype": vase.nbytes / 1e6,
                         "default": (side * side, size, encoding) == (4225, 32, "uint8")})
    default = next((r for r in rows if r["default"]), rows[-1])  # quick: the largest setting swept

    # interpolation modes at the default resolution (quadrilinear etc. are options of instance_ao)
    interpolation = {}
    if not quick:
        fields = DisplacementFields().run(core.Context(scene=scene, params=DisplacementFields.Params(),
                                                       tracer=None)).products[DisplacementFieldSet].fields
        for mode in ("nearest", "position", "direction", "quadrilinear"):
            ao_ctx = core.Context(scene=scene, params=InstanceAO.Params(interpolation=mode), tracer=None,
                                  products={DisplacementFieldSet: DisplacementFieldSet(fields)})
            ao = InstanceAO().run(ao_ctx).products[InstanceOcclusionProduct].point_ao_by_frame[None]
            interpolation[mode] = rms(ao)

    instance_figures = {} if quick else _instance_vertices(scene)
    scaling = _scaling(quick, compute_field_distances, encode_field, DisplacementField, side_for)
    field_times = [s["field_us_per_ray"] for s in scaling]
    bvh_times = [s["bvh_us_per_ray"] for s in scaling]
    crossover = [s for s in scaling if s["bvh_us_per_ray"] > s["field_us_per_ray"]]
    figures = {
        "setting": default["label"],
        "rms_vs_ambient_occlusion": round(default["error"], 5),
        "rms_target": 0.02,
        "rms_4225x32_bit1": next((round(r["error"], 5) for r in rows
                                  if (r["positional"], r["map"], r["encoding"]) == (4225, 32, "bit1")), None),
        "field_query_us_per_ray_max_over_min": round(max(field_times) / min(field_times), 3),
        "bvh_us_per_ray_max_over_min": round(max(bvh_times) / min(bvh_times), 3),
        "prototype_triangles": [s["triangles"] for s in scaling],
        "field_faster_per_ray_from_triangles": crossover[0]["triangles"] if crossover else None,
        "breakeven_rays_at_largest_prototype": scaling[-1]["breakeven_rays"],
        "mb_per_prototype_4225x32_uint8": round(4225 * 32 * 32 / 1e6, 3),
        "mb_per_prototype_4225x32_bit1": round((4225 * 32 * 32 / 8 + 4225) / 1e6, 3),
        "reference_ao_seconds_per_frame_with_bvh_build": round(reference_seconds, 3),
        "scene_bvh_build_seconds": round(bvh_build, 3),
        "instance_ao_seconds_per_frame": round(default["ao_s"], 3),
        "field_build_seconds_both_prototypes": round(default["build_s"], 3),
        # moving instances: the BVH path rebuilds the scene BVH every frame, fields are built once
        "frames_to_break_even_on_instanced_props": (round(default["build_s"] / (reference_seconds - default["ao_s"]),
                                                          2) if reference_seconds > default["ao_s"] else None),
    }
    figures.update(instance_figures)
    if interpolation:
        figures["rms_by_interpolation"] = {k: round(v, 5) for k, v in interpolation.items()}
    table = ("Resolution sweep on `instanced_props.usda` (build = both prototypes' fields, AO = one frame, "
             "nearest lookups):\n\n"
             + harness.markdown_table(rows, ["positional", "map", "encoding", "build_s", "ao_s", "error",
                                             "mb_per_prototype"])
             + f"\n\nPer-ray cost against prototype size (bumpy sphere, {scaling[0]['setting']} uint8 field, "
               f"{scaling[0]['rays']} rays aimed at the prototype, 2 threads; agreement = field hit/miss "
               "equal to the BVH's):\n\n"
             + harness.markdown_table(scaling, ["triangles", "field_build_s", "bvh_build_s", "field_us_per_ray",
                                                "bvh_us_per_ray", "breakeven_rays", "agreement"]))
    if interpolation:
        table += "\n\nRMS by interpolation mode at 4225 x 32x32 uint8: " + ", ".join(
            f"{k} {v:.4f}" for k, v in interpolation.items())
    return harness.result(NAME, description=DESCRIPTION, settings={"sweep": sweep, "ao_samples": 256},
                          points=[{k: v for k, v in r.items()} for r in rows], figures=figures, table=table,
                          knob="positional samples x direction map x encoding",
                          error_label="AO RMS vs ambient_occlusion (same rays)")


def _scaling(quick, compute_field_distances, encode_field, DisplacementField, side_for) -> list[dict]:
    """Field lookup vs BVH any-hit time per ray as the prototype grows."""
    from usdbake.kernels.sh import uniform_sphere_np
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.instancing.instance_ao import query_field

    sizes = [36, 112] if quick else [36, 112, 355]
    ray_count = 200_000 if quick else 1_000_000
    positional, size = (1089, 16) if quick else (4225, 32)
    rng = np.random.default_rng(21)  # fixed seed: the same rays for every prototype size
    origins = 3.0 * uniform_sphere_np(rng.random(ray_count), rng.random(ray_count))  # on a sphere of radius 3
    targets = rng.normal(size=(ray_count, 3)) * 0.6
    directions = targets - origins
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    rows = []
    for n in sizes:
        points, triangles = bumpy_sphere(n)
        started = time.perf_counter()
        values, center, radius = compute_field_distances(points, triangles, side=side_for(positional), map_size=size)
        texels, means = encode_field(values, "uint8")
        field_build = time.perf_counter() - started
        field = DisplacementField("/bumpy", center, radius, side_for(positional), size, "uint8", texels, means,
                                  len(triangles))
        started = time.perf_counter()
        tracer = Tracer(points.astype(np.float32), triangles)
        bvh_build = time.perf_counter() - started
        field_seconds, bvh_seconds = [], []
        for _ in range(2):  # best of two: the machine is shared
            started = time.perf_counter()
            visible = query_field(field, np.eye(4), origins, directions, tracer=tracer)
            field_seconds.append(time.perf_counter() - started)
            started = time.perf_counter()
            blocked = tracer.occluded(origins, directions)
            bvh_seconds.append(time.perf_counter() - started)
        field_us = min(field_seconds) / ray_count * 1e6
        bvh_us = min(bvh_seconds) / ray_count * 1e6
        saved = (bvh_us - field_us) * 1e-6
        rows.append({"triangles": len(triangles), "rays": ray_count, "setting": f"{positional} x {size}x{size}",
                     "field_build_s": field_build,
                     "bvh_build_s": bvh_build, "field_us_per_ray": field_us, "bvh_us_per_ray": bvh_us,
                     "breakeven_rays": f"{field_build / saved:.3g}" if saved > 0 else "never",
                     "agreement": float(np.mean((visible < 0.5) == blocked))})
    return rows


def _instance_vertices(scene) -> dict:
    """instance_ao with instances=True: per-instance mean AO against the exact AO at the instances' vertices."""
    import dataclasses

    from usdbake import core
    from usdbake.geometry.mesh import vertex_normals
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.occlusion.ambient_occlusion import AmbientOcclusion
    from usdbake.processors.instancing.displacement_fields import DisplacementFields
    from usdbake.processors.instancing.instance_ao import InstanceAO
    from usdbake.processors.instancing.instance_points import InstancePoints

    fields = DisplacementFields().run(core.Context(scene=scene, params=DisplacementFields.Params(),
                                                   tracer=None)).products[DisplacementFieldSet].fields
    started = time.perf_counter()
    result = InstanceAO().run(core.Context(scene=scene, params=InstanceAO.Params(instances=True), tracer=None,
                                           products={DisplacementFieldSet: DisplacementFieldSet(fields)}))
    field_seconds = time.perf_counter() - started
    means = result.products[InstanceOcclusionProduct].instance_ao_by_frame[None]
    writable = dataclasses.replace(scene, prim_writable=np.ones(len(scene.prim_paths), bool))
    started = time.perf_counter()
    exact = AmbientOcclusion().run(core.Context(scene=writable, params=AmbientOcclusion.Params(),
                                                tracer=Tracer.from_scene(scene)))
    exact_ao = exact.products[AmbientOcclusionProduct].point_ao
    exact_seconds = time.perf_counter() - started
    normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
    instance_points = InstancePoints(scene, normals, np.zeros_like(normals), np.zeros(len(scene.instances), np.int32))
    exact_means = instance_points.means(exact_ao[instance_points.point_ids])
    return {"instances_rms_of_per_instance_mean_ao": round(float(np.sqrt(np.mean((means - exact_means) ** 2))), 5),
            "instances_max_abs_per_instance_mean_ao": round(float(np.abs(means - exact_means).max()), 5),
            "instances_seconds_field_vs_exact": [round(field_seconds, 3), round(exact_seconds, 3)]}
