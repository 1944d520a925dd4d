"""Radiosity relight: direct light with shadow rays, indirect light from the compressed operator.

The apply half of Shcherbakov (MSU 2017), section 5: for the current lights,

1. **Direct irradiance** ``E0`` (W/m^2 when light radiance is W/(m^2 sr)) at
   several stratified points per patch and at every mesh vertex, with shadow
   rays through the shared BVH:

   ``direct_irradiance`` of the shared light model (kernels/lights.py:
   UsdLux distant, dome, sphere, rect and disk lights, and emissive
   triangles picked by power, ``light_samples`` stratified samples per light).
   The domes by ``sky_guide``: ``sky_training`` cosine rays a point
   learn, per group of nearby points facing one axis, where the sky is seen
   (through a window: a few directions), then ``sky_samples`` rays, a quarter
   cosine-weighted and the rest drawn from that guide, are combined by the
   balance heuristic (unbiased; in a room lit through a window the median
   error of a point's sky term is 8 % at 256 rays, where cosine rays alone
   give 19 % at 256 rays, 11 % at 512 and 57 % at the former default of 64). Emitted light always
   enters the outgoing radiosity product.

2. **Indirect irradiance** at the patches, ``E_ind = M E0`` with the
   multi-bounce operator of ``form_factors``: the relight kernel decodes the
   BC1 blocks of each block row on the fly (endpoints -> 4-entry palette ->
   256-entry code table, never materializing the float matrix), adds the exact
   sparse part, and works in the stored (permuted) order.

3. **Transfer to the mesh**: a final gather per vertex (section 3.5 step 5):
   ``gather_rays`` cosine-weighted rays, each hit adding rho (E0 + E_ind) of
   the patch it lands on, so a vertex sees the patches' k bounces plus the
   gather's own reflection (k + 1, what a probe looking at the patches sees).
   Hits nearer than ``near_hits`` voxel edges (corners, contact edges) take
   E0 at the hit itself (one shadow ray per light, ``hit_sky_samples`` dome
   rays) and their first bounce from one more ray, bounces 2..k from the
   patch (its k-bounce light minus a patch-level gather of its first bounce).
   With ``gather_rays = 0`` each vertex instead blends the k-bounce indirect
   irradiance of its ``neighbors`` nearest patch centroids whose normals
   agree (cos > ``normal_cos``), ``w = (n_v . n_p)^2 / (d^2 + (voxel/2)^2)``:
   no rays, smooth, blurred in corners.
   Direct light at vertices is computed exactly (step 1), not interpolated,
   at the vertex moved 0.1 % towards the centre of its triangle ring
   (VERTEX_INSET) so a vertex on a seam between meshes does not start its
   rays inside the other.

USD written (bake layer), on writable prims with triangles and no ``bake:skip``:

================================= ========= ============= ==============================
property                          type      interpolation value
================================= ========= ============= ==============================
primvars:bake:irradianceDirect    color3f[] vertex        direct irradiance E0 (W/m^2)
primvars:bake:irradianceIndirect  color3f[] vertex        indirect irradiance (W/m^2)
================================= ========= ============= ==============================

Product ``RadiosityProduct`` (products.py, for later processors): patch centroids, normals, areas,
direct and indirect irradiance, and outgoing radiosity ``B = rho (E0 + E_ind)
+ pi L_e`` (W/m^2), one row per patch.

Parameters: ``usdbake list radiosity`` or docs/radiosity.md, both generated from ``Params`` below.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import warp as wp

from ...core import Context, Primvar, Processor, Result, TextureTargetParams, param
from .products import FormFactorProduct, RadiosityProduct
from ...core.scene import LIGHT_DOME, Scene
from ...geometry.mesh import missing_receivers, receiver_prims, vertex_normals
from ...kernels.lightmap_bake import inset_points, layout_messages, lightmap_records, page_image, texel_samples, texture_record
from ...kernels.lightmap_layout import lightmap_layout
from ...kernels.light_bundles import NO_LIGHTS, has_light, light_bundle, shadow_rays_per_point
from ...kernels.lights import Lights, direct_irradiance
from .sky_guide import guided_ray_split, guided_sky_irradiance, learn_sky_guides
from .operator_relight import OperatorRelighter
from .patch_kernels import fragment_of_hit
from ...kernels.sampling import cosine_hemisphere, strata_for, tangent_frame
from ...kernels.tracer import FAR, surface_origin
from ...kernels.traversal import TraceScene, trace_closest

wp.set_module_options({"enable_backward": False, "fuse_fp": False})


# ---------------------------------------------------------------------------
# Direct light (the shared light model, kernels/lights.py)


@wp.kernel
def direct_kernel(
    start: int,
    scene: TraceScene,
    lights: Lights,
    positions: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    strata: int,
    guide_cdf: wp.array2d(dtype=float),
    guide_of: wp.array(dtype=int),
    sky_split: wp.vec3i,
    epsilon: float,
    seed: int,
    irradiance: wp.array(dtype=wp.vec3),
):
    """E0 at point i (zero for a point without a normal): the initial irradiance vector of the relight,
    Shcherbakov section 3.5 step 1, W/m^2. The small lights and emitters by ``direct_irradiance``, the
    domes by ``guided_sky_irradiance`` (cosine rays and rays from the point's learned guide)."""
    i = start + wp.tid()
    n = normals[i]
    if wp.length(n) < 0.5:
        irradiance[i] = wp.vec3(0.0, 0.0, 0.0)
        return
    state = wp.rand_init(seed, i)
    e = direct_irradiance(scene, lights, positions[i], n, strata, 0, epsilon, state)
    if sky_split[0] > 0:
        e += guided_sky_irradiance(scene, lights, positions[i], n, guide_cdf, guide_of[i], sky_split, epsilon,
                                   wp.rand_init(seed, -1 - i))
    irradiance[i] = e


def compute_direct_irradiance(tracer, scene: Scene, positions: np.ndarray, normals: np.ndarray, *,
                              light_samples: int = 16, sky_samples: int = 64, sky_training: int = 16,
                              seed: int = 0, emissive: str = "auto") -> np.ndarray:
    """(N, 3) float32 direct irradiance (W/m^2) at points with unit normals (zero normal -> 0).

    positions, normals : (N, 3) float32 in the scene frame. With dome lights, ``sky_training`` cosine rays
    a point first learn where the sky is seen (``sky_guide``), then ``sky_samples`` rays estimate it.
    """
    positions = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    normals = np.ascontiguousarray(normals, np.float32).reshape(-1, 3)
    strata = strata_for(light_samples)
    lights = light_bundle(scene, tracer.device, emissive=emissive)
    domes = int((np.asarray(scene.lights.light_kind) == LIGHT_DOME).any())
    split = guided_ray_split(sky_samples) if domes else wp.vec3i(0, 0, 0)
    guides = learn_sky_guides(tracer, lights, positions, normals, training=sky_training if domes else 0,
                              seed=seed + 7919)
    out = wp.zeros(len(positions), dtype=wp.vec3, device=tracer.device)
    tracer.launch(direct_kernel, len(positions), [
        tracer.scene, lights, tracer.array(positions, wp.vec3), tracer.array(normals, wp.vec3), strata,
        guides.cdf, guides.guide_of, split, tracer.epsilon, seed, out,
    ])
    tracer.rays_cast += len(positions) * (shadow_rays_per_point(scene, strata=strata, sky_strata=0, emissive=emissive)
                                          + (sky_samples if domes else 0))
    return np.nan_to_num(out.numpy(), nan=0.0, posinf=0.0, neginf=0.0)


# ---------------------------------------------------------------------------
# Transfer to the mesh


@wp.func
def patch_light(
    scene: TraceScene,
    origin: wp.vec3,
    direction: wp.vec3,
    tri_normals: wp.array(dtype=wp.vec3),
    tri_albedo: wp.array(dtype=wp.vec3),
    tri_subdivision: wp.array(dtype=int),
    tri_fragment_start: wp.array(dtype=int),
    fragment_patch: wp.array(dtype=int),
    patch_direct: wp.array(dtype=wp.vec3),
) -> wp.vec3:
    """rho(z) E0(patch of z) at the front face z a ray meets (W/m^2; zero on a miss or a back face)."""
    q = trace_closest(scene, origin, direction, FAR)
    if q.result:
        if wp.dot(direction, tri_normals[q.face]) < 0.0:
            patch = fragment_patch[fragment_of_hit(q.face, q.u, q.v, tri_subdivision, tri_fragment_start)]
            if patch >= 0:
                return wp.cw_mul(tri_albedo[q.face], patch_direct[patch])
    return wp.vec3(0.0, 0.0, 0.0)


@wp.kernel
def final_gather_kernel(
    start: int,
    scene: TraceScene,
    lights: Lights,
    positions: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    tri_normals: wp.array(dtype=wp.vec3),
    tri_albedo: wp.array(dtype=wp.vec3),
    tri_subdivision: wp.array(dtype=int),
    tri_fragment_start: wp.array(dtype=int),
    fragment_patch: wp.array(dtype=int),
    patch_direct: wp.array(dtype=wp.vec3),
    patch_indirect: wp.array(dtype=wp.vec3),
    patch_higher: wp.array(dtype=wp.vec3),
    near: float,
    strata: int,
    sky_strata: int,
    epsilon: float,
    seed: int,
    irradiance: wp.array(dtype=wp.vec3),
    near_hits: wp.array(dtype=int),
):
    """Final gather, Shcherbakov section 3.5 step 5 (the patch solution carried to the mesh):
    E_ind(x) = sum_j F_xj rho_j (E0_j + E_ind_j), estimated over strata^2 cosine-weighted rays from x as
    the mean of rho(y) (E0(y) + E_ind(y)) at the hits y (back faces absorb, as in the form factors),
    with the hit patch's means. Hits nearer than ``near`` (corners, contact edges, where light varies
    within a patch) evaluate E0(y) at y (one shadow ray per light, sky_strata^2 dome rays) and
    E_ind(y) as rho(z) E0(z) at the patch z one more cosine ray from y meets plus y's patch bounces
    2..k (``patch_higher``). Counts the near hits per point (their rays)."""
    i = start + wp.tid()
    n = normals[i]
    e = wp.vec3(0.0, 0.0, 0.0)
    near_count = int(0)
    if wp.length(n) < 0.5:
        irradiance[i] = e
        return
    state = wp.rand_init(seed, i)
    frame = tangent_frame(n)
    origin = surface_origin(scene, positions[i], n, wp.vec3(0.0, 0.0, 0.0), epsilon)
    rays = strata * strata
    inv = 1.0 / float(strata)
    for k in range(rays):
        # Jitter drawn here, not in a wp.func: the state is passed by value, and the light sample at
        # each hit must see a state advanced past every earlier one.
        u1 = (float(k % strata) + wp.randf(state)) * inv
        u2 = (float(k // strata) + wp.randf(state)) * inv
        w = frame * cosine_hemisphere(u1, u2)
        q = trace_closest(scene, origin, w, FAR)
        if q.result:
            hn = tri_normals[q.face]
            if wp.dot(w, hn) < 0.0:
                patch = fragment_patch[fragment_of_hit(q.face, q.u, q.v, tri_subdivision, tri_fragment_start)]
                indirect = wp.vec3(0.0, 0.0, 0.0)
                direct = wp.vec3(0.0, 0.0, 0.0)
                if patch >= 0:
                    indirect = patch_indirect[patch]
                    direct = patch_direct[patch]
                if q.t < near or patch < 0:
                    y = origin + w * q.t
                    direct = direct_irradiance(scene, lights, y, hn, 1, sky_strata, epsilon, state)
                    # The first bounce at y varies fast near corners and contact edges: one more cosine ray
                    # from y to the direct light it meets; bounces 2..k from y's patch.
                    v = tangent_frame(hn) * cosine_hemisphere(wp.randf(state), wp.randf(state))
                    indirect = patch_light(scene, surface_origin(scene, y, hn, wp.vec3(0.0, 0.0, 0.0), epsilon), v,
                                           tri_normals, tri_albedo, tri_subdivision, tri_fragment_start,
                                           fragment_patch, patch_direct)
                    if patch >= 0:
                        indirect = indirect + patch_higher[patch]
                    near_count += 1
                e += wp.cw_mul(tri_albedo[q.face], direct + indirect)
    irradiance[i] = e / float(rays)
    near_hits[i] = near_count


def final_gather(tracer, scene: Scene, patches, patch_direct: np.ndarray, patch_indirect: np.ndarray,
                 patch_higher: np.ndarray, positions: np.ndarray, normals: np.ndarray, *, rays: int, near: float,
                 sky_samples: int, seed: int = 0, emissive: str = "auto") -> np.ndarray:
    """(N, 3) float32 indirect irradiance at points: one gather over the patches' direct + indirect light."""
    strata, sky_strata = strata_for(rays), strata_for(sky_samples)
    out = wp.zeros(len(positions), dtype=wp.vec3, device=tracer.device)
    near_hits = wp.zeros(len(positions), dtype=int, device=tracer.device)
    tracer.launch(final_gather_kernel, len(positions), [
        tracer.scene, light_bundle(scene, tracer.device, emissive=emissive),
        tracer.array(np.ascontiguousarray(positions, np.float32), wp.vec3),
        tracer.array(np.ascontiguousarray(normals, np.float32), wp.vec3),
        tracer.array(scene.tri_normals, wp.vec3), tracer.array(scene.tri_albedo, wp.vec3),
        tracer.array(patches.tri_subdivision, wp.int32), tracer.array(patches.tri_fragment_start, wp.int32),
        tracer.array(patches.fragment_patch, wp.int32),
        tracer.array(np.ascontiguousarray(patch_direct, np.float32), wp.vec3),
        tracer.array(np.ascontiguousarray(patch_indirect, np.float32), wp.vec3),
        tracer.array(np.ascontiguousarray(patch_higher, np.float32), wp.vec3), float(near), strata, sky_strata, tracer.epsilon, seed, out, near_hits,
    ])
    tracer.rays_cast += len(positions) * strata * strata + int(near_hits.numpy().sum()) * (1 + shadow_rays_per_point(
        scene, strata=1, sky_strata=sky_strata, emissive=emissive))
    return np.nan_to_num(out.numpy())


VERTEX_INSET = 1e-3
"""Vertices are evaluated this fraction of the way towards the centre of their triangle ring: a
vertex on the seam of two meshes (a wall standing on a floor) can sit a rounding error behind its
neighbour, where every ray would start inside it."""


def vertex_sample_positions(points: np.ndarray, tri_vertices: np.ndarray, tri_areas: np.ndarray,
                            inset: float = VERTEX_INSET) -> np.ndarray:
    """(P, 3) float32 points moved ``inset`` of the way towards the area-weighted centroid of their ring."""
    corners = points[tri_vertices].astype(np.float64)
    centroids = corners.mean(axis=1) * tri_areas[:, None]
    accum = np.zeros((len(points), 3), np.float64)
    weight = np.zeros(len(points), np.float64)
    for corner in range(3):
        np.add.at(accum, tri_vertices[:, corner], centroids)
        np.add.at(weight, tri_vertices[:, corner], tri_areas.astype(np.float64))
    ring = np.where(weight[:, None] > 0, accum / np.maximum(weight, 1e-300)[:, None], points)
    return (points + inset * (ring - points)).astype(np.float32)


def transfer_to_vertices(positions: np.ndarray, normals: np.ndarray, patch_centroids: np.ndarray,
                         patch_normals: np.ndarray, patch_values: np.ndarray, *, neighbors: int = 8,
                         normal_cos: float = 0.5, smoothing: float = 0.0) -> np.ndarray:
    """(N, 3) float32 values at points blended from the nearest patches with agreeing normals.

    Weights ``(n_v . n_p)^2 / (d^2 + smoothing^2)`` over the ``neighbors`` nearest centroids with
    ``n_v . n_p > normal_cos``; a point none of them agrees with takes the nearest patch facing
    its side (n_v . n_p > 0), else 0. Points without a normal blend by distance only.
    """
    from scipy.spatial import cKDTree

    if len(patch_centroids) == 0 or len(positions) == 0:
        return np.zeros((len(positions), 3), np.float32)
    k = min(neighbors, len(patch_centroids))
    tree = cKDTree(patch_centroids.astype(np.float64))
    dist, idx = tree.query(positions.astype(np.float64), k=k)
    dist = dist.reshape(len(positions), k)
    idx = idx.reshape(len(positions), k)
    cos = np.einsum("nkc,nc->nk", patch_normals[idx].astype(np.float64), normals.astype(np.float64))
    has_normal = np.linalg.norm(normals, axis=1) > 0.5
    agree = np.where(has_normal[:, None], cos > normal_cos, True)
    w = np.where(agree, np.where(has_normal[:, None], cos, 1.0) ** 2 / (dist ** 2 + smoothing ** 2 + 1e-30), 0.0)
    total = w.sum(axis=1)
    values = patch_values[idx].astype(np.float64)
    out = np.einsum("nk,nkc->nc", w, values) / np.maximum(total, 1e-300)[:, None]
    lonely = total <= 0
    if lonely.any():
        facing = cos[lonely] > 0
        first = np.where(facing.any(axis=1), facing.argmax(axis=1), -1)
        fallback = np.where(first[:, None] >= 0, values[lonely][np.arange(lonely.sum()), np.maximum(first, 0)], 0.0)
        out[lonely] = fallback
    return np.nan_to_num(out).astype(np.float32)


# ---------------------------------------------------------------------------
# Processor


def _patch_points(patches, points_per_patch: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)  # fixed seed: points are part of the result's definition
    n = patches.count
    u = (np.arange(points_per_patch)[None, :] + rng.random((n, points_per_patch))) / points_per_patch
    start = patches.patch_fragment_start.astype(np.int64)
    counts = np.diff(start)
    cdf = patches.patch_fragment_cdf.astype(np.float64) + np.repeat(np.arange(n), counts)
    slot = np.searchsorted(cdf, (np.minimum(u, 1 - 1e-9) + np.arange(n)[:, None]).ravel(), side="right")
    slot = np.clip(slot, np.repeat(start[:-1], points_per_patch), np.repeat(start[1:] - 1, points_per_patch))
    fragment = patches.patch_fragments[slot]
    corners = patches.fragment_vertices[fragment].astype(np.float64)
    r1 = np.sqrt(rng.random(len(fragment)))[:, None]
    r2 = rng.random(len(fragment))[:, None]
    points = corners[:, 0] * (1 - r1) + corners[:, 1] * (r1 * (1 - r2)) + corners[:, 2] * (r1 * r2)
    return points.astype(np.float32), fragment


def solve(tracer, scene: Scene, product, p, point_ids: np.ndarray, progress=lambda f: None,
          apply_operator=None, texels: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """Direct light, compressed relight and transfer for the points ``point_ids`` (pure; run and benchmarks).

    Vertex indirect light: with ``gather_rays`` > 0 a final gather over the patches' direct + k-bounce
    indirect light (``final_gather``: the gather adds one reflection, k + 1 in all, as a probe or any
    point looking at the patches sees), with direct light evaluated at near hits; with 0 the patches'
    k-bounce indirect light interpolated (``transfer_to_vertices``: no rays, smooth, blurred in corners).
    ``apply_operator(E0) -> E_ind`` replaces the relight (run: an OperatorRelighter for the step's memory budget; benchmarks: the dense operator).
    ``texels``: (points, unit normals) of lightmap texels (the texture target), lit by the same transfer as the
    vertices (``texel_direct``, ``texel_indirect`` in the result).
    ``transfer_seconds`` in the result: the time of the vertices' transfer (the gather or the blend).
    """
    patches, op = product.patches, product.operator
    points, fragment = _patch_points(patches, p.patch_points, p.seed)
    point_normals = scene.tri_normals[patches.fragment_tri[fragment]]
    e0_patch = compute_direct_irradiance(tracer, scene, points, point_normals, light_samples=p.light_samples,
                                         sky_samples=p.sky_samples, sky_training=p.sky_training, seed=p.seed + 1,
                                         emissive=p.emissive_lights)
    e0_patch = e0_patch.reshape(patches.count, p.patch_points, 3).mean(axis=1)
    progress(0.3)
    if apply_operator is None:
        e_ind_patch = relighter_for(tracer, op, p).apply(e0_patch)
    else:
        e_ind_patch = np.asarray(apply_operator(e0_patch), np.float32)
    # Only the triangles around the points: instances (a million flattened triangles) get no vertex values.
    wanted = np.zeros(scene.num_points, bool)
    wanted[point_ids] = True
    tris = np.flatnonzero(wanted[scene.tri_vertices].any(axis=1))
    tri_vertices, tri_areas = scene.tri_vertices[tris], scene.tri_areas[tris]
    normals = vertex_normals(scene.points, tri_vertices, scene.tri_normals[tris], tri_areas)[point_ids]
    positions = vertex_sample_positions(scene.points, tri_vertices, tri_areas)[point_ids]
    first_patch = None
    if p.gather_rays > 0:
        zero = np.zeros_like(e_ind_patch)
        first_patch = final_gather(tracer, scene, patches, e0_patch, zero, zero, points, point_normals,
                                   rays=max(1, p.gather_rays // p.patch_points), near=0.0, sky_samples=1,
                                   seed=p.seed + 3).reshape(patches.count, p.patch_points, 3).mean(axis=1)
    e0_vertex, e_ind_vertex, transfer_seconds = _light_at(tracer, scene, patches, p, e0_patch, e_ind_patch,
                                                          first_patch, positions, normals, seed=p.seed)
    progress(0.6)
    solved = {"patch_direct": e0_patch.astype(np.float32), "patch_indirect": e_ind_patch,
              "vertex_direct": e0_vertex, "vertex_indirect": e_ind_vertex, "transfer_seconds": transfer_seconds}
    if texels is not None:
        solved["texel_direct"], solved["texel_indirect"], _ = _light_at(
            tracer, scene, patches, p, e0_patch, e_ind_patch, first_patch, *texels, seed=p.seed + 10)
    progress(0.9)
    return solved


def _light_at(tracer, scene: Scene, patches, p, e0_patch: np.ndarray, e_ind_patch: np.ndarray,
              first_patch: np.ndarray | None, positions: np.ndarray, normals: np.ndarray, *,
              seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(direct, indirect) (N, 3) float32 irradiance at points with unit normals (``solve``'s transfer), and the
    seconds the indirect transfer took."""
    direct = compute_direct_irradiance(tracer, scene, positions, normals, light_samples=p.light_samples,
                                       sky_samples=p.sky_samples, sky_training=p.sky_training, seed=seed + 2,
                                       emissive=p.emissive_lights)
    started = time.perf_counter()
    if first_patch is not None:
        higher = np.maximum(e_ind_patch - first_patch, 0.0)
        indirect = final_gather(tracer, scene, patches, e0_patch, e_ind_patch, higher, positions, normals,
                                rays=p.gather_rays, near=p.near_hits * patches.voxel_size,
                                sky_samples=p.hit_sky_samples, seed=seed + 4, emissive=p.emissive_lights)
    else:
        indirect = transfer_to_vertices(positions, normals, patches.patch_centroids, patches.patch_normals,
                                        e_ind_patch, neighbors=p.neighbors, normal_cos=p.normal_cos,
                                        smoothing=0.5 * patches.voxel_size)
    return direct, np.maximum(indirect, 0.0).astype(np.float32), time.perf_counter() - started


def relighter_for(tracer, op, p) -> OperatorRelighter:
    """The operator in its run-time form for ``p.relight_memory_mb`` (0: the default budget)."""
    budget = int(p.relight_memory_mb * 2**20) if p.relight_memory_mb > 0 else None
    return OperatorRelighter(op, device=tracer.device, threads=tracer.threads, memory_budget=budget)


class Radiosity(Processor):
    name = "radiosity"
    version = "3"
    summary = "Direct + multi-bounce indirect irradiance per vertex from the compressed form-factor operator."
    requires = (FormFactorProduct,)
    provides = (RadiosityProduct,)
    facets = ("geometry", "materials", "lights", "uvs")
    follows_refinement = True
    refined_by = "sky_visibility"
    writes = ("primvars:bake:irradianceDirect", "primvars:bake:irradianceIndirect", "bake:lightmap:irradianceDirect:",
              "bake:lightmap:irradianceIndirect:", "primvars:bake:lightmapST")

    @dataclass(frozen=True)
    class Params(TextureTargetParams):
        light_samples: int = param(16, "shadow-ray samples per light, and for the emissive triangles "
                                   "(picked by power)", low=1, high=65536)
        sky_samples: int = param(256, "rays a point for the dome lights: a quarter cosine-weighted, the rest "
                                 "from the sky guide learned by the training rays (sky_guide.py)",
                                 low=1, high=65536)
        sky_training: int = param(16, "cosine rays a point that learn where the sky is seen (pooled over "
                                  "groups of nearby points facing one axis); 0 = cosine rays alone",
                                  low=0, high=65536)
        patch_points: int = param(16, "stratified points per patch for the patch direct light", low=1, high=4096)
        gather_rays: int = param(512, "final-gather rays per vertex over the patches' light (adds one "
                                 "reflection: k + 1 in all); 0 = interpolate the patches' k-bounce light",
                                 low=0, high=65536)
        near_hits: float = param(0.5, "gather hits nearer than this many voxel edges evaluate direct light "
                                 "at the hit, not the patch mean", low=0.0)
        hit_sky_samples: int = param(4, "dome rays per near gather hit", low=1, high=65536)
        neighbors: int = param(8, "nearest patches blended per vertex (gather_rays = 0)", low=1, high=64)
        normal_cos: float = param(0.5, "a patch contributes to a vertex when n_v . n_p exceeds this "
                                  "(gather_rays = 0)", low=-1.0, high=1.0)
        emissive_lights: str = param("auto", "emissive triangles as area lights: auto (only without UsdLux "
                                     "lights), on, off", choices=("auto", "on", "off"))
        relight_memory_mb: float = param(0.0, "memory budget (MB) of the relight operator: the dense float32 "
                                         "operator (BLAS) when it fits, else the compressed kernel; 0 = a "
                                         "quarter of the physical memory", low=0.0)
        refine: bool = param(True, "in a run without a mesh refiner, run sky_visibility's first: faces whose "
                             "sky is partly hidden are split, so vertex light follows a window's light across a "
                             "floor of two triangles (a closed scene is not refined)")
        seed: int = param(0, "random seed (identical results across thread counts)", low=0)

    def applies(self, ctx: Context) -> tuple[bool, str]:
        scene = ctx.scene
        if not has_light(scene):
            return False, NO_LIGHTS
        reason = missing_receivers(scene)
        return not reason, reason

    def needs_refinement(self, scene: Scene) -> tuple[bool, str]:
        if not (np.asarray(scene.lights.light_kind) == LIGHT_DOME).any():
            return False, "no DomeLight (the refinement follows where the sky is partly hidden)"
        return True, ""

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        rays_before = ctx.tracer.rays_cast
        receivers = receiver_prims(scene)
        # the texture target alone lights no vertex: the product's vertex arrays stay 0
        point_ids = np.flatnonzero(np.isin(scene.point_prim, receivers)) if p.target != "texture" \
            else np.zeros(0, np.int64)
        relighter = relighter_for(ctx.tracer, ctx.products[FormFactorProduct].operator, p)
        layout = pages = None
        texels = None
        if p.target in ("texture", "both"):
            layout = lightmap_layout(scene, receivers, density=p.texel_density, max_size=p.max_texture_size,
                                     device=ctx.device)
            pages = texel_samples(scene, layout, vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals,
                                                                scene.tri_areas), ctx.device)
            texels = (np.concatenate([inset_points(page) for page in pages]),
                      np.concatenate([page.normals for page in pages]))
        solved = solve(ctx.tracer, scene, ctx.products[FormFactorProduct], p, point_ids, progress=ctx.progress,
                       apply_operator=relighter.apply, texels=texels)
        e0_vertex = np.zeros((scene.num_points, 3), np.float32)
        e_ind_vertex = np.zeros((scene.num_points, 3), np.float32)
        e0_vertex[point_ids] = solved["vertex_direct"]
        e_ind_vertex[point_ids] = solved["vertex_indirect"]
        patches = ctx.products[FormFactorProduct].patches
        e0_patch, e_ind_patch = solved["patch_direct"], solved["patch_indirect"]
        radiosity = patches.patch_albedo * (e0_patch + e_ind_patch) + math.pi * patches.patch_emission
        result = Result(products={RadiosityProduct: RadiosityProduct(
            patch_centroids=patches.patch_centroids, patch_normals=patches.patch_normals,
            patch_areas=patches.patch_areas, patch_irradiance_direct=e0_patch.astype(np.float32),
            patch_irradiance_indirect=e_ind_patch, patch_radiosity=radiosity.astype(np.float32),
            vertex_irradiance_direct=e0_vertex, vertex_irradiance_indirect=e_ind_vertex,
        )})
        for prim in receivers if p.target != "texture" else ():
            sl = scene.prim_points(prim)
            result.outputs.append(Primvar(scene.prim_paths[prim], "bake:irradianceDirect", e0_vertex[sl],
                                          "color3f", "vertex"))
            result.outputs.append(Primvar(scene.prim_paths[prim], "bake:irradianceIndirect", e_ind_vertex[sl],
                                          "color3f", "vertex"))
        if layout is not None:
            self._textures(scene, p, layout, pages, solved, result)
        result.stats["rays"] = float(ctx.tracer.rays_cast - rays_before)
        result.stats["patches"] = float(patches.count)
        result.messages.append(f"indirect light relit with the {relighter.form} operator "
                               f"({relighter.nbytes / 2**20:.1f} MB)")
        skipped = int((~scene.prim_writable).sum())
        if skipped:
            result.messages.append(f"{skipped} instanced prims occlude and bounce light but get no primvars")
        ctx.progress(1.0)
        return result

    @staticmethod
    def _textures(scene: Scene, p, layout, pages: list, solved: dict, result: Result) -> None:
        """The texture target: direct and indirect irradiance (W/m^2, RGB) per lightmap texel, one half-float
        EXR each per page, described on each mesh (``LightmapAPI:irradianceDirect`` / ``irradianceIndirect``)."""
        for channel, key in (("irradianceDirect", "texel_direct"), ("irradianceIndirect", "texel_indirect")):
            files, first = [], 0
            for page in pages:
                values = solved[key][first:first + len(page.texel)]
                first += len(page.texel)
                meshes = scene.tri_prim[page.triangle] if p.denoise else None
                texture = texture_record(f"{channel}_lightmap_{page.page}",
                                         page_image(page, values, p.margin, denoise_meshes=meshes, hdr=True),
                                         eight_bit_range=False)
                result.outputs.append(texture)
                files.append(texture.path)
            result.outputs.extend(lightmap_records(scene, layout, channel, files, channels="rgb", units="W/m^2",
                                                   with_uvs=channel == "irradianceDirect"))
        result.messages.extend(layout_messages(scene, layout, p.texel_density))
        result.stats["texels"] = float(first)
