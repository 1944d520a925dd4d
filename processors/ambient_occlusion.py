"""Ambient occlusion by cosine-weighted hemisphere ray casts.

The reference every faster AO estimate in usdbake is checked against::

    AO(x) = 1/pi * integral_{H(n)} V(x, w) cos(theta) dw

estimated with stratified cosine-weighted directions (concentric map +
Malley), so AO is the mean visibility V of the sampled rays; V = 0 when a
ray hits geometry closer than ``max_distance``.

USD written (bake layer):

======================== ========= ============= ===================================
property                 type      interpolation when
======================== ========= ============= ===================================
primvars:bake:ao         float[]   vertex        always, one value per authored point
primvars:bake:aoFace     float[]   uniform       ``per_face``: one per authored face
inputs:occlusion         float     (connection)  ``connect_occlusion``, on each bound
                                                 UsdPreviewSurface, from a new
                                                 UsdPrimvarReader_float
======================== ========= ============= ===================================

Parameters
----------
==================== ====== ======= ==================================================
name                 type   default meaning
==================== ====== ======= ==================================================
samples              int    256     rays per point (rounded to a square for stratification)
max_distance         float  inf     hits farther than this (stage units) do not occlude
per_face             bool   False   also write per-face AO (area-weighted triangle samples)
connect_occlusion    bool   False   wire bake:ao into UsdPreviewSurface inputs:occlusion
seed                 int    0       random seed (results are identical across thread counts)
==================== ====== ======= ==================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core import Attribute, Context, Params, Prim, Primvar, Processor, Result, param
from ..core.products import AmbientOcclusionProduct
from ..kernels.sampling import cosine_hemisphere, strata_for, stratified_pair, tangent_frame, triangle_point
from ..geometry.mesh import face_means, receiver_prims, vertex_normals
from ..core.scene import Scene

wp.set_module_options({"enable_backward": False})


@wp.func
def occlusion_at(mesh: wp.uint64, origin: wp.vec3, frame: wp.mat33, strata: int, max_distance: float,
                 state: wp.uint32) -> float:
    """Mean visibility of strata^2 stratified cosine-weighted rays from origin."""
    visible = int(0)
    for k in range(strata * strata):
        u = stratified_pair(k, strata, state)
        direction = frame * cosine_hemisphere(u[0], u[1])
        if not wp.mesh_query_ray_anyhit(mesh, origin, direction, max_distance):
            visible += 1
    return float(visible) / float(strata * strata)


@wp.kernel
def vertex_ao_kernel(
    start: int,
    mesh: wp.uint64,
    positions: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    strata: int,
    max_distance: float,
    epsilon: float,
    seed: int,
    ao: wp.array(dtype=float),
):
    """AO at points (vertices) around their normals; a point without a normal gets 1."""
    i = start + wp.tid()
    n = normals[i]
    if wp.length(n) < 0.5:
        ao[i] = 1.0
        return
    state = wp.rand_init(seed, i)
    ao[i] = occlusion_at(mesh, positions[i] + n * epsilon, tangent_frame(n), strata, max_distance, state)


@wp.kernel
def face_ao_kernel(
    start: int,
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    triangles: wp.array(dtype=wp.vec3i),
    normals: wp.array(dtype=wp.vec3),
    strata: int,
    max_distance: float,
    epsilon: float,
    seed: int,
    ao: wp.array(dtype=float),
):
    """AO averaged over a triangle: each stratified direction from a uniform random point on it."""
    i = start + wp.tid()
    n = normals[i]
    if wp.length(n) < 0.5:
        ao[i] = 1.0
        return
    tri = triangles[i]
    a = points[tri[0]]
    b = points[tri[1]]
    c = points[tri[2]]
    frame = tangent_frame(n)
    state = wp.rand_init(seed, i)
    visible = int(0)
    for k in range(strata * strata):
        x = triangle_point(a, b, c, wp.randf(state), wp.randf(state))
        u = stratified_pair(k, strata, state)
        direction = frame * cosine_hemisphere(u[0], u[1])
        if not wp.mesh_query_ray_anyhit(mesh, x + n * epsilon, direction, max_distance):
            visible += 1
    ao[i] = float(visible) / float(strata * strata)


def compute_vertex_ao(tracer, positions: np.ndarray, normals: np.ndarray, *, samples: int,
                      max_distance: float = math.inf, seed: int = 0) -> np.ndarray:
    """AO at points with unit normals.

    Parameters
    ----------
    tracer : Tracer
    positions, normals : (N, 3) float32
    samples : rays per point (rounded to a square)

    Returns
    -------
    (N,) float32 in [0, 1]; 1 where the normal is zero.
    """
    positions = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    normals = np.ascontiguousarray(normals, np.float32).reshape(-1, 3)
    if positions.shape != normals.shape:
        raise ValueError(f"positions {positions.shape} and normals {normals.shape} differ")
    strata = strata_for(samples)
    ao = wp.zeros(len(positions), dtype=float, device=tracer.device)
    tracer.launch(vertex_ao_kernel, len(positions), [
        tracer.mesh.id, tracer.array(positions, wp.vec3), tracer.array(normals, wp.vec3),
        strata, float(min(max_distance, 3.0e38)), tracer.epsilon, seed, ao,
    ])
    tracer.rays_cast += len(positions) * strata * strata
    return ao.numpy()


def compute_face_ao(tracer, points: np.ndarray, tri_vertices: np.ndarray, tri_normals: np.ndarray, *,
                    samples: int, max_distance: float = math.inf, seed: int = 0) -> np.ndarray:
    """(T,) float32 AO averaged over each triangle's area and hemisphere."""
    strata = strata_for(samples)
    ao = wp.zeros(len(tri_vertices), dtype=float, device=tracer.device)
    tracer.launch(face_ao_kernel, len(tri_vertices), [
        tracer.mesh.id, tracer.array(points, wp.vec3), tracer.array(tri_vertices.astype(np.int32), wp.vec3i),
        tracer.array(tri_normals, wp.vec3), strata, float(min(max_distance, 3.0e38)), tracer.epsilon, seed, ao,
    ])
    tracer.rays_cast += len(tri_vertices) * strata * strata
    return ao.numpy()


class AmbientOcclusion(Processor):
    name = "ambient_occlusion"
    version = "2"
    summary = "Per-vertex ambient occlusion by cosine-weighted hemisphere ray casts (the reference AO)."
    facets = ("geometry",)
    provides = (AmbientOcclusionProduct,)

    @dataclass(frozen=True)
    class Params(Params):
        samples: int = param(256, "rays per point (rounded to a square for stratification)", low=1, high=65536)
        max_distance: float = param(math.inf, "hits farther than this (stage units) do not occlude", low=0.0)
        per_face: bool = param(False, "also write per-face AO as primvars:bake:aoFace (uniform)")
        connect_occlusion: bool = param(False, "wire bake:ao into each bound UsdPreviewSurface inputs:occlusion")
        seed: int = param(0, "random seed (identical results across thread counts)", low=0)

    def applies(self, ctx: Context) -> tuple[bool, str]:
        scene = ctx.scene
        if len(receiver_prims(scene)) == 0:
            return False, "no writable meshes (all instanced, bake:skip or empty)"
        return True, ""

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        receivers = receiver_prims(scene)
        normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
        point_mask = np.isin(scene.point_prim, receivers)
        point_ids = np.flatnonzero(point_mask)
        ao_points = np.ones(scene.num_points, np.float32)
        ctx.progress(0.0)
        ao_points[point_ids] = compute_vertex_ao(
            ctx.tracer, scene.points[point_ids], normals[point_ids],
            samples=p.samples, max_distance=p.max_distance, seed=p.seed)
        ctx.progress(0.5 if p.per_face else 1.0)

        result = Result(products={AmbientOcclusionProduct: AmbientOcclusionProduct(ao_points)})
        for prim in receivers:
            result.outputs.append(Primvar(scene.prim_paths[prim], "bake:ao", ao_points[scene.prim_points(prim)],
                                          "float", "vertex"))
        if p.per_face:
            self._per_face(scene, p, ctx.tracer, receivers, result)
            ctx.progress(1.0)
        if p.connect_occlusion:
            result.outputs.extend(occlusion_network(scene, receivers))
        rays_per_point = strata_for(p.samples) ** 2
        result.stats["rays"] = float(len(point_ids) * rays_per_point
                                     + (int(np.isin(scene.tri_prim, receivers).sum()) * rays_per_point
                                        if p.per_face else 0))
        skipped = int((~scene.prim_writable).sum())
        if skipped:
            result.messages.append(f"{skipped} instanced prims occlude but receive no AO (read-only in USD)")
        return result

    @staticmethod
    def _per_face(scene: Scene, p, tracer, receivers: np.ndarray, result: Result) -> None:
        tris = np.flatnonzero(np.isin(scene.tri_prim, receivers))
        tri_ao = compute_face_ao(tracer, scene.points, scene.tri_vertices[tris], scene.tri_normals[tris],
                                 samples=p.samples, max_distance=p.max_distance, seed=p.seed)
        for prim in receivers:
            mine = scene.tri_prim[tris] == prim
            values = face_means(tri_ao[mine], scene.tri_areas[tris][mine], scene.tri_face[tris][mine],
                                int(scene.prim_face_count[prim]))
            result.outputs.append(Primvar(scene.prim_paths[prim], "bake:aoFace", values, "float", "uniform"))


def occlusion_network(scene: Scene, receivers: np.ndarray) -> list:
    """Records for a UsdPrimvarReader_float reading bake:ao into each bound surface's inputs:occlusion."""
    records: list = []
    surfaces = sorted({scene.prim_surface[prim] for prim in receivers} - {""})
    for surface in surfaces:
        reader = surface.rsplit("/", 1)[0] + "/bakeAoReader"
        records += [
            Prim(reader, "Shader"),
            Attribute(reader, "info:id", "UsdPrimvarReader_float", "token", uniform=True),
            Attribute(reader, "inputs:varname", "bake:ao", "string"),
            Attribute(reader, "inputs:fallback", 1.0, "float"),
            Attribute(reader, "outputs:result", None, "float"),
            Attribute(surface, "inputs:occlusion", None, "float", connect_to=f"{reader}.outputs:result"),
        ]
    return records
