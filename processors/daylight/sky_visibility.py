"""Sky visibility factors with adaptive, crack-free mesh refinement (Bosch, Besuievsky & Martin).

Bosch C., Besuievsky G., Martin I., "A hardware accelerated adaptive mesh
subdivision for interactive daylight illumination" -- here with ray-core (BVH) ray
casts instead of occlusion queries. The sky dome is split into patches
(``kernels/sky.py``); the visibility factor of triangle i for patch j
is (paper, Sec. 4.1)::

    V_ij = 1 / (A_i dw_j) * integral_{A_i} integral_{patch j} vis(x, w) max(0, n_i . w) dw dA

estimated with ``samples`` rays per (triangle, patch) pair: stratified,
equal-solid-angle directions inside the patch, each from a uniform random
point on the triangle. Patches wholly below the triangle's horizon are not
traced (V = 0). The sky irradiance of a face under a sky of patch radiances
L_j is then sum_j L_j V_ij dw_j (paper, Eq. 1), pi L for an open upward face
under a uniform sky L.

Adaptive subdivision (paper, Sec. 4.2): a triangle is split into four when
its visibility is partial, its area is above ``min_area`` (relative to the
scene diagonal squared) and it is less than ``max_level`` four-way splits
below its source triangle; only the new triangles are traced again, until
nothing is split. Partial visibility is measured per triangle as::

    partial_i = 2 / pi * sum_j min(Vvis_ij, Vocc_ij) dw_j

where Vvis and Vocc are the cosine-weighted visible and occluded parts of
V_ij: the share of the face's open-sky irradiance that changes across the
face (0 when every patch is wholly visible or wholly hidden, 1 when half of
the face is in shadow from the whole sky). A triangle is refined when
``partial_i > tolerance``, so faces that see no sky are never refined.
``criterion = paper`` is the paper's own test instead: a triangle is split
when some patch j sees it partly (0 < V_ij < 1) with a mean projected area
A_i max(0, n_i . c_j) above ``min_area`` (their A_min, here relative to the
scene diagonal squared rather than in pixels; the cosine term keeps grazing
patches from splitting), below the level cap. The refinement is conforming (``processors/daylight/refine.py``: longest-edge closure, no
T-junctions; watertight input stays watertight).

USD written (bake layer), on each writable mesh prim (not ``bake:skip``, not instanced):

================================ ========== ============= =============================================
property                         type       interpolation meaning
================================ ========== ============= =============================================
points                           point3f[]                the refined mesh, in the prim's local space
faceVertexCounts                 int[]                    all 3
faceVertexIndices                int[]                    refined triangles
orientation                      token                    ``rightHanded`` (winding is written for it)
(every authored attribute)                                carried onto the refined faces (see below)
primvars:bake:sourceFace         int[]      uniform       authored face of the input mesh per face
primvars:bake:skyVisibility      uchar[]    uniform       V_ij quantized to 0..255, elementSize = N
primvars:bake:skyExposure        float[]    uniform       sum_j V_ij dw_j / pi: open-sky share of irradiance
bake:sky:visibilityScale         float                    V = value * scale (1/255)
bake:sky:patchCount ... upAxis   (SkyVisibilityAPI, applied) patch layout, directions, solid angles
================================ ========== ============= =============================================

The refined mesh keeps the authored points at their indices and adds new ones; normals,
velocities, primvars of every interpolation (indexed or not), GeomSubsets, creases and holes are
carried onto it (``stages/refined_mesh.py``: barycentric interpolation at new vertices, uniform
values copied to child faces). Its Scene is the ``RefinedScene`` product: processors that write
per-vertex results run on it in the same run.

Parameters: ``usdbake list sky_visibility`` or docs/daylight.md, both generated from ``Params`` below.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...core import Attribute, Context, Prim, Primvar, Processor, Result, TextureTargetParams, param
from ...core.chunks import SceneChunks
from .glazing import GlassPanes, scene_glazing
from ...core.products import RefinedScene
from .products import SkyVisibilityProduct
from ...core.scene import Scene
from ...geometry.mesh import backdrop_prims, detail_diagonal, missing_receivers, receiver_prims, vertex_normals
from ...kernels.lightmap_bake import layout_messages, texel_samples
from ...kernels.lightmap_layout import lightmap_layout
from ...kernels.sky import SkyPatches, enu_to_world, patch_layout
from .patch_visibility import PAIRS_PER_BATCH, QUANT_LEVELS, traced_rays, visibility_pass_chunk
from .texel_receivers import check_texel_memory, compute_texel_visibility, texel_lightmaps
from .refine import refine, weld_points
from .refined_scene import refine_scene

PRESPLIT_PASSES = 12
"""Most four-way splits of a face larger than max_face_area before tracing (4^12 children at most)."""


def _areas_normals(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    corners = points[triangles]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    double = np.linalg.norm(cross, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        normals = np.where(double[:, None] > 0, cross / double[:, None], 0.0)
    return double / 2, normals


def compute_sky_visibility(tracer, scene: Scene, *, patches: SkyPatches, samples: int = 4,
                           tolerance: float = 0.1, min_area: float = 1e-5, max_level: int = 5,
                           max_face_area: float = 0.0, size_reference: str = "scene",
                           max_triangles: int = 500_000, seed: int = 0, adaptive: bool = True,
                           prims: np.ndarray | None = None, criterion: str = "share", uniform: bool = False,
                           progress=lambda f: None, chunks=None) -> tuple[SkyVisibilityProduct, dict]:
    """Refine the receiver prims adaptively and compute their visibility factors.

    The precompute of Bosch, Besuievsky & Martin, Sec. 3 (Fig. 2) and 4: visibility
    factors per (triangle, sky patch) (Sec. 4.1), then triangles with partial
    visibility, area above ``min_area`` (times the scene diagonal^2, stage
    units^2; with ``size_reference="detail"`` the diagonal of the receivers
    without backdrops, ``geometry.mesh.detail_diagonal``, for this and
    ``max_face_area``) and fewer than ``max_level`` four-way splits below their input
    triangle are split and traced again until nothing splits (Sec. 4.2; here
    all patches at once rather than patch by patch, with the module docstring's
    partial-visibility measure and a conforming longest-edge split).

    ``adaptive=False`` traces the input mesh only; ``uniform=True`` splits every face ``max_level`` times
    instead (the uniform subdivision the adaptive one is compared with).
    ``chunks`` (core.chunks; default: in process on ``tracer``) runs each pass's visibility factors.
    Returns the product and a dict of figures (triangles in/out, iterations, rays).
    """
    chunks = chunks if chunks is not None else SceneChunks(tracer)
    glass = GlassPanes.of_scene(scene)  # panes transmit the sky with their transmittance (glazing.py)
    prims = receiver_prims(scene) if prims is None else np.asarray(prims, np.int32)
    to_world = enu_to_world(scene.up_axis)
    n_patch = len(patches)
    tris = np.flatnonzero(np.isin(scene.tri_prim, prims))
    used, local = np.unique(scene.tri_vertices[tris], return_inverse=True)
    points = scene.points[used].astype(np.float64)
    point_source = used.astype(np.int64)
    weld = weld_points(scene.points[used], scene.point_prim[used])
    triangles = local.reshape(-1, 3).astype(np.int64)
    source = tris.astype(np.int64)
    level = np.zeros(len(tris), np.int64)
    weights = np.broadcast_to(np.eye(3), (len(tris), 3, 3)).copy()  # corners in their source triangle
    # V is kept quantized (uint8) while refining: 1 byte per factor bounds memory on big meshes.
    quantized = np.zeros((len(tris), n_patch), np.uint8)
    exposure = np.zeros(len(tris), np.float64)
    quant_error = 0.0
    score = np.zeros(len(tris), np.float64)
    pending = np.ones(len(tris), bool)
    # size_reference 'detail': a 200 m ground plane around a room does not make every face of the room small
    detail = size_reference == "detail"
    length = detail_diagonal(scene) if detail else scene.diagonal
    area_floor = float(min_area) * length ** 2
    rays = 0
    next_id = 0
    ids = np.zeros(len(tris), np.int64)
    iterations = 0

    def split(marked: np.ndarray):
        """Refine the marked faces, carrying source, level and corner weights to the children."""
        nonlocal points, weld, triangles, source, level, weights
        result = refine(points, triangles, marked, weld=weld)
        points, weld, triangles = result.points, result.weld, result.triangles
        source, level = source[result.parent], level[result.parent] + result.halvings
        weights = np.einsum("tij,tjk->tik", result.corner_weights, weights[result.parent])
        return result

    area_cap = float(max_face_area) * length ** 2
    backdrop = np.isin(scene.tri_prim, backdrop_prims(scene)[0] if detail else [])
    if area_cap > 0:  # large faces first: each (face, patch) pair is judged from `samples` points only
        for _ in range(PRESPLIT_PASSES):  # (not the backdrops': their area is why the length left them out)
            big = (_areas_normals(points, triangles)[0] > area_cap) & ~backdrop[source]
            if not big.any() or len(triangles) >= max_triangles:
                break
            split(big)
        level = np.zeros(len(triangles), np.int64)  # max_level counts splits below the split input face
    if uniform:  # split every face max_level times, then trace once
        for _ in range(max_level):
            split(np.ones(len(triangles), bool))
    if area_cap > 0 or uniform:
        quantized = np.zeros((len(triangles), n_patch), np.uint8)
        exposure = np.zeros(len(triangles), np.float64)
        score = np.zeros(len(triangles), np.float64)
        pending = np.ones(len(triangles), bool)
        ids = np.zeros(len(triangles), np.int64)
    adaptive = adaptive and not uniform
    while True:
        todo = np.flatnonzero(pending)
        ids[todo] = next_id + np.arange(len(todo))
        next_id += len(todo)
        batch = max(1, PAIRS_PER_BATCH // max(n_patch, 1))
        for lo in range(0, len(todo), batch):  # batches bound the float32 temporaries
            part_todo = todo[lo:lo + batch]
            normals = scene.tri_normals[source[part_todo]]
            seeds = (ids[part_todo] % (2 ** 31 - 1)).astype(np.int32)
            q, exposure[part_todo], q_error, score[part_todo] = chunks.map(
                visibility_pass_chunk, (points[triangles[part_todo]].astype(np.float32), normals, seeds),
                patches=patches, to_world=to_world, samples=samples, seed=seed, criterion=criterion, glass=glass)
            quantized[part_todo] = q
            quant_error = max(quant_error, float(q_error.max(initial=0.0)))
            rays += traced_rays(normals, patches, to_world, samples)
        pending[:] = False
        iterations += 1
        progress(min(0.95, 0.1 * iterations))
        if not adaptive:
            break
        areas, _ = _areas_normals(points, triangles)
        if criterion == "paper":  # Sec. 4.2: some patch with 0 < V_ij < 1 sees a projected area above A_min
            marked = (score > 0) & (score * areas > area_floor) & (level < 2 * max_level)
        else:
            marked = (score > tolerance) & (areas > area_floor) & (level < 2 * max_level)
        if not marked.any() or len(triangles) >= max_triangles:
            break
        result = split(marked)
        quantized, exposure, score = quantized[result.parent], exposure[result.parent], score[result.parent]
        ids = ids[result.parent]
        pending = result.changed.copy()

    # Faces grouped by prim, then by source triangle (so by authored face), in refinement order within one.
    order = np.lexsort((source, scene.tri_prim[source]))
    triangles, source, level, weights = triangles[order], source[order], level[order], weights[order]
    point_source = np.concatenate([point_source, np.full(len(points) - len(point_source), -1, np.int64)])
    # The patch quadrature of sum_j V_ij dw_j / pi can exceed 1 by a fraction of a percent on a fully
    # open face; exposure is a share of the sky, so it is clamped to [0, 1].
    quantized, exposure = quantized[order], np.clip(exposure[order], 0.0, 1.0).astype(np.float32)
    areas, _ = _areas_normals(points, triangles)
    product = SkyVisibilityProduct(
        face_points=points, face_vertices=triangles.astype(np.int32),
        face_normals=scene.tri_normals[source].astype(np.float32), face_areas=areas.astype(np.float32),
        face_source=source.astype(np.int32), face_prim=scene.tri_prim[source].astype(np.int32),
        face_face=scene.tri_face[source].astype(np.int32), face_level=level.astype(np.int32),
        face_corner_weights=weights, point_source=point_source,
        visibility=quantized, visibility_scale=1.0 / QUANT_LEVELS, exposure=exposure,
        patches=patches, to_world=to_world, up_axis=scene.up_axis, prims=prims.astype(np.int32),
    )
    stats = {
        "triangles_in": float(len(tris)), "triangles_out": float(len(triangles)),
        "iterations": float(iterations), "rays": float(rays),
        "quantization_error_max": quant_error,
        "visibility_mb": quantized.nbytes / 2 ** 20,
    }
    return product, stats


SKY_CHECK_BATCH = 1 << 18
"""Rays per batch of the applies() check; it stops at the first batch in which a ray escapes."""


def sees_sky(tracer, scene: Scene, directions: np.ndarray) -> bool:
    """Whether any receiver face sees the sky along any patch centre direction (a ray from its
    centroid that escapes the scene's opaque triangles: glazing lets the sky in). Scenes open to the sky
    answer in the first batch."""
    glazing = scene_glazing(scene, tracer)
    tracer = glazing.opaque_tracer if glazing is not None else tracer
    faces = np.flatnonzero(np.isin(scene.tri_prim, receiver_prims(scene)) & (scene.tri_areas > 0))
    corners = scene.points[scene.tri_vertices[faces]].astype(np.float64)
    centroids, normals = corners.mean(axis=1), scene.tri_normals[faces].astype(np.float64)
    per_batch = max(1, SKY_CHECK_BATCH // max(len(directions), 1))
    for lo in range(0, len(faces), per_batch):
        c, n = centroids[lo:lo + per_batch], normals[lo:lo + per_batch]
        face, patch = np.nonzero(n @ directions.T > 0.0)  # only directions above the face's horizon
        if len(face) == 0:
            continue
        origins = c[face] + n[face] * tracer.epsilon
        if not tracer.occluded(origins, directions[patch]).all():
            return True
    return False


class SkyVisibility(Processor):
    name = "sky_visibility"
    version = "3"
    summary = "Per-face sky patch visibility with adaptive crack-free refinement (Bosch et al.)."
    facets = ("geometry", "uvs")
    writes = ("points", "faceVertexCounts", "faceVertexIndices", "orientation",
              "primvars:bake:sourceFace", "primvars:bake:skyVisibility", "primvars:bake:skyExposure", "bake:sky:",
              "bake:lightmap:skyExposure:", "primvars:bake:lightmapST")
    provides = (SkyVisibilityProduct, RefinedScene)

    @dataclass(frozen=True)
    class Params(TextureTargetParams):
        patch_layout: str = param("uniform", "sky patches: uniform (equal solid angle), tregenza (145), "
                                  "reinhart (MF subdivision)", choices=("uniform", "tregenza", "reinhart"))
        patch_count: int = param(256, "number of patches of the uniform layout", low=1, high=65536)
        subdivision: int = param(2, "Reinhart MF subdivision (577 patches for 2)", low=1, high=16)
        samples: int = param(4, "rays per (triangle, patch) pair (rounded to a square)", low=1, high=4096)
        tolerance: float = param(0.1, "refine a face when its partial-visibility share exceeds this",
                                 low=0.0, high=1.0)
        min_area: float = param(1e-5, "smallest face area refined, times the scene diagonal squared",
                                low=0.0, high=1.0)
        max_level: int = param(5, "most four-way splits below an input face", low=0, high=16)
        max_face_area: float = param(1e-3, "faces larger than this, times the scene diagonal squared, are split "
                                     "before tracing, so no large face is judged from a handful of points "
                                     "(0: off)", low=0.0, high=1.0)
        size_reference: str = param("detail", "what min_area and max_face_area are relative to: scene (the stage's "
                                     "diagonal) or detail (the receivers' without backdrops such as a ground plane, "
                                     "which are then not pre-split)", choices=("scene", "detail"))
        max_triangles: int = param(500_000, "stop refining at this many faces (V takes faces x patches bytes)",
                                   low=1)
        criterion: str = param("share", "refinement test: share (cosine-weighted share of the face's sky that is "
                               "partly hidden), any (solid angle of patches with any partial visibility) or "
                               "paper (Bosch et al. Sec. 4.2: some patch partly visible whose projected area "
                               "A cos(theta) exceeds min_area; tolerance unused)",
                               choices=("share", "any", "paper"))
        seed: int = param(0, "random seed (identical results across thread counts)", low=0)

    def applies(self, ctx: Context) -> tuple[bool, str]:
        scene = ctx.scene
        reason = missing_receivers(scene)
        if reason:
            return False, reason
        patches = patch_layout(self.params.patch_layout, count=self.params.patch_count,
                               subdivision=self.params.subdivision)
        if not sees_sky(ctx.tracer, scene, patches.patch_directions @ enu_to_world(scene.up_axis).T):
            return False, "no sky-visible faces (every face is enclosed or faces away from the sky)"
        return True, ""

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        patches = patch_layout(p.patch_layout, count=p.patch_count, subdivision=p.subdivision)
        product, stats = compute_sky_visibility(
            ctx.tracer, scene, patches=patches, samples=p.samples, tolerance=p.tolerance,
            min_area=p.min_area, max_level=p.max_level, max_face_area=p.max_face_area, size_reference=p.size_reference,
            max_triangles=p.max_triangles, seed=p.seed,
            criterion=p.criterion, progress=ctx.progress, chunks=ctx.chunks)
        result = Result(stats=stats)
        refined = None
        if p.target in ("vertex", "both"):
            refined = refine_scene(scene, product.face_points, product.point_source, product.face_vertices,
                                   product.face_source, product.face_corner_weights, with_sources=True)
            self._mesh_outputs(scene, product, refined[0], refined[1], result)
        texels = None
        if p.target in ("texture", "both"):  # with both, on the refined meshes: their UVs fit the meshes written
            laid_out_on = refined[0] if refined is not None else scene
            layout = lightmap_layout(laid_out_on, product.prims, density=p.texel_density,
                                     max_size=p.max_texture_size, device=ctx.device)
            pages = texel_samples(laid_out_on, layout, vertex_normals(
                laid_out_on.points, laid_out_on.tri_vertices, laid_out_on.tri_normals, laid_out_on.tri_areas),
                ctx.device)
            check_texel_memory(laid_out_on, pages, len(patches), density=p.texel_density,
                               max_size=p.max_texture_size)
            texels = compute_texel_visibility(
                ctx.tracer, scene, product, layout, pages, samples=p.samples, seed=p.seed, margin=p.margin,
                denoise=p.denoise, chunks=ctx.chunks,
                refined=(refined[0], refined[2], refined[3]) if refined is not None else None)
            stats["texels"] = float(texels.count)
            stats["rays"] += float(traced_rays(texels.view.face_normals, patches, product.to_world, p.samples))
            result.outputs += texel_lightmaps(scene, texels, "skyExposure", texels.view.exposure, units="fraction",
                                              unit_range=True, with_uvs=True)
            result.messages += layout_messages(scene, texels.layout, p.texel_density)
        result.products[SkyVisibilityProduct] = replace(product, texels=texels, mesh_written=refined is not None)
        ctx.progress(1.0)
        skipped = int((~scene.prim_writable).sum())
        if skipped:
            result.messages.append(f"{skipped} instanced prims occlude but are not refined (read-only in USD)")
        if stats["triangles_out"] >= p.max_triangles:
            result.messages.append(f"refinement stopped at max_triangles={p.max_triangles}")
        return result

    @staticmethod
    def _mesh_outputs(scene: Scene, product: SkyVisibilityProduct, refined: Scene, meshes: list,
                      result: Result) -> None:
        """The vertex target: the refined meshes (the RefinedScene product) and their per-face V and exposure."""
        result.products[RefinedScene] = RefinedScene(refined, product.prims.astype(np.int32))
        result.outputs += list(meshes)
        patches = product.patches
        directions = (patches.patch_directions @ product.to_world.T).astype(np.float32)
        n_patch = len(patches)
        for prim in product.prims:
            path = scene.prim_paths[prim]
            faces = np.flatnonzero(product.face_prim == prim)
            result.outputs.append(Prim(path, api_schemas=("SkyVisibilityAPI",)))
            result.outputs += [
                Primvar(path, "bake:skyVisibility", product.visibility[faces].ravel(), "uchar", "uniform",
                        element_size=n_patch),
                Primvar(path, "bake:skyExposure", product.exposure[faces], "float", "uniform"),
                Primvar(path, "bake:sourceFace", product.face_face[faces], "int", "uniform"),
                Attribute(path, "bake:sky:visibilityScale", float(product.visibility_scale), "float"),
                Attribute(path, "bake:sky:patchCount", n_patch, "int"),
                Attribute(path, "bake:sky:patchLayout", patches.layout, "token"),
                Attribute(path, "bake:sky:subdivision", int(patches.subdivision), "int"),
                Attribute(path, "bake:sky:patchDirections", directions, "float3[]"),
                Attribute(path, "bake:sky:patchSolidAngles", patches.patch_solid_angles.astype(np.float32),
                          "float[]"),
                Attribute(path, "bake:sky:upAxis", scene.up_axis, "token"),
            ]
