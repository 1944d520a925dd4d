"""Which UVs a mesh's lightmap uses, and the pages (textures) they fill: the texture target's layout.

Per receiver mesh, in this order (``MeshLightmap.reason`` says which and why):

1. its dedicated lightmap UV set (``Scene.prim_lightmap_uv``: ``st1``, ``lightmapST``, ...) as authored;
   one that spans several UDIM tiles is refused (``LightmapError``; extraction leaves out sets with NaN);
2. else its ``st`` when that lies in one tile and overlaps itself on under ``OVERLAP_LIMIT`` of its texels
   (mirrored or stacked shells share texels, so they cannot hold a lightmap);
3. else a generated layout: xatlas (Young, *xatlas*, after Levy et al.'s LSCM charts and a skyline
   packer) charts every such mesh and packs them into shared pages, written as the faceVarying
   ``primvars:bake:lightmapST``.

Page size: a mesh's own UV page holds ``density`` texels per metre of its surface (``metersPerUnit``
respected), square, capped at ``max_size`` (the bake says where the cap lowered the density); generated
pages are one atlas of at most ``max_size`` texels a side each.

This module sits with the kernels because it measures UV overlap with the texel rasterizer
(``kernels.texels``); it holds no Warp code of its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import StageError
from ..core.scene import Scene
from .texels import degenerate_uv_triangles, overlap_share

OVERLAP_LIMIT = 1e-3
"""Largest share of an ``st`` set's texels covered twice that still counts as not overlapping (rounding
where shells touch)."""
OVERLAP_GRID = 1024
"""Side of the grid over [0, 1]^2 the overlap share is measured on (at most: the page size if smaller)."""
GENERATED_UV = "bake:lightmapST"
"""The primvar a generated layout is written as (faceVarying texCoord2f)."""
PACK_PADDING = 2
"""Texels between generated charts, so bilinear filtering of one chart never reads another."""
MIN_PAGE = 8
MAX_TEXELS = 1 << 26
"""Most texels the pages of one bake may hold (four 4096 x 4096 pages): baking a texel holds ~250 bytes of
temporaries (its point, normal, triangle, weights), so this bounds a bake to a few GB; more is refused before
any ray, naming the pages and the parameters to lower."""


class LightmapError(StageError):
    """A mesh's UVs cannot hold a lightmap and cannot be replaced (names the prim, the primvar and why)."""


@dataclass(frozen=True)
class MeshLightmap:
    """How one receiver mesh's lightmap is laid out."""

    prim: int
    source: str
    """'lightmap' (its dedicated set), 'st' (its main set) or 'generated'."""
    uv_name: str
    """The primvar a renderer reads the lightmap with."""
    reason: str
    """Why this source, for people."""
    page: int
    overlap: float = math.nan
    """Share of the ``st`` set's texels covered twice (NaN: not measured)."""
    out_of_tile: float = math.nan
    """Share of the ``st`` set's UV area outside its tile (NaN: not measured)."""
    degenerate: int = 0
    """Triangles with no UV area: they get no texels."""
    split_faces: int = 0
    """Generated layouts: authored faces whose triangles xatlas put in different charts (the faceVarying
    primvar holds one UV per face corner, so the later triangles of such a face are baked at the first's UVs)."""
    density: float = math.nan
    """Texels per metre the page gives this mesh (lower than asked where the size cap applied)."""


@dataclass(frozen=True)
class LightmapLayout:
    tri_uv: np.ndarray
    """(T, 3, 2) float32 page UV of each receiver triangle's corners, in [0, 1]; NaN for other triangles."""
    tri_page: np.ndarray
    """(T,) int32 page of each triangle, -1 for triangles that are not baked."""
    page_sizes: list[tuple[int, int]]
    """(width, height) texels of each page."""
    meshes: list[MeshLightmap]
    generated: dict[int, np.ndarray] = field(default_factory=dict)
    """prim -> (face-vertex slots, 2) float32 values of its faceVarying ``bake:lightmapST``."""


def lightmap_layout(scene: Scene, receivers: np.ndarray, *, density: float, max_size: int,
                    device: str = "cpu") -> LightmapLayout:
    """The layout of every receiver prim's lightmap (module docstring). ``density``: texels per metre."""
    tri_uv = np.full((scene.num_triangles, 3, 2), np.nan, np.float32)
    tri_page = np.full(scene.num_triangles, -1, np.int32)
    pages: list[tuple[int, int]] = []
    meshes: list[MeshLightmap] = []
    to_generate: list[tuple[int, str]] = []
    metres = scene.meters_per_unit
    prim_triangles = triangles_by_prim(scene)
    for prim in (int(p) for p in receivers):
        tris = prim_triangles(prim)
        world_area = float(scene.tri_areas[tris].astype(np.float64).sum()) * metres * metres
        own = _own_uvs(scene, prim, tris, world_area, density, max_size, device)
        if isinstance(own, str):
            to_generate.append((prim, own))
            continue
        uvs, source, name, size, overlap, out_of_tile = own
        tri_uv[tris], tri_page[tris] = uvs, len(pages)
        degenerate = int(degenerate_uv_triangles(uvs, size, size).sum())
        meshes.append(MeshLightmap(prim, source, name, _kept_reason(source, name, overlap), len(pages), overlap,
                                   out_of_tile, degenerate, density=_page_density(uvs, size, world_area)))
        pages.append((size, size))
    generated = _generate(scene, to_generate, density, max_size, tri_uv, tri_page, pages, meshes, prim_triangles)
    total = sum(width * height for width, height in pages)
    if total > MAX_TEXELS:
        raise LightmapError(scene.source or "the stage", "", f"its lightmaps would hold {total:,} texels on "
                            f"{len(pages)} pages (at most {MAX_TEXELS:,}); lower texel_density ({density:g}) or "
                            f"max_texture_size ({max_size}), or bake fewer meshes")
    return LightmapLayout(tri_uv, tri_page, pages, meshes, generated)


def triangles_by_prim(scene: Scene):
    """A function prim -> its triangle indices (ascending), from one stable sort: a stage of thousands of prims
    does not scan every triangle once per prim."""
    order = np.argsort(scene.tri_prim, kind="stable")
    bounds = np.searchsorted(scene.tri_prim[order], np.arange(len(scene.prim_paths) + 1))
    return lambda prim: order[bounds[prim]:bounds[prim + 1]]


def _own_uvs(scene: Scene, prim: int, tris: np.ndarray, world_area: float, density: float, max_size: int,
             device: str):
    """(uvs moved into [0, 1], source, primvar, page size, overlap, out-of-tile share) of the prim's own set
    a lightmap can use, else the reason it cannot (a str: the mesh gets a generated layout)."""
    path = scene.prim_paths[prim]
    lightmap_name = scene.prim_lightmap_uv[prim]
    if lightmap_name:
        uvs = scene.tri_lightmap_uv[tris]
        tiles = _tiles(uvs)
        if len(tiles) > 1:
            raise LightmapError(path, f"primvars:{lightmap_name}",
                                f"spans {len(tiles)} UDIM tiles; a lightmap set must lie in one tile (pack it "
                                f"into one, or remove it to let usdbake generate a layout)")
        uvs = uvs - np.array(tiles[0], np.float32)
        size = _page_size(uvs, world_area, density, max_size)
        return uvs, "lightmap", lightmap_name, size, math.nan, 0.0
    st_name = scene.prim_st[prim]
    if not st_name:
        return "it has no UVs"
    uvs = scene.tri_st[tris]
    tiles = _tiles(uvs)
    if len(tiles) > 1:
        return f"primvars:{st_name} spans {len(tiles)} UDIM tiles"
    uvs = uvs - np.array(tiles[0], np.float32)
    out_of_tile = _out_of_tile_share(uvs)
    if out_of_tile > 0.0:
        return f"primvars:{st_name} has {out_of_tile:.1%} of its area outside its tile"
    size = _page_size(uvs, world_area, density, max_size)
    grid = min(size, OVERLAP_GRID)
    overlap = overlap_share(uvs, grid, grid, device)
    if overlap > OVERLAP_LIMIT:
        return f"primvars:{st_name} overlaps itself on {overlap:.1%} of its texels"
    return uvs, "st", st_name, size, overlap, out_of_tile


def _kept_reason(source: str, name: str, overlap: float) -> str:
    if source == "lightmap":
        return f"its lightmap UV set primvars:{name}"
    return f"primvars:{name} lies in one tile and does not overlap ({overlap:.2%} of texels covered twice)"


def _tiles(uvs: np.ndarray) -> list[tuple[int, int]]:
    """The integer (u, v) tiles the triangles' centroids lie in, sorted."""
    tiles = np.floor(uvs.astype(np.float64).mean(axis=1)).astype(np.int64)
    return [tuple(t) for t in np.unique(tiles.reshape(-1, 2), axis=0)] or [(0, 0)]


def _uv_areas(uvs: np.ndarray) -> np.ndarray:
    u = uvs.astype(np.float64)
    return 0.5 * np.abs((u[:, 1, 0] - u[:, 0, 0]) * (u[:, 2, 1] - u[:, 0, 1])
                        - (u[:, 1, 1] - u[:, 0, 1]) * (u[:, 2, 0] - u[:, 0, 0]))


def _out_of_tile_share(uvs: np.ndarray) -> float:
    """Share of the UV area of triangles with a corner outside [0, 1]^2 (past rounding)."""
    areas = _uv_areas(uvs)
    outside = ((uvs < -1e-6) | (uvs > 1.0 + 1e-6)).any(axis=(1, 2))
    total = areas.sum()
    return float(areas[outside].sum() / total) if total > 0 else 0.0


def _page_size(uvs: np.ndarray, world_area: float, density: float, max_size: int) -> int:
    """Side of a square page that gives ``density`` texels per metre over the set's UV area."""
    uv_area = float(_uv_areas(uvs).sum())
    if uv_area <= 0.0 or world_area <= 0.0:
        return MIN_PAGE
    return int(min(max(math.ceil(density * math.sqrt(world_area / uv_area)), MIN_PAGE), max_size))


def _page_density(uvs: np.ndarray, size: int, world_area: float) -> float:
    uv_area = float(_uv_areas(uvs).sum())
    return size * math.sqrt(uv_area / world_area) if world_area > 0 else math.nan


def _generate(scene: Scene, prims: list[tuple[int, str]], density: float, max_size: int, tri_uv: np.ndarray,
              tri_page: np.ndarray, pages: list, meshes: list, prim_triangles) -> dict[int, np.ndarray]:
    """Chart and pack ``prims`` with xatlas into pages after ``pages``; fills tri_uv, tri_page, pages and
    meshes; returns each prim's faceVarying values."""
    if not prims:
        return {}
    inputs = []
    for prim, _ in prims:
        tris = prim_triangles(prim)
        slots = scene.tri_corner[tris]
        if (slots < 0).any():  # a Scene not read from USD: every corner its own slot
            slots = np.arange(3 * len(tris)).reshape(-1, 3)
        used, corner_vertex = np.unique(slots, return_inverse=True)
        positions = np.zeros((len(used), 3), np.float32)
        positions[corner_vertex.reshape(-1)] = scene.points[scene.tri_vertices[tris]].reshape(-1, 3)
        inputs.append((tris, slots, used, corner_vertex.reshape(-1, 3), positions))

    texels_per_unit = density * scene.meters_per_unit
    atlas = _pack(inputs, texels_per_unit, resolution=0)
    if max(atlas.width, atlas.height) > max_size:
        atlas = _pack(inputs, texels_per_unit, resolution=max_size)
    first_page = len(pages)
    pages.extend([(int(atlas.width), int(atlas.height))] * int(atlas.atlas_count))
    values: dict[int, np.ndarray] = {}
    for index, ((prim, why), (tris, slots, used, corner_vertex, _)) in enumerate(zip(prims, inputs)):
        vmapping, out_tris, out_uvs = atlas.get_mesh(index)
        vertex_atlas, _ = atlas.get_mesh_vertex_assignment(index)
        slot_uv = np.full((len(used), 2), np.nan, np.float32)
        slot_uv[vmapping] = out_uvs  # the last output vertex of a slot wins
        uvs = slot_uv[corner_vertex]
        split = np.abs(out_uvs[out_tris] - uvs).max(axis=(1, 2)) > 0.0  # triangles not baked at their own chart
        page = first_page + vertex_atlas[out_tris[:, 0]].astype(np.int32)
        tri_uv[tris], tri_page[tris] = uvs, page
        faces = np.unique(scene.tri_face[tris][split])
        slot_count = max(int(scene.prim_corner_count[prim]), int(used.max()) + 1 if len(used) else 0)
        values[prim] = _slot_values(slot_uv, used, slot_count)
        world_area = float(scene.tri_areas[tris].astype(np.float64).sum()) * scene.meters_per_unit ** 2
        width, height = pages[int(page[0])] if len(page) else (MIN_PAGE, MIN_PAGE)
        achieved = math.sqrt(float(_uv_areas(uvs).sum()) * width * height / world_area) if world_area > 0 else math.nan
        meshes.append(MeshLightmap(prim, "generated", GENERATED_UV, f"{why}: generated by xatlas", int(page[0])
                                   if len(page) else first_page, split_faces=len(faces), density=achieved))
    return values


def _pack(inputs: list, texels_per_unit: float, resolution: int):
    import xatlas  # here, not at import: only a generated layout needs it

    atlas = xatlas.Atlas()
    for _, _, _, corner_vertex, positions in inputs:
        atlas.add_mesh(positions, corner_vertex.astype(np.uint32))
    pack = xatlas.PackOptions()
    pack.texels_per_unit = float(texels_per_unit)
    pack.padding = PACK_PADDING
    pack.resolution = int(resolution)
    pack.bilinear = True
    atlas.generate(pack_options=pack)
    return atlas


def _slot_values(slot_uv: np.ndarray, used: np.ndarray, slot_count: int) -> np.ndarray:
    """(slot_count, 2) float32: the UV of every face-vertex slot (0 for slots of skipped faces)."""
    values = np.zeros((slot_count, 2), np.float32)
    values[used] = np.nan_to_num(slot_uv)
    return values
