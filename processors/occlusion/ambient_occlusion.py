"""Ambient occlusion by cosine-weighted hemisphere ray casts.

The reference every faster AO estimate in usdbake is checked against::

    AO(x) = 1/pi * integral_{H(n)} V(x, w) cos(theta) dw

(Zhukov, Iones & Kronin, "An ambient light illumination model", EGWR 1998:
their obscurance with the distance mapping a step at ``max_distance``)
estimated with stratified cosine-weighted directions (concentric map +
Malley; Pharr, Jakob & Humphreys, PBRT 3rd ed., Section 13.6.3), so AO is the
mean visibility V of the sampled rays (the Monte Carlo estimator f/p of PBRT
Section 13.2, with f/p = V); V = 0 when a ray hits geometry closer than
``max_distance``. The estimator lives in ``kernels.occlusion``, shared with
``instance_ao``.

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

Instanced receivers (``instances``; ``processors/occlusion/instances.py``): USD holds no per-vertex data on an
instance, so with ``mean`` (the default) each instance gets the area-weighted mean AO of its
surface: ``primvars:bake:ao`` (constant) on a native instance's root prim, which its meshes
inherit, and ``primvars:bake:ao`` (vertex: one value per instance, 1 for masked rows) on a
PointInstancer; ``skip`` leaves instances out. The bake's messages say which was done. For
per-vertex AO on native instances, bake with ``--deinstance`` (``usdbake.bake(deinstance=True)``):
their meshes are then ordinary receivers of every processor, de-instanced in the bake layer.

Parameters: ``usdbake list ambient_occlusion`` or docs/ambient_occlusion.md, both generated from ``Params`` below.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ...core import Attribute, Context, Params, Prim, Primvar, Processor, Result, param
from .products import AmbientOcclusionProduct
from ...core.scene import Scene
from .instances import instanced_receivers, per_instance_means
from ...geometry.mesh import NO_RECEIVERS, face_means, receiver_prims, vertex_inward, vertex_normals
from ...kernels.occlusion import AOPoint, AORays, ao_direction, ao_point, ao_rays, as_points_and_normals, launch_ao
from ...kernels.sampling import strata_for, triangle_point
from ...kernels.tracer import surface_origin, triangle_origin
from ...kernels.traversal import trace_any

wp.set_module_options({"enable_backward": False, "fuse_fp": False})


@wp.func
def occlusion_at(rays: AORays, origin: wp.vec3, point: AOPoint) -> float:
    """AO estimate (dimensionless, [0, 1]) at ``origin``: the fraction of the strata^2 stratified
    cosine-weighted rays of ``point`` that hit nothing within ``max_distance`` (stage units):
    the Monte Carlo estimate of Zhukov et al.'s integral with pdf cos(theta)/pi (PBRT 3rd ed., Sections
    13.2 and 13.6.3; ``kernels.occlusion``)."""
    count = rays.strata * rays.strata
    visible = int(0)
    direction = ao_direction(rays, point, 0)
    for k in range(count):
        current = direction
        direction = ao_direction(rays, point, wp.min(k + 1, count - 1))  # the next ray's, made during this trace
        if not trace_any(rays.scene, origin, current, rays.max_distance):
            visible += 1
    return float(visible) / float(count)


@wp.kernel
def vertex_ao_kernel(start: int, rays: AORays, first: int, positions: wp.array(dtype=wp.vec3),
                     normals: wp.array(dtype=wp.vec3), inward: wp.array(dtype=wp.vec3), ao: wp.array(dtype=float)):
    """AO (dimensionless, [0, 1]) at point i around its unit normal by ``occlusion_at`` (Zhukov et al. 1998
    integral, PBRT 3rd ed. Section 13.6.3 rays) from ``surface_origin`` (``inward``: the vertex's unit
    tangent into its own faces, ``vertex_inward``); a point without a normal gets 1. Point i's rays are
    seeded by (seed, first + i): ``first`` is the global index of positions[0] (a chunk's start)."""
    i = start + wp.tid()
    n = normals[i]
    if wp.length(n) < 0.5:
        ao[i] = 1.0
        return
    ao[i] = occlusion_at(rays, surface_origin(rays.scene, positions[i], n, inward[i], rays.epsilon),
                         ao_point(rays, n, first + i))


@wp.kernel
def face_ao_kernel(start: int, rays: AORays, first: int, points: wp.array(dtype=wp.vec3),
                   triangles: wp.array(dtype=wp.vec3i), tri_normals: wp.array(dtype=wp.vec3), ao: wp.array(dtype=float)):
    """AO (dimensionless, [0, 1]) averaged over triangle i's area and hemisphere: the estimator of
    vertex_ao_kernel (Zhukov et al. 1998 integral, PBRT 3rd ed. Section 13.6.3 rays), each ray from its
    own uniform random point on the triangle (Osada et al. 2002 square-root warp), so the mean estimates
    (1/A) integral_A AO(x) dA. Triangle i seeds its directions and its points by (seed, first + i)."""
    i = start + wp.tid()
    n = tri_normals[i]
    if wp.length(n) < 0.5:
        ao[i] = 1.0
        return
    tri = triangles[i]
    a = points[tri[0]]
    b = points[tri[1]]
    c = points[tri[2]]
    point = ao_point(rays, n, first + i)
    state = wp.rand_init(wp.int32(point.state), -1)  # the points' own stream, apart from the rays' jitter hashes
    visible = int(0)
    for k in range(rays.strata * rays.strata):
        x = triangle_point(a, b, c, wp.randf(state), wp.randf(state))
        origin = triangle_origin(rays.scene, a, b, c, x, n, rays.epsilon)
        if not trace_any(rays.scene, origin, ao_direction(rays, point, k), rays.max_distance):
            visible += 1
    ao[i] = float(visible) / float(rays.strata * rays.strata)


def compute_vertex_ao(tracer, positions: np.ndarray, normals: np.ndarray, *, samples: int,
                      max_distance: float = math.inf, seed: int = 0, inward: np.ndarray | None = None,
                      first: int = 0) -> np.ndarray:
    """AO at points with unit normals (vertex_ao_kernel: Zhukov et al. 1998 integral, estimated with
    cosine-weighted rays, PBRT 3rd ed. Sections 13.2 and 13.6.3).

    Parameters
    ----------
    tracer : Tracer
    positions, normals : (N, 3) float32, stage units and unit vectors
    samples : rays per point (rounded to a square)
    max_distance : stage units; farther hits do not occlude
    inward : (N, 3) float32 unit tangents into each point's own surface (``vertex_inward``); None: zero
    first : global index of positions[0], which seeds its rays (a chunk of a larger set, core.chunks)

    Returns
    -------
    (N,) float32 in [0, 1]; 1 where the normal is zero.
    """
    positions, normals = as_points_and_normals(positions, normals)
    rays = ao_rays(tracer.scene, samples=samples, max_distance=max_distance, epsilon=tracer.epsilon, seed=seed,
                   device=tracer.device)
    inward = np.zeros_like(positions) if inward is None else np.ascontiguousarray(inward, np.float32).reshape(-1, 3)
    return launch_ao(tracer, vertex_ao_kernel, len(positions), rays, [
        int(first), tracer.array(positions, wp.vec3), tracer.array(normals, wp.vec3), tracer.array(inward, wp.vec3)])


def compute_face_ao(tracer, points: np.ndarray, tri_vertices: np.ndarray, tri_normals: np.ndarray, *,
                    samples: int, max_distance: float = math.inf, seed: int = 0, first: int = 0) -> np.ndarray:
    """(T,) float32 AO in [0, 1] averaged over each triangle's area and hemisphere (face_ao_kernel: the
    Zhukov et al. 1998 integral, PBRT 3rd ed. Section 13.6.3 rays).

    ``points`` (P, 3) float32 stage units, ``tri_vertices`` (T, 3) int, ``tri_normals`` (T, 3) unit;
    ``first``: global index of triangle 0, which seeds its rays (core.chunks).
    """
    rays = ao_rays(tracer.scene, samples=samples, max_distance=max_distance, epsilon=tracer.epsilon, seed=seed,
                   device=tracer.device)
    return launch_ao(tracer, face_ao_kernel, len(tri_vertices), rays, [
        int(first), tracer.array(points, wp.vec3), tracer.array(tri_vertices.astype(np.int32), wp.vec3i),
        tracer.array(tri_normals, wp.vec3)])


def vertex_ao_chunk(tracer, first: int, positions: np.ndarray, normals: np.ndarray, inward: np.ndarray, *,
                    samples: int, max_distance: float, seed: int) -> np.ndarray:
    """``compute_vertex_ao`` of points first .. first + len(positions) - 1: one chunk (core.chunks)."""
    return compute_vertex_ao(tracer, positions, normals, inward=inward, samples=samples, max_distance=max_distance,
                             seed=seed, first=first)


def face_ao_chunk(tracer, first: int, tri_corners: np.ndarray, tri_normals: np.ndarray, *, samples: int,
                  max_distance: float, seed: int) -> np.ndarray:
    """``compute_face_ao`` of triangles first .. first + len(tri_corners) - 1 given by their (T, 3, 3)
    corners, so a chunk carries only its own triangles: one chunk (core.chunks)."""
    corners = np.ascontiguousarray(tri_corners, np.float32).reshape(-1, 3)
    return compute_face_ao(tracer, corners, np.arange(len(corners), dtype=np.int32).reshape(-1, 3), tri_normals,
                           samples=samples, max_distance=max_distance, seed=seed, first=first)


class AmbientOcclusion(Processor):
    name = "ambient_occlusion"
    version = "2"
    summary = "Per-vertex ambient occlusion by cosine-weighted hemisphere ray casts (the reference AO)."
    facets = ("geometry",)
    follows_refinement = True
    writes = ("primvars:bake:ao", "primvars:bake:aoFace", "inputs:occlusion")
    provides = (AmbientOcclusionProduct,)

    @dataclass(frozen=True)
    class Params(Params):
        samples: int = param(256, "rays per point (rounded to a square for stratification)", low=1, high=65536)
        max_distance: float = param(math.inf, "hits farther than this (stage units) do not occlude", low=0.0)
        per_face: bool = param(False, "also write per-face AO as primvars:bake:aoFace (uniform)")
        connect_occlusion: bool = param(False, "wire bake:ao into each bound UsdPreviewSurface inputs:occlusion")
        seed: int = param(0, "random seed (identical results across thread counts)", low=0)
        instances: str = param("mean", "instanced receivers: mean (per-instance mean AO on the instance root "
                               "or PointInstancer) or skip; --deinstance bakes native ones per vertex",
                               choices=("mean", "skip"))

    def applies(self, ctx: Context) -> tuple[bool, str]:
        scene = ctx.scene
        if len(receiver_prims(scene)) or (self.params.instances != "skip" and len(instanced_receivers(scene))):
            return True, ""
        return False, NO_RECEIVERS

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        receivers = receiver_prims(scene)
        instanced = instanced_receivers(scene) if p.instances != "skip" else np.zeros(0, np.int64)
        normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
        point_mask = np.isin(scene.point_prim, np.concatenate([receivers, instanced]))
        point_ids = np.flatnonzero(point_mask)
        ao_points = np.ones(scene.num_points, np.float32)
        ctx.progress(0.0)
        inward = vertex_inward(scene.points, scene.tri_vertices, normals)
        share = 0.5 if p.per_face else 1.0
        ao_points[point_ids] = ctx.chunks.map(
            vertex_ao_chunk, (scene.points[point_ids], normals[point_ids], inward[point_ids]),
            progress=lambda f: ctx.progress(share * f), samples=p.samples, max_distance=p.max_distance, seed=p.seed)
        ctx.progress(share)

        result = Result(products={AmbientOcclusionProduct: AmbientOcclusionProduct(ao_points)})
        for prim in receivers:
            result.outputs.append(Primvar(scene.prim_paths[prim], "bake:ao", ao_points[scene.prim_points(prim)],
                                          "float", "vertex"))
        if p.per_face:
            self._per_face(scene, p, ctx, receivers, result)
            ctx.progress(1.0)
        if p.connect_occlusion:
            result.outputs.extend(occlusion_network(scene, receivers))
        if len(instanced):
            self._instances(scene, p, instanced, ao_points, result)
        rays_per_point = strata_for(p.samples) ** 2
        result.stats["rays"] = float(len(point_ids) * rays_per_point
                                     + (int(np.isin(scene.tri_prim, receivers).sum()) * rays_per_point
                                        if p.per_face else 0))
        skipped = len(instanced_receivers(scene)) if p.instances == "skip" else 0
        if skipped:
            result.messages.append(f"{skipped} instanced meshes occlude but receive no AO (instances=skip)")
        return result

    @staticmethod
    def _instances(scene: Scene, p, instanced: np.ndarray, ao_points: np.ndarray, result: Result) -> None:
        """Per-instance means (module docstring)."""
        means = per_instance_means(scene, ao_points, instanced, fill=1.0)
        for root, value in means.native.items():
            result.outputs.append(Primvar(root, "bake:ao", np.array([value], np.float32), "float", "constant"))
        for instancer, values in means.instancers.items():
            result.outputs.append(Primvar(instancer, "bake:ao", values, "float", "vertex"))
        if means.native:
            result.messages.append(f"{len(means.native)} native instances: per-instance mean AO as constant "
                                   f"primvars:bake:ao on their roots (--deinstance for per-vertex AO)")
        for instancer, values in means.instancers.items():
            result.messages.append(f"{instancer}: per-instance mean AO of its {len(values)} instances as "
                                   f"primvars:bake:ao (one value per instance)")

    @staticmethod
    def _per_face(scene: Scene, p, ctx: Context, receivers: np.ndarray, result: Result) -> None:
        tris = np.flatnonzero(np.isin(scene.tri_prim, receivers))
        tri_ao = ctx.chunks.map(face_ao_chunk, (scene.points[scene.tri_vertices[tris]], scene.tri_normals[tris]),
                                progress=lambda f: ctx.progress(0.5 + 0.5 * f), samples=p.samples,
                                max_distance=p.max_distance, seed=p.seed)
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
