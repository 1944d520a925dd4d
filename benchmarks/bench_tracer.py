"""The ray core against Embree: closest and any hit per thread and on all cores, inside processors,
instancing, build time, agreement, and a model of thread scaling (issue: the ray core at Embree speed)."""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import warp as wp

from . import harness
from .bench_progressive_mesh import height_field, sphere
from usdbake.kernels.occlusion import AORays, ao_direction, ao_point, ao_rays
from usdbake.kernels.tracer import (MIN_CHUNK, RAY_EPSILON_RELATIVE, Tracer, default_threads, launch_chunked,
                                    surface_origin)
from usdbake.kernels.traversal import TraceScene, trace_any, trace_closest

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

NAME = "tracer"
DESCRIPTION = (
    "Rays per second of the ray core (`kernels.traversal`: 8-wide BVH, packets of 4 triangles, watertight "
    "test) on incoherent cosine-distributed AO rays from random vertices (one ray per vertex, infinite "
    "length), closest hit and any hit, in a kernel that reads the rays and writes the hits (the bare core): "
    "one thread, and all cores through `launch_chunked`; the same rays through Embree 4 (embreex, "
    "single-threaded rtcIntersect1/rtcOccluded1 calls) in the same run. Scenes: atrium (51k triangles), "
    "city_block (9.6k), a 79k-triangle height field and atrium tiled 20 times (1.02M). Inside processors: "
    "rays per second of `compute_vertex_ao` on atrium (256 rays per vertex, the processor's default; also 64) and of the first visibility pass "
    "of `compute_sky_visibility` on building (256 patches, 4 rays each), against the bare core figure on "
    "that scene (any hit, incoherent AO rays, all cores) and, more demanding, against the bare core tracing "
    "the very same rays, captured beforehand by kernels that make them as the processors do (their rays are "
    "more coherent than the figure's, so they trace faster). "
    "Instancing: 1000 instances of a 2.5k-triangle prototype traced two-level vs flattened, and a USD "
    "PointInstancer of 10,000 instances through extraction. Agreement: hit/miss equal to Embree's closest "
    "hit, rays whose hit by either lies within 2e-5 of the scene diagonal of the origin (self-hits: our "
    "origins sit 1e-5 of the diagonal off their surface) excluded. Scaling model: each of 256 slices of the rays timed alone on one thread, then "
    "`launch_chunked`'s partition on N threads scheduled greedily (the predicted time is the longest thread).")

SCALING_SLICES = 256
SELF_HIT_DISTANCE = 2.0 * RAY_EPSILON_RELATIVE
"""Hits nearer the origin than this fraction of the scene diagonal are self-hits (the origin is pushed
RAY_EPSILON_RELATIVE off its surface): left out of the agreement with Embree, which has no such offset."""
MODEL_THREADS = (1, 2, 4, 8, 16, 32, 64)


@wp.kernel
def ao_ray_kernel(start: int, rays: AORays, positions: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                  origins: wp.array(dtype=wp.vec3), directions: wp.array(dtype=wp.vec3)):
    """Ray i as ``ambient_occlusion`` casts it from point i with unit normal n: from p + n epsilon along
    ``ao_direction`` (cosine-weighted; one ray per point, so each one is a fresh direction)."""
    i = start + wp.tid()
    n = normals[i]
    origins[i] = positions[i] + n * rays.epsilon
    directions[i] = ao_direction(rays, ao_point(rays, n, i), 0)


@wp.kernel
def any_kernel(start: int, scene: TraceScene, origins: wp.array(dtype=wp.vec3),
               directions: wp.array(dtype=wp.vec3), occluded: wp.array(dtype=wp.int8)):
    """The bare core, any hit: ray i from the arrays, result to the array."""
    i = start + wp.tid()
    occluded[i] = wp.int8(wp.where(trace_any(scene, origins[i], directions[i], 3.0e38), 1, 0))


@wp.kernel
def closest_kernel(start: int, scene: TraceScene, origins: wp.array(dtype=wp.vec3),
                   directions: wp.array(dtype=wp.vec3), hit_t: wp.array(dtype=float)):
    """The bare core, closest hit: distance of ray i's hit (-1 for a miss)."""
    i = start + wp.tid()
    hit = trace_closest(scene, origins[i], directions[i], 3.0e38)
    hit_t[i] = wp.where(hit.result, hit.t, -1.0)


def mesh_scene(points: np.ndarray, tris: np.ndarray) -> SimpleNamespace:
    """The arrays of a Scene that ``ao_ray_arrays`` reads, for geometry that is not a sample stage."""
    points = np.asarray(points, np.float32)
    tris = np.asarray(tris, np.int32)
    cross = np.cross(points[tris[:, 1]] - points[tris[:, 0]], points[tris[:, 2]] - points[tris[:, 0]])
    length = np.linalg.norm(cross, axis=1)
    normals = np.where(length[:, None] > 0, cross / np.maximum(length, 1e-30)[:, None], 0.0).astype(np.float32)
    return SimpleNamespace(points=points, tri_vertices=tris, tri_normals=normals,
                           tri_areas=(length / 2).astype(np.float32), num_triangles=len(tris))


def ao_ray_arrays(tracer, scene, count: int, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """(count, 3) float32 origins and unit directions of AO rays from random vertices of ``scene``."""
    from usdbake.geometry.mesh import vertex_normals

    rng = np.random.default_rng(seed)  # fixed seed: the same rays for every backend and thread count
    normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
    usable = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0.5)
    picks = usable[rng.integers(0, len(usable), count)]
    origins = wp.empty(count, dtype=wp.vec3, device=tracer.device)
    directions = wp.empty(count, dtype=wp.vec3, device=tracer.device)
    rays = ao_rays(tracer.scene, samples=1, max_distance=np.inf, epsilon=tracer.epsilon, seed=seed,
                   device=tracer.device)
    tracer.launch(ao_ray_kernel, count, [rays, tracer.array(scene.points[picks], wp.vec3),
                                         tracer.array(normals[picks], wp.vec3), origins, directions])
    return origins.numpy(), directions.numpy()


def tiled(scene, copies: int) -> tuple[np.ndarray, np.ndarray]:
    """``copies`` side-by-side copies of a scene's triangles (5 per row)."""
    extent = scene.points.max(axis=0) - scene.points.min(axis=0)
    points = [scene.points + np.array([(k % 5) * extent[0] * 1.1, 0.0, (k // 5) * extent[2] * 1.1], np.float32)
              for k in range(copies)]
    return np.concatenate(points), np.concatenate([scene.tri_vertices + len(scene.points) * k for k in range(copies)])


# ---------------------------------------------------------------------------
# Measurements


class CoreRun:
    """The bare core's kernels on one tracer and one set of rays."""

    def __init__(self, tracer: Tracer, origins: np.ndarray, directions: np.ndarray):
        self.tracer, self.count = tracer, len(origins)
        self.origins = tracer.array(origins, wp.vec3)
        self.directions = tracer.array(directions, wp.vec3)
        self.occluded = wp.zeros(self.count, dtype=wp.int8, device=tracer.device)
        self.hit_t = wp.zeros(self.count, dtype=float, device=tracer.device)
        self.run("any", 1, 0, min(self.count, 1000))  # compile/load outside the timings
        self.run("closest", 1, 0, min(self.count, 1000))

    def run(self, query: str, threads: int, lo: int = 0, hi: int | None = None) -> None:
        hi = self.count if hi is None else hi
        kernel, out = (any_kernel, self.occluded) if query == "any" else (closest_kernel, self.hit_t)
        launch_chunked(kernel, hi - lo, [self.tracer.scene, self.origins, self.directions, out],
                       device=self.tracer.device, threads=threads, offset=lo)

    def seconds(self, query: str, threads: int, repeats: int) -> float:
        return min(harness.timings(lambda: self.run(query, threads), repeats))


def embree_scene(points: np.ndarray, tris: np.ndarray):
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError:
        return None
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, np.ascontiguousarray(points[tris], np.float32))
    return scene


def compare_scene(label: str, points, tris, scene_like, rays: int, repeats: int, threads: int) -> dict:
    """Bare core vs Embree on one scene: Mrays/s and ratios, agreement, build seconds."""
    started = time.perf_counter()
    tracer = Tracer(points, tris, threads=threads)
    build = time.perf_counter() - started
    origins, directions = ao_ray_arrays(tracer, scene_like, rays)
    core = CoreRun(tracer, origins, directions)
    row = {"scene": label, "triangles": len(tris), "build_s": round(build, 3)}
    for query in ("closest", "any"):
        one = core.seconds(query, 1, repeats)
        every = core.seconds(query, threads, repeats)
        row[f"{query}_mrays_1"] = round(rays / one / 1e6, 3)
        row[f"{query}_mrays_all"] = round(rays / every / 1e6, 3)
    embree = embree_scene(points, tris)
    if embree is not None:
        embree.run(origins[:1000], directions[:1000], query="OCCLUDED")
        for query, name in (("closest", "DISTANCE"), ("any", "OCCLUDED")):
            seconds = min(harness.timings(lambda: embree.run(origins, directions, query=name), repeats))
            row[f"{query}_embree_mrays"] = round(rays / seconds / 1e6, 3)
            row[f"{query}_per_thread_vs_embree"] = round(row[f"{query}_mrays_1"] / row[f"{query}_embree_mrays"], 3)
            row[f"{query}_all_cores_vs_embree"] = round(row[f"{query}_mrays_all"] / row[f"{query}_embree_mrays"], 3)
        core.run("closest", threads)
        ours = core.hit_t.numpy()
        theirs = embree.run(origins, directions, query="DISTANCE")
        ours_hit, theirs_hit = ours >= 0, theirs < 1e30
        diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
        near = SELF_HIT_DISTANCE * diagonal
        self_hit = (ours_hit & (ours < near)) | (theirs_hit & (theirs < near))
        row["agreement_vs_embree"] = round(float((ours_hit == theirs_hit)[~self_hit].mean()), 6)
        row["self_hits_excluded"] = int(self_hit.sum())
    row["_core"] = core
    return row


@wp.kernel
def ao_capture_kernel(start: int, rays: AORays, positions: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                      inward: wp.array(dtype=wp.vec3), origins: wp.array(dtype=wp.vec3),
                      directions: wp.array(dtype=wp.vec3)):
    """The rays ``vertex_ao_kernel`` casts from vertex i (same origin rule, seeds and directions), stored."""
    i = start + wp.tid()
    n = normals[i]
    origin = surface_origin(rays.scene, positions[i], n, inward[i], rays.epsilon)
    point = ao_point(rays, n, i)
    count = rays.strata * rays.strata
    for k in range(count):
        origins[i * count + k] = origin
        directions[i * count + k] = ao_direction(rays, point, k)


@wp.kernel
def sky_capture_kernel(start: int, normals: wp.array(dtype=wp.vec3), tri_ids: wp.array(dtype=int),
                       sample_origins: wp.array(dtype=wp.vec3), origin_sets: int, samples: wp.array(dtype=wp.vec3),
                       sample_sets: int, patch_centers: wp.array(dtype=wp.vec3),
                       patch_horizon: wp.array(dtype=float), num_patches: int, count: int,
                       origins: wp.array(dtype=wp.vec3), directions: wp.array(dtype=wp.vec3),
                       traced: wp.array(dtype=wp.int8)):
    """The rays ``patch_visibility_kernel`` casts for triangle i, in its order (patch by patch, sample by
    sample), stored; traced[r] = 1 for the ones it really traces (patch not below the horizon, sample facing
    the triangle's side)."""
    i = start + wp.tid()
    n = normals[i]
    sample_set = int(wp.rand_init(tri_ids[i]) % wp.uint32(sample_sets))
    for j in range(num_patches):
        first = (sample_set * num_patches + j) * count
        for s in range(count):
            r = (i * num_patches + j) * count + s
            d = samples[first + s]
            traced[r] = wp.int8(0)
            if wp.length(n) >= 0.5 and wp.dot(n, patch_centers[j]) >= patch_horizon[j] and wp.dot(n, d) > 0.0:
                origins[r] = sample_origins[(i * origin_sets + j % origin_sets) * count + s]
                directions[r] = d
                traced[r] = wp.int8(1)


def in_processor_rates(threads: int, quick: bool) -> dict:
    """Rays/s inside compute_vertex_ao (atrium, at the processor's default rays a vertex and at 64) and inside
    the first visibility pass of compute_sky_visibility (building), each against the bare core tracing the
    very rays the processor casts, stored beforehand."""
    from usdbake.geometry.mesh import vertex_inward, vertex_normals
    from usdbake.kernels.sky import enu_to_world, uniform_patches
    from usdbake.processors.occlusion.ambient_occlusion import AmbientOcclusion, compute_vertex_ao
    from usdbake.processors.daylight.sky_visibility import compute_sky_visibility

    figures = {}
    default_rays = AmbientOcclusion.Params().samples
    cases = [("ao_atrium", "atrium", 16 if quick else default_rays)]
    if not quick:
        cases.append(("ao_atrium_64", "atrium", 64))  # the figure of the issue that asked for it, at 64 rays
    cases.append(("sky_visibility_building", "building", 0))
    for label, sample, samples in cases:
        scene = harness.load_scene(sample)
        tracer = Tracer.from_scene(scene, threads=threads)
        launched = {"seconds": 0.0}
        original = tracer.launch

        def timed_launch(kernel, dim, inputs, **kwargs):
            started = time.perf_counter()
            original(kernel, dim, inputs, **kwargs)
            launched["seconds"] += time.perf_counter() - started

        if sample == "atrium":
            normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
            inward = vertex_inward(scene.points, scene.tri_vertices, normals)
            receivers = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0.5)
            positions, normals, inward = scene.points[receivers], normals[receivers], inward[receivers]
            rays = ao_rays(tracer.scene, samples=samples, max_distance=np.inf, epsilon=tracer.epsilon, seed=0,
                          device=tracer.device)
            count = len(positions) * rays.strata ** 2
            origins = wp.empty(count, dtype=wp.vec3, device=tracer.device)
            directions = wp.empty(count, dtype=wp.vec3, device=tracer.device)
            tracer.launch(ao_capture_kernel, len(positions), [rays, tracer.array(positions, wp.vec3),
                                                              tracer.array(normals, wp.vec3),
                                                              tracer.array(inward, wp.vec3), origins, directions])
            origins, directions = origins.numpy(), directions.numpy()
            compute_vertex_ao(tracer, positions, normals, samples=samples, inward=inward)  # compile

            def bake():
                compute_vertex_ao(tracer, positions, normals, samples=samples, inward=inward)
        else:
            patches = uniform_patches(64 if quick else 256)
            origins, directions = _sky_rays(tracer, scene, patches, enu_to_world(scene.up_axis))
            compute_sky_visibility(tracer, scene, patches=uniform_patches(4), adaptive=False)  # compile

            def bake():
                compute_sky_visibility(tracer, scene, patches=patches, adaptive=False)
        repeats = 1 if quick else 7  # the building's pass is ~20 ms: enough repeats to find its floor
        tracer.launch = timed_launch
        launch_seconds = []
        for _ in range(repeats):
            launched["seconds"] = 0.0
            bake()
            launch_seconds.append(launched["seconds"])
        tracer.launch = original
        bare = CoreRun(tracer, origins, directions)
        bare_seconds = bare.seconds("any", threads, repeats)
        rate = len(origins) / min(launch_seconds)
        figures[f"{label}_mrays"] = round(rate / 1e6, 3)
        figures[f"{label}_same_rays_bare_mrays"] = round(len(origins) / bare_seconds / 1e6, 3)
        figures[f"{label}_vs_bare_same_rays"] = round(bare_seconds / min(launch_seconds), 3)
        incoherent = CoreRun(tracer, *ao_ray_arrays(tracer, scene, 200_000 if quick else 1_000_000))
        figure = incoherent.count / incoherent.seconds("any", threads, repeats)
        figures[f"{label}_bare_figure_mrays"] = round(figure / 1e6, 3)
        figures[f"{label}_vs_bare_figure"] = round(rate / figure, 3)
    return figures


def _sky_rays(tracer, scene, patches, to_world) -> tuple[np.ndarray, np.ndarray]:
    """The rays the first (unrefined) pass of compute_sky_visibility traces, as origins and directions."""
    from usdbake.geometry.mesh import receiver_prims
    from usdbake.kernels.sampling import strata_for
    from usdbake.kernels.sky import patch_jittered_samples
    from usdbake.processors.daylight.patch_visibility import ORIGIN_SETS, sample_origins_kernel, sample_set_count

    tris = np.flatnonzero(np.isin(scene.tri_prim, receiver_prims(scene)))
    corners = scene.points[scene.tri_vertices[tris]].astype(np.float32)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]).astype(np.float64)
    length = np.linalg.norm(cross, axis=1)
    normals = np.where(length[:, None] > 0, cross / np.maximum(length, 1e-300)[:, None], 0.0).astype(np.float32)
    strata = strata_for(4)
    count = strata * strata
    normals_wp = tracer.array(normals, wp.vec3)
    ids = tracer.array(np.arange(len(tris), dtype=np.int32), int)
    origin_sets = min(ORIGIN_SETS, len(patches))
    sample_origins = wp.empty(len(tris) * origin_sets * count, dtype=wp.vec3, device=tracer.device)
    tracer.launch(sample_origins_kernel, len(tris), [
        tracer.scene, tracer.array(corners.reshape(-1, 3), wp.vec3), normals_wp, ids, strata, origin_sets,
        tracer.epsilon, 0, sample_origins])
    sets = sample_set_count(len(patches), count)
    samples = (patch_jittered_samples(patches, strata, 0, sets) @ to_world.T).reshape(-1, 3).astype(np.float32)
    centers = (patches.patch_directions @ to_world.T).astype(np.float32)
    horizon = (-np.sin(np.minimum(patches.patch_radius, np.pi / 2))).astype(np.float32)
    rays = len(tris) * len(patches) * count
    origins = wp.empty(rays, dtype=wp.vec3, device=tracer.device)
    directions = wp.empty(rays, dtype=wp.vec3, device=tracer.device)
    traced = wp.empty(rays, dtype=wp.int8, device=tracer.device)
    tracer.launch(sky_capture_kernel, len(tris), [
        normals_wp, ids, sample_origins, origin_sets, tracer.array(samples, wp.vec3), sets,
        tracer.array(centers, wp.vec3),
        tracer.array(horizon, float), len(patches), count, origins, directions, traced])
    keep = traced.numpy().astype(bool)
    return origins.numpy()[keep], directions.numpy()[keep]


def instancing(threads: int, quick: bool) -> dict:
    """1000 instances of a 2.5k-triangle prototype: two-level vs flattened memory and throughput."""
    from usdbake.kernels.bvh_build import build_triangle_bvh, two_level

    proto_points, proto_tris = sphere(36, 36)
    proto_points = proto_points * (1.0 + 0.15 * np.sin(5 * proto_points[:, :1]) * np.cos(4 * proto_points[:, 1:2]))
    count = 1000
    rng = np.random.default_rng(3)  # fixed seed: the same instances every run
    to_world = np.zeros((count, 3, 4))
    for k in range(count):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        to_world[k, :, :3] = q * rng.uniform(0.5, 1.5)
        to_world[k, :, 3] = [(k % 32) * 3.0, rng.uniform(0, 2), (k // 32) * 3.0]
    flat_points = np.concatenate([proto_points @ m[:, :3].T + m[:, 3] for m in to_world]).astype(np.float32)
    flat_tris = np.concatenate([proto_tris + len(proto_points) * k for k in range(count)]).astype(np.int32)
    corners = np.array([flat_points.min(axis=0), flat_points.max(axis=0)])
    started = time.perf_counter()
    bottom = build_triangle_bvh(proto_points.astype(np.float32), proto_tris)
    arrays = two_level([bottom], np.zeros(count, np.int64), to_world,
                       np.arange(count) * len(proto_tris), np.zeros(count, np.int32))
    instanced = Tracer(corners, np.zeros((0, 3), np.int32), threads=threads, arrays=arrays)
    instanced_build = time.perf_counter() - started
    flat = Tracer(flat_points, flat_tris, threads=threads)
    prototype = Tracer(proto_points, proto_tris, threads=threads)
    rays = 100_000 if quick else 1_000_000
    origins = rng.uniform(corners[0], corners[1], (rays, 3)).astype(np.float32)
    directions = rng.normal(size=(rays, 3)).astype(np.float32)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    repeats = 1 if quick else 3
    figures = {"instanced_triangles": len(flat_tris), "prototype_triangles": len(proto_tris),
               "instanced_build_s": round(instanced_build, 3),
               "instanced_memory_vs_prototype": round(instanced.nbytes / prototype.nbytes, 3),
               "flattened_memory_vs_prototype": round(flat.nbytes / prototype.nbytes, 3)}
    runs = {"instanced": CoreRun(instanced, origins, directions), "flattened": CoreRun(flat, origins, directions)}
    for query in ("closest", "any"):
        seconds = {k: run.seconds(query, threads, repeats) for k, run in runs.items()}
        figures[f"instanced_{query}_slowdown_vs_flattened"] = round(seconds["instanced"] / seconds["flattened"], 3)
    runs["instanced"].run("closest", threads)
    runs["flattened"].run("closest", threads)
    a, b = runs["instanced"].hit_t.numpy(), runs["flattened"].hit_t.numpy()
    figures["instanced_vs_flattened_hit_agreement"] = round(float(((a >= 0) == (b >= 0)).mean()), 6)
    figures.update(point_instancer(2000 if quick else 10_000, threads))
    return figures


def point_instancer(count: int, threads: int) -> dict:
    """A USD PointInstancer of ``count`` instances of a 1,216-triangle sphere, extracted and traced two-level."""
    from pxr import Usd, UsdGeom, Vt

    from usdbake.stages.extract import extract_scene

    stage = Usd.Stage.CreateInMemory()
    points, tris = sphere(20, 32)
    ground = UsdGeom.Mesh.Define(stage, "/World/Ground")
    ground.CreatePointsAttr([(-500, -1, -500), (500, -1, -500), (500, -1, 500), (-500, -1, 500)])
    ground.CreateFaceVertexCountsAttr([4])
    ground.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Instancer")
    proto = UsdGeom.Mesh.Define(stage, "/World/Instancer/Prototypes/Ball")
    proto.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
    proto.CreateFaceVertexCountsAttr([3] * len(tris))
    proto.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(tris.astype(np.int32).ravel()))
    instancer.CreatePrototypesRel().SetTargets([proto.GetPath()])
    side = int(np.ceil(np.sqrt(count)))
    rng = np.random.default_rng(5)  # fixed seed
    positions = np.c_[(np.arange(count) % side) * 3.0 - side * 1.5, rng.uniform(0, 1, count),
                      (np.arange(count) // side) * 3.0 - side * 1.5]
    instancer.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(positions.astype(np.float32)))
    instancer.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(np.zeros(count, np.int32)))
    started = time.perf_counter()
    scene = extract_scene(stage)
    extract = time.perf_counter() - started
    started = time.perf_counter()
    tracer = Tracer.from_scene(scene, threads=threads)
    build = time.perf_counter() - started
    return {"point_instancer_instances": count, "point_instancer_triangles": scene.num_triangles,
            "point_instancer_two_level": bool(tracer.arrays.top_root >= 0),
            "point_instancer_extract_s": round(extract, 3), "point_instancer_build_s": round(build, 3),
            "point_instancer_tracer_mb": round(tracer.nbytes / 2 ** 20, 3),
            "point_instancer_scene_triangle_mb": round((scene.points.nbytes + scene.tri_vertices.nbytes) / 2 ** 20, 3)}


def scaling_model(core: CoreRun, threads: int, repeats: int) -> dict:
    """Predicted speed-up on N threads from per-slice timings (see DESCRIPTION), and the measured one."""
    edges = np.linspace(0, core.count, SCALING_SLICES + 1).astype(np.int64)
    slice_seconds = np.array([min(harness.timings(lambda: core.run("any", 1, int(lo), int(hi)), repeats))
                              for lo, hi in zip(edges[:-1], edges[1:])])
    slice_rays = np.diff(edges)

    def predicted(n: int) -> float:
        chunks = 1 if n <= 1 or core.count < 2 * MIN_CHUNK else min(n * 4, max(1, core.count // MIN_CHUNK))
        bounds = np.linspace(0, core.count, chunks + 1)
        # seconds of each chunk: the slices it covers, in proportion to their overlap
        chunk_seconds = []
        for lo, hi in zip(bounds[:-1], bounds[1:]):
            overlap = np.clip(np.minimum(edges[1:], hi) - np.maximum(edges[:-1], lo), 0, None)
            chunk_seconds.append(float((slice_seconds * overlap / slice_rays).sum()))
        workers = np.zeros(max(n, 1))
        for seconds in chunk_seconds:  # the pool hands the next chunk to the first free thread
            workers[np.argmin(workers)] += seconds
        return workers.max()

    one = predicted(1)
    figures = {f"model_speedup_{n}": round(one / predicted(n), 3) for n in MODEL_THREADS}
    figures["slice_seconds_cv"] = round(float(slice_seconds.std() / slice_seconds.mean()), 3)
    measured_one = core.seconds("any", 1, repeats)
    figures[f"measured_speedup_{threads}"] = round(measured_one / core.seconds("any", threads, repeats), 3)
    return figures


def run(quick: bool = False) -> dict:
    threads = default_threads()
    rays = 200_000 if quick else 1_000_000
    repeats = 1 if quick else 3
    atrium = harness.load_scene("atrium")
    cases = [("atrium", atrium.points, atrium.tri_vertices, atrium)]
    city = harness.load_scene("city_block")
    cases.append(("city_block", city.points, city.tri_vertices, city))
    points, tris = height_field(200)  # bench_progressive_mesh's bumpy grid: 79,202 triangles
    cases.append(("height_field_79k", points, tris, mesh_scene(points, tris)))
    if not quick:
        points, tris = tiled(atrium, 20)
        cases.append(("atrium_x20_1M", points, tris, mesh_scene(points, tris)))
    rows = [compare_scene(label, np.asarray(p, np.float32), np.asarray(t, np.int32), like, rays, repeats, threads)
            for label, p, t, like in cases]
    figures = {"threads": threads}
    for query in ("closest", "any"):
        for kind in ("per_thread_vs_embree", "all_cores_vs_embree"):
            values = [r[f"{query}_{kind}"] for r in rows if f"{query}_{kind}" in r]
            if values:
                figures[f"{query}_{kind}_min"] = min(values)
    agreements = [r["agreement_vs_embree"] for r in rows if "agreement_vs_embree" in r]
    if agreements:
        figures["agreement_vs_embree_min"] = min(agreements)
    largest = max(rows, key=lambda r: r["triangles"])
    figures["build_s_per_million_triangles"] = round(largest["build_s"] / largest["triangles"] * 1e6, 3)
    atrium_row = rows[0]
    figures["all_cores_speedup"] = round(atrium_row["any_mrays_all"] / atrium_row["any_mrays_1"], 3)
    figures.update(scaling_model(atrium_row["_core"], threads, repeats))
    figures.update(in_processor_rates(threads, quick))
    figures.update(instancing(threads, quick))
    if wp.is_cuda_available():
        figures.update(cuda_rates(atrium, rays))
    for row in rows:
        row.pop("_core")
    columns = ["scene", "triangles", "build_s", "closest_mrays_1", "closest_embree_mrays", "closest_per_thread_vs_embree",
               "closest_all_cores_vs_embree", "any_mrays_1", "any_embree_mrays", "any_per_thread_vs_embree",
               "any_all_cores_vs_embree", "agreement_vs_embree"]
    table = harness.markdown_table(rows, [c for c in columns if c in rows[0]])
    points_out = [{"label": r["scene"], "seconds": rays / (r["any_mrays_all"] * 1e6), "error": 0.0,
                   "default": r["scene"] == "atrium", **{k: v for k, v in r.items() if k != "scene"}} for r in rows]
    return harness.result(NAME, description=DESCRIPTION, settings={"rays": rays, "threads": threads,
                                                                   "scenes": [r["scene"] for r in rows]},
                          points=points_out, figures=figures, table=table, knob="scene", error_label="(exact)")


def cuda_rates(scene, rays: int) -> dict:
    """Mrays/s of the same kernels on the first CUDA device (recorded only where one is present)."""
    tracer = Tracer.from_scene(scene, device="cuda:0")
    origins, directions = ao_ray_arrays(tracer, scene, rays)
    core = CoreRun(tracer, origins, directions)
    return {f"cuda_{query}_mrays": round(rays / core.seconds(query, 1, 3) / 1e6, 3) for query in ("closest", "any")}
