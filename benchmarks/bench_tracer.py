"""Tracer throughput on atrium.usda: incoherent AO rays, 1 thread vs all cores (vs Embree if installed)."""

from __future__ import annotations

import os

import numpy as np
import warp as wp

from . import harness
from usdbake.kernels.occlusion import AORays, ao_direction, ao_rays
from usdbake.kernels.sampling import tangent_frame

wp.set_module_options({"enable_backward": False})

NAME = "tracer"
DESCRIPTION = ("Ray throughput of the shared Warp BVH (`Tracer.occluded`, any-hit) on `atrium.usda` with "
               "incoherent cosine-distributed AO rays from random vertices: one thread against all cores, "
               "and the same rays through Embree (embreex, single-threaded calls) when it is installed.")


@wp.kernel
def ao_ray_kernel(start: int, rays: AORays, positions: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                  origins: wp.array(dtype=wp.vec3), directions: wp.array(dtype=wp.vec3)):
    """Ray i as ``ambient_occlusion`` casts it from point i with unit normal n: from p + n epsilon along
    ``ao_direction`` (cosine-weighted; one ray per point, so each one is a fresh direction)."""
    i = start + wp.tid()
    n = normals[i]
    origins[i] = positions[i] + n * rays.epsilon
    directions[i] = ao_direction(rays, tangent_frame(n), 0, wp.rand_init(rays.seed, i))


def ao_ray_arrays(tracer, scene, count: int, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """(count, 3) float32 origins and unit directions of AO rays from random vertices of ``scene``."""
    from usdbake.geometry.mesh import vertex_normals

    rng = np.random.default_rng(seed)  # fixed seed: the same rays for every backend and thread count
    normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
    usable = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0.5)
    picks = usable[rng.integers(0, len(usable), count)]
    origins = wp.empty(count, dtype=wp.vec3, device=tracer.device)
    directions = wp.empty(count, dtype=wp.vec3, device=tracer.device)
    rays = ao_rays(tracer.scene, samples=1, max_distance=np.inf, epsilon=tracer.epsilon, seed=seed)
    tracer.launch(ao_ray_kernel, count, [rays, tracer.array(scene.points[picks], wp.vec3),
                                         tracer.array(normals[picks], wp.vec3), origins, directions])
    return origins.numpy(), directions.numpy()


def run(quick: bool = False) -> dict:
    from usdbake.kernels.tracer import Tracer

    scene = harness.load_scene("atrium")
    count = 500_000 if quick else 4_000_000
    cores = os.cpu_count() or 1
    tracer = Tracer.from_scene(scene)
    origins, directions = ao_ray_arrays(tracer, scene, count)
    tracer.occluded(origins[:1000], directions[:1000])  # compile/load outside the timing
    repeats = 1 if quick else 3

    def best_seconds(threads: int) -> float:
        tracer.threads = threads
        return min(harness.timings(lambda: tracer.occluded(origins, directions), repeats))

    one, everyone = best_seconds(1), best_seconds(cores)
    figures = {
        "triangles": scene.num_triangles, "rays": count,
        "mrays_per_s_1_thread": round(count / one / 1e6, 3),
        f"mrays_per_s_{cores}_threads": round(count / everyone / 1e6, 3),
        "all_cores_speedup": round(one / everyone, 3),
    }
    embree = _embree_seconds(scene, origins, directions, repeats)
    if embree is not None:
        figures["embree_mrays_per_s"] = round(count / embree / 1e6, 3)
        figures["warp_all_cores_over_embree"] = round(embree / everyone, 3)
    points = [{"label": "1 thread", "seconds": one, "error": 0.0, "default": False},
              {"label": f"{cores} threads", "seconds": everyone, "error": 0.0, "default": True}]
    return harness.result(NAME, description=DESCRIPTION, settings={"rays": count, "sample": "atrium.usda"},
                          points=points, figures=figures, knob="threads", error_label="(exact)")


def _embree_seconds(scene, origins, directions, repeats: int) -> float | None:
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError:
        return None
    embree_scene = rtcore_scene.EmbreeScene()
    TriangleMesh(embree_scene, scene.points[scene.tri_vertices].astype(np.float32))
    embree_scene.run(origins[:1000], directions[:1000], query="OCCLUDED")
    return min(harness.timings(lambda: embree_scene.run(origins, directions, query="OCCLUDED"), repeats))
