"""Lightmap texels as daylight receivers: the texture target of sky_visibility, interreflection, daylight and
annual_daylight.

Each covered texel of a receiver's lightmap (``kernels.lightmap_layout``, ``kernels.lightmap_bake``) is baked at
its point x of its owning triangle abc. The daylight chain works on faces (V_ij averages over a face, rays leave
from random points of it), so a texel enters it as a face: the owning triangle shrunk about x by
``TEXEL_INSET``, x + s (abc - x). Every point of that face lies within s of x, inside the owning triangle and
towards its interior (as radiosity's texel points are inset), so each visibility factor, gather ray and sun ray
of the texel starts at x to within 1e-3 of the triangle's size, along its face normal as the per-face path's.
The face is that small, so ``triangle_origin`` always takes its careful branch (``surface_origin`` with the
tangent towards the triangle's centroid): near the owning triangle's edges that is the rule its own points
follow, and elsewhere it adds only a tangential step of the tracer's epsilon. The texels then run through the same kernels and relighting as the refined faces: a
``SkyVisibilityProduct`` whose faces are texels (``TexelReceivers.view``).

Their area, the weight of a texel in area-weighted metrics (sDA, ASE), is its share of the surface: its owning
triangle's area over the number of texels that triangle owns, so the texels' areas sum to the mesh's (but for
triangles too small to own a texel).
"""

from __future__ import annotations

import os

import numpy as np

from ...core.chunks import SceneChunks
from ...core.scene import Scene
from ...kernels.lightmap_bake import TEXEL_INSET, TexelSamples, lightmap_records, page_image, texture_record
from ...kernels.lightmap_layout import LightmapError, LightmapLayout
from .glazing import GlassPanes
from .interreflection import grey
from .patch_visibility import PAIRS_PER_BATCH, visibility_pass_chunk
from .products import SkyVisibilityProduct, TexelReceivers


def receiver_sets(product: SkyVisibilityProduct, interreflection) -> list[tuple]:
    """[(faces, their interreflection product)] the relighting processors evaluate: the refined faces when they
    are written (target vertex or both), then the lightmap texels when there are any (texture or both)."""
    sets = [(product, interreflection)] if product.mesh_written else []
    if product.texels is not None:
        sets.append((product.texels.view, interreflection.texels))
    return sets


def texel_faces(scene: Scene, layout: LightmapLayout, pages: list[TexelSamples]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The texels of ``pages`` as faces (module docstring): (T, 3, 3) float64 inset corners, (T, 3) float32
    face normals of their triangles, (T,) float32 footprint areas, (T,) int64 owning triangles and (T, 3, 3)
    float64 barycentric coordinates of the corners in them."""
    triangle = np.concatenate([page.triangle for page in pages]) if pages else np.zeros(0, np.int64)
    points = np.concatenate([page.points for page in pages]).astype(np.float64) if pages else np.zeros((0, 3))
    corners = scene.points[scene.tri_vertices[triangle]].astype(np.float64)
    inset = points[:, None, :] + TEXEL_INSET * (corners - points[:, None, :])
    owned = np.bincount(triangle, minlength=scene.num_triangles)
    footprint = scene.tri_areas[triangle].astype(np.float64) / np.maximum(owned[triangle], 1)
    weights = np.concatenate([np.repeat(page.weights.astype(np.float64)[:, None, :], 3, axis=1) for page in pages]) \
        if pages else np.zeros((0, 3, 3))
    weights = (1.0 - TEXEL_INSET) * weights + TEXEL_INSET * np.eye(3)[None, :, :]
    return inset, scene.tri_normals[triangle].astype(np.float32), footprint.astype(np.float32), triangle, weights


def texel_lightmaps(scene: Scene, receivers: TexelReceivers, channel: str, values: np.ndarray, *, units: str,
                    unit_range: bool = False, name: str | None = None, time: float | None = None,
                    with_uvs: bool = False) -> list:
    """Records of lightmap ``channel`` from ``values`` (T, C) per texel: one image per page (16-bit PNG for
    values in [0, 1] with ``unit_range``, else half EXR; gutters dilated by the receivers' margin, denoised
    when asked) named ``<name or channel>_lightmap_<page>``, and ``LightmapAPI:<channel>`` on each mesh (the
    file as the sample at ``time``, when given: an image per time)."""
    values = np.asarray(values, np.float32).reshape(receivers.count, -1)
    records, files = [], []
    for page, rows in zip(receivers.pages, receivers.page_slices()):
        meshes = receivers.view.face_prim[rows] if receivers.denoise else None
        image = page_image(page, values[rows], receivers.margin, denoise_meshes=meshes, hdr=not unit_range)
        texture = texture_record(f"{name or channel}_lightmap_{page.page}", image, eight_bit_range=unit_range)
        records.append(texture)
        files.append(texture.path)
    colours = {1: "r", 3: "rgb"}.get(values.shape[1], "r")
    return records + lightmap_records(scene, receivers.layout, channel, files, channels=colours, units=units,
                                      with_uvs=with_uvs, time=time)


def daylight_texel_bytes(texels: int, patches: int, channels: int) -> int:
    """Bytes the daylight chain holds per bake for ``texels`` texels: per texel and patch, V (one byte, and a
    float copy while daylight relights) and the indirect coefficients (a float per colour channel)."""
    return int(texels) * int(patches) * (1 + 4 + 4 * int(channels))


def memory_budget() -> int:
    """Bytes the texels' coefficients may take: half the machine's physical memory."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 2


def check_texel_memory(scene: Scene, pages: list[TexelSamples], patches: int, *, density: float, max_size: int,
                       budget: int | None = None) -> None:
    """Refuse, before any ray, a texture target whose texels' daylight coefficients would not fit
    ``budget`` (default ``memory_budget``): a LightmapError naming the meshes with the most texels (a ground
    plane of 200 m at 32 texels/m is a 4096^2 page: 17M texels, tens of GB of coefficients) and what to change."""
    budget = memory_budget() if budget is None else budget
    owners = np.concatenate([scene.tri_prim[page.triangle] for page in pages]) if pages else np.zeros(0, np.int64)
    channels = 1 if grey(scene.tri_albedo) else 3
    needed = daylight_texel_bytes(len(owners), patches, channels)
    if needed <= budget:
        return
    counts = np.bincount(owners, minlength=len(scene.prim_paths))
    largest = ", ".join(f"{scene.prim_paths[prim]} {counts[prim]:,}" for prim in np.argsort(-counts)[:3]
                        if counts[prim])
    raise LightmapError(scene.source or "the stage", "", (
        f"the daylight texture target's {len(owners):,} texels would hold {needed / 2**30:.1f} GB of daylight "
        f"coefficients ({patches} patches, {channels} colour channel{'s' * (channels > 1)}), more than half "
        f"this machine's memory ({budget / 2**30:.1f} GB); the most texels: {largest}. Mark backdrops such as a "
        f"ground plane bake:skip, or lower sky_visibility.texel_density ({density:g}) or max_texture_size "
        f"({max_size})"))


def compute_texel_visibility(tracer, scene: Scene, product: SkyVisibilityProduct, layout: LightmapLayout,
                             pages: list[TexelSamples], *, samples: int, seed: int, margin: int, denoise: bool,
                             refined: tuple | None = None, chunks=None, progress=lambda f: None) -> TexelReceivers:
    """Sky visibility factors V_ij and exposure of every texel of ``pages`` (Bosch, Besuievsky & Martin,
    Sec. 4.1, as ``sky_visibility`` computes them per face: ``visibility_pass_chunk`` on the texels' inset
    faces), for ``product``'s patch layout, as the receivers the rest of the daylight chain relights.

    ``refined``: (refined Scene, source triangle and corner weights of each of its triangles) when the layout
    was made on the refined meshes (target both: the lightmap UVs must fit the meshes as written); the
    texels' triangles and weights are then carried back to ``scene``'s, which the rest of the chain reads."""
    chunks = chunks if chunks is not None else SceneChunks(tracer)
    laid_out_on = refined[0] if refined is not None else scene
    corners, normals, areas, triangle, weights = texel_faces(laid_out_on, layout, pages)
    if refined is not None:
        _, tri_source, tri_weights = refined
        weights = np.einsum("tik,tkj->tij", weights, tri_weights[triangle])
        triangle = tri_source[triangle]
    count, n_patch = len(triangle), len(product.patches)
    quantized = np.zeros((count, n_patch), np.uint8)
    exposure = np.zeros(count, np.float64)
    ids = (np.arange(count) % (2 ** 31 - 1)).astype(np.int32)
    glass = GlassPanes.of_scene(scene)
    batch = max(1, PAIRS_PER_BATCH // max(n_patch, 1))
    for lo in range(0, count, batch):
        part = slice(lo, min(count, lo + batch))
        quantized[part], exposure[part], _, _ = chunks.map(
            visibility_pass_chunk, (corners[part].astype(np.float32), normals[part], ids[part]),
            progress=lambda f, lo=lo: progress((lo + f * (part.stop - lo)) / max(count, 1)),
            patches=product.patches, to_world=product.to_world, samples=samples, seed=seed, criterion="share",
            glass=glass)
    view = SkyVisibilityProduct(
        face_points=corners.reshape(-1, 3), face_vertices=np.arange(3 * count, dtype=np.int32).reshape(-1, 3),
        face_normals=normals, face_areas=areas, face_source=triangle.astype(np.int32),
        face_prim=scene.tri_prim[triangle].astype(np.int32), face_face=scene.tri_face[triangle].astype(np.int32),
        face_level=np.zeros(count, np.int32), face_corner_weights=weights,
        point_source=np.full(3 * count, -1, np.int64), visibility=quantized,
        visibility_scale=product.visibility_scale, exposure=np.clip(exposure, 0.0, 1.0).astype(np.float32),
        patches=product.patches, to_world=product.to_world, up_axis=product.up_axis, prims=product.prims)
    return TexelReceivers(layout, pages, view, int(margin), bool(denoise))
