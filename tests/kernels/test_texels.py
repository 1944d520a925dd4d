"""Texel coverage and lightmap layouts, against plain float64 geometry written here (supersampled squares,
shoelace areas), never against the rasterizer's own tests."""

from __future__ import annotations

import numpy as np
import pytest

from usdbake.core.scene import Scene
from usdbake.kernels.lightmap_bake import dilate
from usdbake.kernels.lightmap_layout import GENERATED_UV, LightmapError, lightmap_layout
from usdbake.kernels.texels import overlap_share, page_texels

RNG = np.random.default_rng(7)


def square_touches_triangle(x: int, y: int, tri: np.ndarray, samples: int = 24) -> bool:
    """Whether any of samples^2 points strictly inside texel (x, y)'s square lies inside the triangle
    (texel units, float64)."""
    offsets = (np.arange(samples) + 0.5) / samples
    px, py = np.meshgrid(x + offsets, y + offsets)
    p = np.stack([px.ravel(), py.ravel()], axis=1)
    a, b, c = tri
    def side(u, v):
        return (v[0] - u[0]) * (p[:, 1] - u[1]) - (v[1] - u[1]) * (p[:, 0] - u[0])
    s1, s2, s3 = side(a, b), side(b, c), side(c, a)
    return bool((((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))).any())


def test_every_texel_a_triangle_reaches_is_covered_and_baked_inside_it():
    size = 24
    tris = RNG.random((12, 3, 2)) * 0.9 + 0.05
    covered = page_texels(tris, size, size)
    owner = np.full(size * size, -1)
    owner[covered.texel] = covered.triangle
    assert (covered.weights >= -1e-6).all() and np.allclose(covered.weights.sum(axis=1), 1.0, atol=1e-5)
    for t, tri in enumerate(tris * size):
        for y in range(size):
            for x in range(size):
                if square_touches_triangle(x, y, tri):
                    assert owner[y * size + x] >= 0, f"texel {(x, y)} reaches triangle {t} and is empty"
    # every covered texel's baked point is within the texel's half diagonal of its centre
    centres = np.stack([covered.texel % size + 0.5, covered.texel // size + 0.5], axis=1)
    points = np.einsum("nk,nkd->nd", covered.weights, tris[covered.triangle] * size)
    assert (np.linalg.norm(points - centres, axis=1) <= np.sqrt(0.5) + 1e-4).all()


def test_a_centre_inside_a_triangle_is_baked_at_the_centre():
    tri = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]])
    covered = page_texels(tri, 16, 16)
    x, y = covered.texel % 16 + 0.5, covered.texel // 16 + 0.5
    inside = x + y < 16 - 1e-3
    points = np.einsum("nk,nkd->nd", covered.weights, tri[covered.triangle] * 16)
    np.testing.assert_allclose(points[inside], np.stack([x, y], axis=1)[inside], atol=1e-4)


def test_degenerate_and_nan_uv_triangles_cover_nothing():
    tris = np.array([[[0.1, 0.1], [0.5, 0.5], [0.9, 0.9]], [[np.nan, 0.0], [1.0, 0.0], [0.0, 1.0]]], np.float32)
    assert len(page_texels(tris, 32, 32).texel) == 0


def test_overlap_share_counts_shared_texels_once_and_ignores_shared_edges():
    square = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float64) * 0.8 + 0.1
    assert overlap_share(square, 64, 64) == 0.0
    mirrored = np.concatenate([square, square[:, ::-1]])
    assert overlap_share(mirrored, 64, 64) == 1.0


def test_dilate_fills_the_margin_ring_by_ring_and_no_further():
    image = np.zeros((9, 9, 1), np.float32)
    filled = np.zeros((9, 9), bool)
    image[4, 4], filled[4, 4] = 0.5, True
    out = dilate(image, filled, 2)
    assert (out[2:7, 2:7] == 0.5).all() and out[0, 0] == 0 and out[1, 4] == 0


def flat_scene(tri_uv: np.ndarray, *, lightmap: np.ndarray | None = None, corner_count: int | None = None,
               metres: float = 1.0) -> Scene:
    """A scene of one mesh prim: unit squares in a row (two triangles each) with the given per-corner UVs."""
    count = len(tri_uv) // 2
    points, tris = [], []
    for k in range(count):
        base = len(points)
        points += [(k * 1.5, 0, 0), (k * 1.5 + 1, 0, 0), (k * 1.5 + 1, 1, 0), (k * 1.5, 1, 0)]
        tris += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    points = np.array(points, np.float32)
    tris = np.array(tris, np.int32)
    n = len(tris)
    return Scene(points=points, tri_vertices=tris, tri_normals=np.tile([0, 0, 1], (n, 1)).astype(np.float32),
                 tri_areas=np.full(n, 0.5, np.float32), tri_albedo=np.full((n, 3), 0.5, np.float32),
                 tri_emission=np.zeros((n, 3), np.float32), tri_prim=np.zeros(n, np.int32),
                 tri_face=np.arange(n, dtype=np.int32), tri_instance=np.full(n, -1, np.int32),
                 tri_double_sided=np.zeros(n, bool), point_prim=np.zeros(len(points), np.int32),
                 prim_paths=("/World/Mesh",), prim_point_start=np.array([0, len(points)]),
                 prim_face_count=np.array([n], np.int32), prim_writable=np.ones(1, bool),
                 prim_skip=np.zeros(1, bool), prim_surface=("",), meters_per_unit=metres,
                 tri_corner=np.arange(3 * n, dtype=np.int32).reshape(-1, 3),
                 tri_st=np.asarray(tri_uv, np.float32), prim_st=("st",),
                 tri_lightmap_uv=None if lightmap is None else np.asarray(lightmap, np.float32),
                 prim_lightmap_uv=("st1",) if lightmap is not None else None)


def squares_uv(count: int, *, shared: bool = False, offset=(0.0, 0.0)) -> np.ndarray:
    """Per-corner UVs of ``count`` unit squares: side by side in one tile, or all on one shell (shared)."""
    uvs = []
    for k in range(count):
        x0 = 0.0 if shared else k / count
        w = 0.9 if shared else 0.9 / count
        a, b, c, d = (x0, 0.05), (x0 + w, 0.05), (x0 + w, 0.95), (x0, 0.95)
        uvs += [(a, b, c), (a, c, d)]
    return np.array(uvs, np.float32) + np.array(offset, np.float32)


def test_layout_keeps_st_that_lies_in_one_tile_without_overlap_at_the_asked_density():
    scene = flat_scene(squares_uv(3))
    layout = lightmap_layout(scene, np.array([0]), density=64.0, max_size=4096)
    (mesh,) = layout.meshes
    assert mesh.source == "st" and mesh.uv_name == "st" and mesh.overlap == 0.0
    assert abs(mesh.density - 64.0) / 64.0 < 0.05  # the ceil of the page side only adds texels
    capped = lightmap_layout(scene, np.array([0]), density=64.0, max_size=16).meshes[0]
    assert capped.density < 20.0


def test_layout_moves_st_of_one_udim_tile_into_the_page():
    layout = lightmap_layout(flat_scene(squares_uv(2, offset=(1.0, 0.0))), np.array([0]), density=16.0,
                             max_size=256)
    assert layout.meshes[0].source == "st"
    assert np.nanmin(layout.tri_uv) >= 0.0 and np.nanmax(layout.tri_uv) <= 1.0


@pytest.mark.parametrize("why, uv", [
    ("overlaps", squares_uv(3, shared=True)),
    ("outside its tile", squares_uv(2) * np.float32(1.2) - np.float32(0.1)),
    ("UDIM tiles", np.concatenate([squares_uv(1), squares_uv(1, offset=(1.0, 0.0))])),
])
def test_layout_generates_uvs_where_st_cannot_hold_a_lightmap(why, uv):
    scene = flat_scene(uv)
    layout = lightmap_layout(scene, np.array([0]), density=32.0, max_size=1024)
    (mesh,) = layout.meshes
    assert mesh.source == "generated" and mesh.uv_name == GENERATED_UV and why in mesh.reason
    width, height = layout.page_sizes[mesh.page]
    assert overlap_share(layout.tri_uv, width, height) == 0.0  # charts never share a texel centre
    e1, e2 = layout.tri_uv[:, 1] - layout.tri_uv[:, 0], layout.tri_uv[:, 2] - layout.tri_uv[:, 0]
    areas = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert (areas > 0).all() and (layout.tri_uv >= 0).all() and (layout.tri_uv <= 1).all()
    values = layout.generated[0]
    assert values.shape == (int(scene.prim_corner_count[0]), 2)
    np.testing.assert_array_equal(values[scene.tri_corner], layout.tri_uv)  # what is written is what is baked


def test_layout_uses_the_lightmap_set_and_refuses_one_across_tiles():
    shared_st = squares_uv(2, shared=True)
    layout = lightmap_layout(flat_scene(shared_st, lightmap=squares_uv(2)), np.array([0]), density=8.0, max_size=64)
    assert layout.meshes[0].source == "lightmap" and layout.meshes[0].uv_name == "st1"
    spanning = np.concatenate([squares_uv(1), squares_uv(1, offset=(0.0, 1.0))])
    with pytest.raises(LightmapError, match=r"/World/Mesh\.primvars:st1: spans 2 UDIM tiles"):
        lightmap_layout(flat_scene(shared_st, lightmap=spanning), np.array([0]), density=8.0, max_size=64)


def test_layout_counts_degenerate_uv_triangles():
    uv = squares_uv(2)
    uv[1] = [[0.2, 0.2], [0.3, 0.3], [0.4, 0.4]]
    layout = lightmap_layout(flat_scene(uv), np.array([0]), density=16.0, max_size=128)
    assert layout.meshes[0].source == "st" and layout.meshes[0].degenerate == 1


def test_a_layout_beyond_the_texel_budget_is_refused_before_any_ray():
    scene = flat_scene(squares_uv(3))
    with pytest.raises(LightmapError, match=r"would hold 268,435,456 texels on 1 pages .* lower texel_density"):
        lightmap_layout(scene, np.array([0]), density=1e5, max_size=16384)
