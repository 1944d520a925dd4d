"""Tracer throughput on atrium.usda: incoherent AO rays, 1 thread vs all cores (vs Embree if installed)."""

from __future__ import annotations

import os
import time

import numpy as np

from . import harness

NAME = "tracer"
DESCRIPTION = ("Ray throughput of the shared Warp BVH (`Tracer.occluded`, any-hit) on `atrium.usda` with "
               "incoherent cosine-distributed AO rays from random vertices: one thread against all cores, "
               "and the same rays through Embree (embreex, single-threaded calls) when it is installed.")


def ao_rays(scene, count: int, epsilon: float, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """``count`` rays from random vertices along cosine-weighted directions around their normals."""
    from usdbake.geometry.mesh import vertex_normals
    from usdbake.kernels.sampling import cosine_hemisphere_np

    rng = np.random.default_rng(seed)  # fixed seed: the same rays for every backend and thread count
    normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
    usable = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0.5)
    picks = usable[rng.integers(0, len(usable), count)]
    n = normals[picks].astype(np.float64)
    helper = np.where(np.abs(n[:, :1]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    t = np.cross(n, helper)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    s = np.cross(n, t)
    local = cosine_hemisphere_np(rng.random(count), rng.random(count))
    directions = local[:, :1] * t + local[:, 1:2] * s + local[:, 2:] * n
    origins = scene.points[picks] + n * epsilon
    return origins.astype(np.float32), directions.astype(np.float32)


def best_of(repeats: int, fn) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        fn()
        times.append(time.perf_counter() - started)
    return min(times)


def run(quick: bool = False) -> dict:
    from pxr import Usd

    from usdbake.kernels.tracer import Tracer
    from usdbake.stages.extract import extract_scene

    scene = extract_scene(Usd.Stage.Open(str(harness.SAMPLES / "atrium.usda")))
    count = 500_000 if quick else 4_000_000
    cores = os.cpu_count() or 1
    tracer = Tracer.from_scene(scene)
    origins, directions = ao_rays(scene, count, tracer.epsilon)
    tracer.occluded(origins[:1000], directions[:1000])  # compile/load outside the timing
    repeats = 1 if quick else 3
    one = best_of(repeats, lambda: Tracer.occluded(_with_threads(tracer, 1), origins, directions))
    everyone = best_of(repeats, lambda: Tracer.occluded(_with_threads(tracer, cores), origins, directions))
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


def _with_threads(tracer, threads: int):
    tracer.threads = threads
    return tracer


def _embree_seconds(scene, origins, directions, repeats: int) -> float | None:
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError:
        return None
    embree_scene = rtcore_scene.EmbreeScene()
    TriangleMesh(embree_scene, scene.points[scene.tri_vertices].astype(np.float32))
    origins64, directions64 = origins.astype(np.float32), directions.astype(np.float32)
    embree_scene.run(origins64[:1000], directions64[:1000], query="OCCLUDED")
    return best_of(repeats, lambda: embree_scene.run(origins64, directions64, query="OCCLUDED"))
