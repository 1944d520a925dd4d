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

Texture target (``target=texture`` or ``both``; ``kernels.lightmap_layout`` and ``kernels.lightmap_bake``): AO
per lightmap texel at the texel's point of its triangle, on the mesh's lightmap UVs (its own, or generated as
faceVarying ``primvars:bake:lightmapST``), one 16-bit PNG per page (linear, row 0 at the top) with gutters
dilated by ``margin``; ``LightmapAPI:ao`` on each mesh names the file, the UV primvar, the channel (r) and the
units; each bound UsdPreviewSurface gets ``inputs:occlusion`` from a UsdUVTexture of the page read through a
UsdPrimvarReader_float2 of those UVs; a material bound to meshes on different pages gets a variant per page
(a sibling that references it) and those meshes are bound to theirs. No mesh's geometry is changed.

Instanced receivers (``instances``; ``processors/occlusion/instances.py``): USD holds no per-vertex data on an
instance, so with ``mean`` (the default) each instance gets the area-weighted mean AO of its
surface: ``primvars:bake:ao`` (constant) on a native instance's root prim, which its meshes
inherit, with the same value as the scalar ``userProperties:bake:ao`` (Blender 5's USD import drops inherited
constant primvars but makes this the instance's custom property ``bake:ao``), and ``primvars:bake:ao`` (vertex: one value per instance, 1 for masked rows) on a
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

from ...core import Attribute, Context, Prim, Primvar, Processor, Relationship, Result, TextureTargetParams, param
from .products import AmbientOcclusionProduct
from ...core.scene import Scene
from .instances import instanced_receivers, per_instance_means
from ...geometry.mesh import NO_RECEIVERS, face_means, receiver_prims, vertex_inward, vertex_normals
from ...kernels.lightmap_bake import layout_messages, lightmap_records, page_image, texel_samples, texture_record
from ...kernels.lightmap_layout import lightmap_layout
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


@wp.kernel
def texel_ao_kernel(start: int, rays: AORays, first: int, points: wp.array(dtype=wp.vec3),
                    normals: wp.array(dtype=wp.vec3), corners: wp.array(dtype=wp.vec3), ao: wp.array(dtype=float)):
    """AO (dimensionless, [0, 1]) at texel point i of its triangle (corners 3i .. 3i + 2) around its unit
    shading normal by ``occlusion_at`` (Zhukov et al. 1998 integral, PBRT 3rd ed. Section 13.6.3 rays), from
    ``triangle_origin`` (the per-face origin rule); point i's rays are seeded by (seed, first + i)."""
    i = start + wp.tid()
    a = corners[3 * i]
    b = corners[3 * i + 1]
    c = corners[3 * i + 2]
    face = wp.cross(b - a, c - a)
    n = normals[i]
    if wp.length(n) < 0.5 or wp.length(face) <= 0.0:
        ao[i] = 1.0
        return
    origin = triangle_origin(rays.scene, a, b, c, points[i], wp.normalize(face), rays.epsilon)
    ao[i] = occlusion_at(rays, origin, ao_point(rays, n, first + i))


def texel_ao_chunk(tracer, first: int, points: np.ndarray, normals: np.ndarray, corners: np.ndarray, *,
                   samples: int, max_distance: float, seed: int) -> np.ndarray:
    """(N,) float32 AO at texel points first .. first + N - 1 (texel_ao_kernel) given their (N, 3) points,
    unit shading normals and (N, 3, 3) triangle corners: one chunk (core.chunks)."""
    rays = ao_rays(tracer.scene, samples=samples, max_distance=max_distance, epsilon=tracer.epsilon, seed=seed,
                   device=tracer.device)
    flat = np.ascontiguousarray(corners, np.float32).reshape(-1, 3)
    return launch_ao(tracer, texel_ao_kernel, len(points), rays, [
        int(first), tracer.array(np.ascontiguousarray(points, np.float32), wp.vec3),
        tracer.array(np.ascontiguousarray(normals, np.float32), wp.vec3), tracer.array(flat, wp.vec3)])


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
    facets = ("geometry", "uvs")
    follows_refinement = True
    writes = ("primvars:bake:ao", "primvars:bake:aoFace", "inputs:occlusion", "bake:lightmap:ao:",
              "primvars:bake:lightmapST", "material:binding", "userProperties:bake:ao")
    provides = (AmbientOcclusionProduct,)

    @dataclass(frozen=True)
    class Params(TextureTargetParams):
        samples: int = param(256, "rays per point (rounded to a square for stratification)", low=1, high=65536)
        max_distance: float = param(math.inf, "hits farther than this (stage units) do not occlude", low=0.0)
        per_face: bool = param(False, "also write per-face AO as primvars:bake:aoFace (uniform)")
        connect_occlusion: bool = param(False, "vertex target: wire bake:ao into each bound UsdPreviewSurface "
                                        "inputs:occlusion (the texture target always wires its texture)")
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
        vertex_target = p.target in ("vertex", "both")
        vertex_prims = np.concatenate([receivers, instanced]) if vertex_target else instanced
        point_ids = np.flatnonzero(np.isin(scene.point_prim, vertex_prims))
        ao_points = np.ones(scene.num_points, np.float32)
        shares = self._progress_shares(p, len(point_ids))
        ctx.progress(0.0)
        inward = vertex_inward(scene.points, scene.tri_vertices, normals)
        ao_points[point_ids] = ctx.chunks.map(
            vertex_ao_chunk, (scene.points[point_ids], normals[point_ids], inward[point_ids]),
            progress=lambda f: ctx.progress(shares[0] * f), samples=p.samples, max_distance=p.max_distance,
            seed=p.seed)
        ctx.progress(shares[0])

        result = Result(products={AmbientOcclusionProduct: AmbientOcclusionProduct(ao_points)})
        rays_per_point = strata_for(p.samples) ** 2
        rays = len(point_ids) * rays_per_point
        if vertex_target:
            for prim in receivers:
                result.outputs.append(Primvar(scene.prim_paths[prim], "bake:ao", ao_points[scene.prim_points(prim)],
                                              "float", "vertex"))
        if p.per_face:
            self._per_face(scene, p, ctx, receivers, result, shares)
            rays += int(np.isin(scene.tri_prim, receivers).sum()) * rays_per_point
        if p.target in ("texture", "both"):
            rays += self._textures(scene, p, ctx, receivers, normals, result, shares) * rays_per_point
        elif p.connect_occlusion:
            result.outputs.extend(occlusion_network(scene, receivers))
        ctx.progress(1.0)
        if len(instanced):
            self._instances(scene, p, instanced, ao_points, result)
        result.stats["rays"] = float(rays)
        skipped = len(instanced_receivers(scene)) if p.instances == "skip" else 0
        if skipped:
            result.messages.append(f"{skipped} instanced meshes occlude but receive no AO (instances=skip)")
        return result

    @staticmethod
    def _progress_shares(p, vertex_points: int) -> tuple[float, float, float]:
        """Where each pass ends on the progress bar: vertices, faces, texels."""
        passes = [vertex_points > 0, p.per_face, p.target in ("texture", "both")]
        ends, done = [], 0.0
        for active in passes:
            done += 1.0 / max(sum(passes), 1) if active else 0.0
            ends.append(done)
        return ends[0], ends[1], ends[2]

    @staticmethod
    def _textures(scene: Scene, p, ctx: Context, receivers: np.ndarray, normals: np.ndarray, result: Result,
                  shares: tuple) -> int:
        """The texture target: AO per lightmap texel, one 16-bit PNG per page, described on each mesh
        (``LightmapAPI:ao``) and wired into its UsdPreviewSurface's occlusion. Returns the texels baked."""
        layout = lightmap_layout(scene, receivers, density=p.texel_density, max_size=p.max_texture_size,
                                 device=ctx.device)
        pages = texel_samples(scene, layout, normals, ctx.device)
        total = sum(len(page.texel) for page in pages)
        files, first = [], 0
        for page in pages:
            done = first
            values = ctx.chunks.map(
                texel_ao_chunk, (page.points, page.normals, page.corners),
                progress=lambda f: ctx.progress(shares[1] + (shares[2] - shares[1]) * (done + f * len(page.texel))
                                                / max(total, 1)),
                samples=p.samples, max_distance=p.max_distance, seed=p.seed) if len(page.texel) else np.zeros(0)
            first += len(page.texel)
            meshes = scene.tri_prim[page.triangle] if p.denoise else None
            texture = texture_record(f"ao_lightmap_{page.page}",
                                     page_image(page, values, p.margin, 1.0, denoise_meshes=meshes),
                                     eight_bit_range=True)
            result.outputs.append(texture)
            files.append(texture.path)
        result.outputs.extend(lightmap_records(scene, layout, "ao", files, channels="r", units="fraction"))
        wiring, notes = occlusion_texture_network(scene, layout, files)
        result.outputs.extend(wiring)
        result.messages.extend(layout_messages(scene, layout, p.texel_density) + notes)
        result.stats["texels"] = float(total)
        return total

    @staticmethod
    def _instances(scene: Scene, p, instanced: np.ndarray, ao_points: np.ndarray, result: Result) -> None:
        """Per-instance means (module docstring)."""
        means = per_instance_means(scene, ao_points, instanced, fill=1.0)
        for root, value in means.native.items():
            result.outputs.append(Primvar(root, "bake:ao", np.array([value], np.float32), "float", "constant"))
            # a scalar user property too: DCCs that drop inherited constant primvars import it (Blender 5: the
            # instance empty's custom property "bake:ao", read per instance by an Instancer attribute node)
            result.outputs.append(Attribute(root, "userProperties:bake:ao", float(value), "float", custom=True))
        for instancer, values in means.instancers.items():
            result.outputs.append(Primvar(instancer, "bake:ao", values, "float", "vertex"))
        if means.native:
            result.messages.append(f"{len(means.native)} native instances: per-instance mean AO as constant "
                                   f"primvars:bake:ao and float userProperties:bake:ao on their roots "
                                   f"(--deinstance for per-vertex AO)")
        for instancer, values in means.instancers.items():
            result.messages.append(f"{instancer}: per-instance mean AO of its {len(values)} instances as "
                                   f"primvars:bake:ao (one value per instance)")

    @staticmethod
    def _per_face(scene: Scene, p, ctx: Context, receivers: np.ndarray, result: Result, shares: tuple) -> None:
        tris = np.flatnonzero(np.isin(scene.tri_prim, receivers))
        tri_ao = ctx.chunks.map(face_ao_chunk, (scene.points[scene.tri_vertices[tris]], scene.tri_normals[tris]),
                                progress=lambda f: ctx.progress(shares[0] + (shares[1] - shares[0]) * f),
                                samples=p.samples,
                                max_distance=p.max_distance, seed=p.seed)
        for prim in receivers:
            mine = scene.tri_prim[tris] == prim
            values = face_means(tri_ao[mine], scene.tri_areas[tris][mine], scene.tri_face[tris][mine],
                                int(scene.prim_face_count[prim]))
            result.outputs.append(Primvar(scene.prim_paths[prim], "bake:aoFace", values, "float", "uniform"))


def occlusion_network(scene: Scene, receivers: np.ndarray) -> list:
    """Records for a UsdPrimvarReader_float reading bake:ao into each bound surface's inputs:occlusion."""
    records: list = []
    surfaces = sorted({surface for prim in receivers for _, surface in bound_surfaces(scene, prim)})
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


def occlusion_texture_network(scene: Scene, layout, files: list[str]) -> tuple[list, list[str]]:
    """Records wiring each mesh's AO page into its bound UsdPreviewSurface's inputs:occlusion (a UsdUVTexture
    read through a UsdPrimvarReader_float2 of its lightmap UVs), and a line per material they vary.

    A material whose meshes all share one page and UV set is wired where it is. One bound to meshes on
    several pages (or UV sets) gets a variant per page, a sibling ``<material>_bakeAo<k>`` that references it
    (so it is the same material but for the occlusion input), and those meshes are bound to their variant
    in the bake layer. Materials bound to a mesh's GeomSubsets are wired alike (a variant is then bound to
    the subset)."""
    records: list = []
    notes: list[str] = []
    by_surface: dict[str, dict[tuple[str, str], list[str]]] = {}
    for mesh in layout.meshes:
        for target, surface in bound_surfaces(scene, mesh.prim):
            by_surface.setdefault(surface, {}).setdefault((files[mesh.page], mesh.uv_name), []).append(target)
    for surface, uses in sorted(by_surface.items()):
        material, shader = surface.rsplit("/", 1)
        if len(uses) == 1:
            (file, uv_name), = uses
            records += _occlusion_shaders(material, f"{material}/{shader}", file, uv_name)
            continue
        for k, ((file, uv_name), targets) in enumerate(sorted(uses.items())):
            variant = f"{material}_bakeAo{k}"
            records.append(Prim(variant, "Material", references=(material,)))
            records += _occlusion_shaders(variant, f"{variant}/{shader}", file, uv_name)
            records += [Relationship(target, "material:binding", (variant,)) for target in sorted(set(targets))]
        notes.append(f"{material}: bound to meshes on {len(uses)} AO lightmaps: one variant each "
                     f"({material}_bakeAo0..{len(uses) - 1}, referencing it), those meshes (or subsets) bound to "
                     f"theirs")
    return records, notes


def bound_surfaces(scene: Scene, prim: int) -> list[tuple[str, str]]:
    """(binding prim, UsdPreviewSurface path) of each material bound to the mesh: its own binding, then its
    material-bound GeomSubsets'."""
    out = [(scene.prim_paths[prim], scene.prim_surface[prim])] if scene.prim_surface[prim] else []
    return out + list(scene.prim_subset_surfaces[prim] if scene.prim_subset_surfaces is not None else ())


def _occlusion_shaders(material: str, surface: str, file: str, uv_name: str) -> list:
    """A UsdPrimvarReader_float2 of ``uv_name`` and a UsdUVTexture of ``file`` in ``material``, its red channel
    connected to ``surface``'s inputs:occlusion."""
    reader, texture = f"{material}/bakeLightmapUV", f"{material}/bakeAoTexture"
    return [
        Prim(reader, "Shader"),
        Attribute(reader, "info:id", "UsdPrimvarReader_float2", "token", uniform=True),
        Attribute(reader, "inputs:varname", uv_name, "string"),
        Attribute(reader, "outputs:result", None, "float2"),
        Prim(texture, "Shader"),
        Attribute(texture, "info:id", "UsdUVTexture", "token", uniform=True),
        Attribute(texture, "inputs:file", file, "asset"),
        Attribute(texture, "inputs:sourceColorSpace", "raw", "token"),
        Attribute(texture, "inputs:wrapS", "repeat", "token"),
        Attribute(texture, "inputs:wrapT", "repeat", "token"),
        Attribute(texture, "inputs:fallback", (1.0, 1.0, 1.0, 1.0), "float4"),
        Attribute(texture, "inputs:st", None, "float2", connect_to=f"{reader}.outputs:result"),
        Attribute(texture, "outputs:r", None, "float"),
        Attribute(surface, "inputs:occlusion", None, "float", connect_to=f"{texture}.outputs:r"),
    ]
