"""The texture target's shared steps: the world points a lightmap's texels are baked at, their images with
dilated gutters, and the USD records that describe them on each mesh.

A texel is baked at the point of its owning triangle nearest its centre (``kernels.texels``), with the
normal the vertex path would interpolate there (the area-weighted vertex normals, ``geometry.mesh``,
blended by the point's barycentric weights; the face normal where that blend vanishes or turns away from
the face), and its ray origin from the same rule as every other per-face point (``triangle_origin``).
A processor evaluates its light model at ``TexelSamples.points`` and hands the values to ``page_image``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.records import Attribute, Prim, Primvar, Texture
from ..core.scene import Scene
from .lightmap_layout import GENERATED_UV, LightmapLayout
from .texels import page_texels

LIGHTMAP_API = "LightmapAPI"
"""Our multiple-apply API schema (schemas/schema.usda): instance ``<channel>`` describes one lightmap on a mesh."""


@dataclass(frozen=True)
class TexelSamples:
    """The covered texels of one page and the surface points they are baked at."""

    page: int
    width: int
    height: int
    texel: np.ndarray
    """(N,) int64 flat texel index (row y * width + x; row 0 is v = 0)."""
    triangle: np.ndarray
    """(N,) int64 scene triangle."""
    points: np.ndarray
    """(N, 3) float32 world points (stage units, scene frame)."""
    normals: np.ndarray
    """(N, 3) float32 unit shading normals."""
    corners: np.ndarray
    """(N, 3, 3) float32 the owning triangle's corners (for the ray-origin rule)."""
    weights: np.ndarray
    """(N, 3) float32 barycentric coordinates of each point in its triangle."""


def texel_samples(scene: Scene, layout: LightmapLayout, vertex_normals: np.ndarray,
                  device: str = "cpu") -> list[TexelSamples]:
    """One TexelSamples per page of ``layout`` (module docstring)."""
    samples = []
    order = np.argsort(layout.tri_page, kind="stable")  # one sort: a stage of thousands of meshes has as many pages
    bounds = np.searchsorted(layout.tri_page[order], np.arange(len(layout.page_sizes) + 1))
    for page, (width, height) in enumerate(layout.page_sizes):
        tris = order[bounds[page]:bounds[page + 1]]
        covered = page_texels(layout.tri_uv[tris], width, height, device)
        triangle = tris[covered.triangle]
        weights = covered.weights.astype(np.float64)
        corners = scene.points[scene.tri_vertices[triangle]].astype(np.float64)
        points = np.einsum("nk,nkd->nd", weights, corners)
        blended = np.einsum("nk,nkd->nd", weights, vertex_normals[scene.tri_vertices[triangle]].astype(np.float64))
        face = scene.tri_normals[triangle].astype(np.float64)
        length = np.linalg.norm(blended, axis=1, keepdims=True)
        usable = (length[:, 0] > 1e-6) & (np.einsum("nd,nd->n", blended, face) > 0.0)
        normals = np.where(usable[:, None], blended / np.maximum(length, 1e-30), face)
        samples.append(TexelSamples(page, width, height, covered.texel, triangle, points.astype(np.float32),
                                    normals.astype(np.float32), corners.astype(np.float32), covered.weights))
    return samples


TEXEL_INSET = 1e-3
"""Texel points lit by shadow and gather rays are moved this fraction of the way towards their triangle's
centroid (as radiosity's vertices are): a point on an edge where two meshes meet can sit a rounding error
behind the other, where every ray would start inside it."""


def inset_points(samples: TexelSamples, inset: float = TEXEL_INSET) -> np.ndarray:
    """(N, 3) float32 the samples' points moved ``inset`` of the way towards their triangle's centroid."""
    points = samples.points.astype(np.float64)
    return (points + inset * (samples.corners.astype(np.float64).mean(axis=1) - points)).astype(np.float32)


def dilate(image: np.ndarray, filled: np.ndarray, margin: int) -> np.ndarray:
    """``image`` (H, W, C) with empty texels (``filled`` False) within ``margin`` texels of a filled one set
    to the mean of their filled 8-neighbours, one ring per step (the gutter filling of Blender's bake
    margin, 'extend' mode), so bilinear and mip filtering near a chart's edge read its own values."""
    image = image.astype(np.float32, copy=True)
    filled = filled.copy()
    height, width = filled.shape
    for _ in range(margin):
        total = np.zeros_like(image)
        count = np.zeros(filled.shape, np.float32)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dx == 0 and dy == 0:
                    continue
                target = (slice(max(dy, 0), height + min(dy, 0)), slice(max(dx, 0), width + min(dx, 0)))
                source = (slice(max(-dy, 0), height + min(-dy, 0)), slice(max(-dx, 0), width + min(-dx, 0)))
                weight = filled[source].astype(np.float32)
                total[target] += image[source] * weight[:, :, None]
                count[target] += weight
        grow = ~filled & (count > 0)
        if not grow.any():
            break
        image[grow] = total[grow] / count[grow][:, None]
        filled |= grow
    return image


def page_image(samples: TexelSamples, values: np.ndarray, margin: int, background: float = 0.0, *,
               denoise_meshes: np.ndarray | None = None, hdr: bool = False) -> np.ndarray:
    """(H, W, C) float32 page (row 0 is v = 0) holding ``values`` (N, C) at the samples' texels, gutters
    dilated by ``margin``; texels beyond reach hold ``background``. With ``denoise_meshes`` ((N,) mesh of
    each texel) the page is denoised first (``denoise_page``; ``hdr``: values above 1)."""
    values = np.asarray(values, np.float32).reshape(len(samples.texel), -1)
    image = np.full((samples.height * samples.width, values.shape[1]), background, np.float32)
    image[samples.texel] = values
    filled = np.zeros(samples.height * samples.width, bool)
    filled[samples.texel] = True
    shape = (samples.height, samples.width)
    image = dilate(image.reshape(*shape, -1), filled.reshape(shape), max(margin, DENOISE_APRON if
                                                                        denoise_meshes is not None else 0))
    if denoise_meshes is None:
        return image
    clean = denoise_page(image, samples, denoise_meshes, hdr=hdr).reshape(-1, values.shape[1])
    image = np.full((samples.height * samples.width, values.shape[1]), background, np.float32)
    image[samples.texel] = clean[samples.texel]
    return dilate(image.reshape(*shape, -1), filled.reshape(shape), margin)


DENOISE_APRON = 4
"""Texels the gutters are filled to before denoising, at least: the filter then never sees the background
next to a chart (what darkens the seams of denoised bakes)."""


def denoise_page(image: np.ndarray, samples: TexelSamples, meshes: np.ndarray, *, hdr: bool) -> np.ndarray:
    """``image`` (H, W, C) denoised by Intel Open Image Denoise (the ``pyoidn`` package; its RT filter) with two
    noise-free guides that keep charts apart: the texels' shading normals, and an albedo that is a colour per
    mesh (charts of different meshes packed side by side never blend; charts of one mesh meet at creases,
    where the normals differ). Gutters must already be filled (``page_image``)."""
    import pyoidn

    height, width, channels = image.shape
    normal = np.zeros((height * width, 3), np.float32)
    normal[samples.texel] = samples.normals
    albedo = np.full((height * width, 3), 0.5, np.float32)
    codes = np.asarray(meshes, np.uint64) * np.uint64(2654435761)
    albedo[samples.texel] = np.stack([(codes >> np.uint64(s)) % np.uint64(256) for s in (0, 8, 16)], axis=1) / 255.0
    filled = np.zeros(height * width, bool)
    filled[samples.texel] = True
    grown = dilate(np.concatenate([normal, albedo], axis=1).reshape(height, width, 6), filled.reshape(height, width),
                   DENOISE_APRON)
    colour = image if channels == 3 else np.repeat(image[:, :, :1], 3, axis=2)
    out = pyoidn.denoise(np.ascontiguousarray(colour, np.float32), np.ascontiguousarray(grown[:, :, 3:]),
                         np.ascontiguousarray(grown[:, :, :3]), hdr=hdr, clean_aux=True)
    out = np.asarray(out, np.float32)
    return out if channels == 3 else out.mean(axis=2, keepdims=True)


def image_file_pixels(image: np.ndarray, dtype=np.float16) -> np.ndarray:
    """A page (row 0 is v = 0) as file pixels (row 0 at the top, as image files and UsdUVTexture's st
    convention want): float16 or float32 for EXR, uint16 (values in [0, 1]) for PNG."""
    flipped = np.ascontiguousarray(image[::-1])
    if dtype == np.uint16:
        return np.round(np.clip(flipped, 0.0, 1.0) * 65535.0).astype(np.uint16)
    return flipped.astype(dtype)


def lightmap_records(scene: Scene, layout: LightmapLayout, channel: str, files: list[str], *, channels: str,
                     units: str, with_uvs: bool = True, time: float | None = None) -> list:
    """Records describing lightmap ``channel`` on every mesh of ``layout`` (``LightmapAPI:<channel>``: the
    page's file, the UV primvar, the image channels and the units), plus each generated UV set
    (``with_uvs``: a processor writing several channels writes them once). With ``time`` (a time code) the
    file is that time's sample, so a channel holds an image per time; the rest is written at time code 0 only."""
    records: list = []
    for mesh in layout.meshes:
        path = scene.prim_paths[mesh.prim]
        prefix = f"bake:lightmap:{channel}"
        file = Attribute(path, f"{prefix}:file", files[mesh.page], "asset", time=time)
        if time:
            records.append(file)
            continue
        records += [
            Prim(path, api_schemas=(f"{LIGHTMAP_API}:{channel}",)),
            file,
            Attribute(path, f"{prefix}:uv", mesh.uv_name, "token", uniform=True),
            Attribute(path, f"{prefix}:channels", channels, "token", uniform=True),
            Attribute(path, f"{prefix}:units", units, "token", uniform=True),
        ]
        if with_uvs and mesh.prim in layout.generated:
            records.append(Primvar(path, GENERATED_UV, layout.generated[mesh.prim], "texCoord2f", "faceVarying"))
    return records


def layout_messages(scene: Scene, layout: LightmapLayout, density: float) -> list[str]:
    """One line per mesh: which UVs its lightmap uses and why, what the page gives it, what was skipped."""
    lines = []
    for mesh in layout.meshes:
        width, height = layout.page_sizes[mesh.page]
        line = (f"{scene.prim_paths[mesh.prim]}: lightmap on primvars:{mesh.uv_name} ({mesh.reason}), "
                f"page {mesh.page} ({width}x{height})")
        if mesh.density < 0.99 * density:
            line += f", {mesh.density:.3g} texels/m (the size cap lowered it from {density:g})"
        if mesh.degenerate:
            line += f", {mesh.degenerate} triangles with no UV area skipped"
        if mesh.split_faces:
            line += f", {mesh.split_faces} faces cut across charts baked at their first triangle's UVs"
        lines.append(line)
    return lines


HALF_LIMIT = 6.0e4
"""Largest value a half-float lightmap holds (half's maximum is 65504): pages beyond it are written in float."""


def texture_record(name: str, image: np.ndarray, *, eight_bit_range: bool) -> Texture:
    """The Texture record of a page: 16-bit PNG for values in [0, 1] (``eight_bit_range``), else half EXR
    (float EXR when a value is beyond half's range, e.g. illuminance in lux)."""
    if eight_bit_range:
        return Texture(f"{name}.png", image_file_pixels(image, np.uint16))
    wide = image.size and float(np.nanmax(np.abs(image))) > HALF_LIMIT
    return Texture(f"{name}.exr", image_file_pixels(image, np.float32 if wide else np.float16))
