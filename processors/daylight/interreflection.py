"""Interreflected daylight: daylight coefficients with bounces, and the ground outside the model.

The direct daylight coefficients are the sky visibility factors V (F, N): face i's irradiance per unit
L_j dw_j of sky patch j. Interreflection adds, for every patch, the irradiance that reaches face i after
1..k diffuse reflections (the indirect daylight coefficients D, same shape as V), so that any sky relights
the total with one more matrix, not a trace per hour (the two-phase method of Tregenza & Waters,
"Daylight coefficients", Lighting Research & Technology 15(2), 1983, with the bounces precomputed):

    E_i = sum_j V_ij w_j  +  sum_j D_ij (w_j + s_j)  +  (pi g_i + D^g_i) L_g  +  E_sun,i

with w_j = L_j dw_j the sky's patch weights, s_j the sun's direct normal irradiance spread over the patches
nearest the sun (as ``gendaymtx`` does; only for the sun's reflected light: its direct light E_sun keeps
exact shadow rays), g_i the face's view of the ground outside the model and L_g = rho_g E_gh / pi that
ground's radiance (``gendaymtx``'s ground: rho_g times the global horizontal irradiance, uniform).

D comes from the sparse face-to-face gather G (``gather.py``) and k bounces,
D = sum_{b=1..k} (G rho)^b V. The outermost bounce is taken face by face, so light reflected from a sun
patch or a window reveal reaches the faces that see it exactly; bounces 2..k run on patches (faces
clustered by prim, facing and a voxel grid; the gather summed over each patch), the radiosity
hierarchy's idea (Hanrahan, Salzman & Aupperle, "A rapid hierarchical radiosity algorithm",
SIGGRAPH 1991): light bounced twice or more varies slowly over a surface. Written here rather than
reusing the radiosity technique's operator because that one is a lossy compressed matrix over its own
patches, built for one light set, while daylight needs exact columns per sky patch.

Parameters: ``usdbake list interreflection`` or docs/processors.md, both generated from ``Params`` below.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ...core import Context, Params, Processor, Result, param
from ...core.scene import Scene
from ...kernels.tracer import Tracer
from .gather import trace_gather
from .glazing import scene_glazing
from .patch_visibility import compute_patch_visibility
from .products import InterreflectionProduct, SkyVisibilityProduct

PATCH_GROWTH = 1.25
"""Voxel edge ratio between the steps of the patch-size search."""


@dataclass(frozen=True)
class TransportFaces:
    """The faces light bounces between: the refined receivers, then the scene's other triangles (instances,
    skipped prims), which reflect but get no output."""

    corners: np.ndarray
    """(F + X, 3, 3) float32 scene frame."""
    normals: np.ndarray
    """(F + X, 3) float32."""
    areas: np.ndarray
    """(F + X,) float64."""
    albedo: np.ndarray
    """(F + X, 3) float32 diffuse reflectance (0 for glass: it transmits, it does not reflect)."""
    prims: np.ndarray
    """(F + X,) int32 prim of each face (the patches never span two prims)."""
    transmittance: np.ndarray
    """(F + X,) float32 visible transmittance (glazing: > 0; it is crossed, never landed on)."""
    extra_triangles: np.ndarray
    """(X,) int64 scene triangle of each extra face."""
    outputs: int
    """F: the faces with results (the refined receivers)."""


def transport_faces(scene: Scene, product: SkyVisibilityProduct) -> TransportFaces:
    """The refined faces of ``product`` followed by the non-degenerate scene triangles no refined face lies in."""
    refined = product.face_points[product.face_vertices].astype(np.float32)
    covered = np.zeros(scene.num_triangles, bool)
    covered[product.face_source] = True
    extra = np.flatnonzero(~covered & (scene.tri_areas > 0))
    transmittance = np.concatenate([scene.tri_transmittance[product.face_source], scene.tri_transmittance[extra]])
    albedo = np.concatenate([scene.tri_albedo[product.face_source], scene.tri_albedo[extra]]).astype(np.float32)
    albedo[transmittance > 0] = 0.0
    return TransportFaces(
        np.concatenate([refined, scene.points[scene.tri_vertices[extra]].astype(np.float32)]),
        np.concatenate([product.face_normals, scene.tri_normals[extra]]).astype(np.float32),
        np.concatenate([product.face_areas, scene.tri_areas[extra]]).astype(np.float64),
        albedo, np.concatenate([product.face_prim, scene.tri_prim[extra]]).astype(np.int32), transmittance, extra,
        product.num_faces)


def cluster_patches(faces: TransportFaces, target: int) -> np.ndarray:
    """(F + X,) int64 patch of each face: faces of one prim, facing the same way (dominant normal axis and
    sign) and with centroids in one cell of a voxel grid, the cell the largest for which there are at least
    ``target`` patches (or every face its own patch when there are fewer faces)."""
    centroids = faces.corners.mean(axis=1).astype(np.float64)
    axis = np.argmax(np.abs(faces.normals), axis=1)
    facing = 2 * axis + (faces.normals[np.arange(len(axis)), axis] < 0)
    if len(centroids) <= target:
        return np.arange(len(centroids), dtype=np.int64)
    low = centroids.min(axis=0)
    edge = max(float(np.linalg.norm(centroids.max(axis=0) - low)), 1e-30)
    while True:
        cells = np.floor((centroids - low) / edge).astype(np.int64)
        keys = np.column_stack([faces.prims, facing, cells])
        _, patch = np.unique(keys, axis=0, return_inverse=True)
        if patch.max() + 1 >= target or edge < 1e-12:
            return patch.ravel().astype(np.int64)
        edge /= PATCH_GROWTH


@dataclass(frozen=True)
class BounceOperator:
    """G restricted to the output rows, and the patch-level operators for bounces 2..k."""

    gather: sp.csr_matrix
    """(F + X, F + X) float32 face-to-face gather."""
    patch_of: sp.csr_matrix
    """(P, F + X) area-weighted mean over each patch's faces."""
    members: sp.csr_matrix
    """(F + X, P) indicator: face k lies in patch q."""
    patch_gather: sp.csr_matrix
    """(P, P) W = patch_of G members: share of patch p's gather landing on patch q."""
    outputs: int

    @classmethod
    def build(cls, gather: sp.csr_matrix, face_patch: np.ndarray, areas: np.ndarray, outputs: int) -> "BounceOperator":
        count = len(face_patch)
        patches = int(face_patch.max()) + 1 if count else 0
        patch_area = np.bincount(face_patch, weights=areas, minlength=patches)
        weight = np.where(patch_area[face_patch] > 0, areas / np.maximum(patch_area[face_patch], 1e-300), 0.0)
        patch_of = sp.csr_matrix((weight.astype(np.float32), (face_patch, np.arange(count))), shape=(patches, count))
        members = sp.csr_matrix((np.ones(count, np.float32), (np.arange(count), face_patch)), shape=(count, patches))
        return cls(gather, patch_of, members, (patch_of @ gather @ members).tocsr(), outputs)

    def indirect(self, direct: np.ndarray, albedo: np.ndarray, bounces: int,
                 rows: sp.csr_matrix | None = None) -> np.ndarray:
        """(F, C) float32 irradiance after 1..``bounces`` reflections of the (F + X, C) ``direct`` irradiance
        off faces of reflectance ``albedo`` (F + X,): sum_{b=1..k} (G rho)^b E0, bounces 2..k on patches.
        ``rows`` ((T, F + X) gather rows of other receivers, e.g. lightmap texels) gathers at those instead:
        their last bounce face by face, as the outputs'."""
        direct = np.asarray(direct, np.float32)
        rows = self.gather[:self.outputs] if rows is None else rows
        out = np.zeros((rows.shape[0], direct.shape[1]), np.float32)
        if bounces <= 0:
            return out
        rho = np.asarray(albedo, np.float32)
        radiosity = rho[:, None] * direct
        out += rows @ radiosity
        if bounces >= 2:
            patch_rho = self.patch_of @ rho
            bounced = self.patch_gather @ (self.patch_of @ radiosity)  # patch irradiance after one bounce
            total = np.zeros_like(bounced)
            for step in range(1, bounces):
                total += bounced
                if step < bounces - 1:
                    bounced = self.patch_gather @ (patch_rho[:, None] * bounced)
            out += (rows @ sp.diags(rho) @ self.members) @ total
        return out


def grey(albedo: np.ndarray) -> bool:
    """Every face reflects the three channels alike (one set of indirect coefficients serves all)."""
    return bool(np.array_equal(albedo[:, 0], albedo[:, 1]) and np.array_equal(albedo[:, 0], albedo[:, 2]))


def compute_interreflection(tracer, scene: Scene, product: SkyVisibilityProduct, *, bounces: int = 5,
                            gather_rays: int = 128, ground_reflectance: float = 0.2, patches: int = 4096,
                            visibility_samples: int = 4, seed: int = 0,
                            progress=lambda f: None) -> tuple[InterreflectionProduct, dict]:
    """Indirect daylight coefficients of every refined face (see the module docstring)."""
    started = time.perf_counter()
    faces = transport_faces(scene, product)
    glazing = scene_glazing(scene, tracer)
    extra_v = np.zeros((len(faces.extra_triangles), len(product.patches)), np.float32)
    if len(faces.extra_triangles):
        extra_v, _ = compute_patch_visibility(glazing.opaque_tracer if glazing else tracer,
                                              faces.corners[faces.outputs:], faces.normals[faces.outputs:],
                                              product.patches, product.to_world, samples=visibility_samples,
                                              seed=seed, tri_ids=faces.extra_triangles.astype(np.int32),
                                              glazing=glazing)
    opaque = np.flatnonzero(faces.transmittance <= 0)  # glass is crossed by the gather, never landed on
    transport = Tracer(faces.corners.reshape(-1, 3), (3 * opaque[:, None] + np.arange(3)).astype(np.int32),
                       device=str(tracer.device), threads=tracer.threads)
    progress(0.1)
    traced = time.perf_counter()
    gather = trace_gather(transport, faces.corners, faces.normals, rays=gather_rays, up=scene.up_vector, seed=seed,
                          glazing=glazing, landing=opaque, progress=lambda f: progress(0.1 + 0.6 * f))
    tracer.rays_cast += transport.rays_cast
    gather_seconds = time.perf_counter() - traced
    operator = BounceOperator.build(gather.matrix, cluster_patches(faces, patches), faces.areas, faces.outputs)
    direct = np.concatenate([product.visibility_float(), extra_v])
    direct = np.column_stack([direct, np.pi * gather.ground_view])  # the ground as one more patch
    texels = product.texels.view if product.texels is not None else None
    texel_gather = None
    if texels is not None:  # the texels gather from the same faces, which carry the bounces
        before = transport.rays_cast
        texel_gather = trace_gather(transport, texels.face_points[texels.face_vertices], texels.face_normals,
                                    rays=gather_rays, up=scene.up_vector, seed=seed + 1, glazing=glazing,
                                    landing=opaque, columns=len(faces.corners),
                                    progress=lambda f: progress(0.6 + 0.1 * f))
        tracer.rays_cast += transport.rays_cast - before
    channels = [0] if grey(faces.albedo) else [0, 1, 2]
    sky_indirect = np.zeros((len(channels), faces.outputs, len(product.patches)), np.float32)
    ground_indirect = np.zeros((len(channels), faces.outputs), np.float32)
    texel_count = texels.num_faces if texels is not None else 0
    texel_sky = np.zeros((len(channels), texel_count, len(product.patches)), np.float32)
    texel_ground = np.zeros((len(channels), texel_count), np.float32)
    for index, channel in enumerate(channels):
        values = operator.indirect(direct, faces.albedo[:, channel], bounces)
        sky_indirect[index], ground_indirect[index] = values[:, :-1], values[:, -1]
        if texel_gather is not None:
            values = operator.indirect(direct, faces.albedo[:, channel], bounces, texel_gather.matrix)
            texel_sky[index], texel_ground[index] = values[:, :-1], values[:, -1]
        progress(0.7 + 0.3 * (index + 1) / len(channels))
    stats = {"gather_rays": float((len(faces.corners) + texel_count) * gather_rays), "gather_s": gather_seconds,
             "transport_faces": float(len(faces.corners)), "patches": float(operator.patch_gather.shape[0]),
             "channels": float(len(channels)), "interreflection_s": time.perf_counter() - started}
    texel_product = None
    if texel_gather is not None:
        texel_product = InterreflectionProduct(bounces, float(ground_reflectance), texel_sky,
                                               (np.pi * texel_gather.ground_view).astype(np.float32), texel_ground)
    return InterreflectionProduct(bounces, float(ground_reflectance), sky_indirect,
                                  (np.pi * gather.ground_view[:faces.outputs]).astype(np.float32),
                                  ground_indirect, texels=texel_product), stats


class Interreflection(Processor):
    name = "interreflection"
    version = "1"
    summary = "Indirect daylight coefficients: sky light after 1..k diffuse bounces, and the ground outside."
    facets = ("geometry", "materials")
    requires = (SkyVisibilityProduct,)
    provides = (InterreflectionProduct,)

    @dataclass(frozen=True)
    class Params(Params):
        bounces: int = param(5, "diffuse reflections of sky and sun light (5: Radiance -ab 6 with a glow sky, "
                             "as IES LM-83; 0: direct light only)", low=0, high=64)
        gather_rays: int = param(128, "gather rays per face (the last bounce is taken face by face)",
                                 low=1, high=65536)
        ground_reflectance: float = param(0.2, "reflectance of the ground outside the model (below the horizon, "
                                          "as gendaymtx); a stage with its own ground hides it", low=0.0, high=1.0)
        patches: int = param(4096, "patches for bounces 2..k (faces clustered by prim, facing and voxel)",
                             low=1, high=1_000_000)
        seed: int = param(0, "random seed of the gather rays", low=0)

    def run(self, ctx: Context) -> Result:
        p = ctx.params
        product, stats = compute_interreflection(
            ctx.tracer, ctx.scene, ctx.products[SkyVisibilityProduct], bounces=p.bounces,
            gather_rays=p.gather_rays, ground_reflectance=p.ground_reflectance, patches=p.patches, seed=p.seed,
            progress=ctx.progress)
        return Result(products={InterreflectionProduct: product}, stats=stats)
