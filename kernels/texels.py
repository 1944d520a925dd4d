"""The texels of a lightmap page that triangles cover in UV space, and the point of its triangle each is baked at.

Conservative coverage: a texel belongs to a triangle when its square shares area with the triangle
(separating-axis test on the square's two axes and the triangle's three edge normals; Ericson,
*Real-Time Collision Detection*, 2005, Section 5.2.1, with touching taken as separate), so no texel a
chart reaches is left black. Of the triangles that cover a texel, the one nearest its centre owns it
(ties: the lowest triangle index, so the result does not depend on thread order), and the texel is baked
at that triangle's point nearest the centre (Ericson Section 5.1.5, in 2D): the centre itself when it is
inside, else a point on the triangle's edge, never outside the surface.

Written here rather than taken from a rasterizer library: the bake needs, per texel, the owning
triangle and barycentric coordinates under this exact coverage rule, which image libraries do not give.
Texel (x, y) of a width x height page spans UV [x/width, (x+1)/width] x [y/height, (y+1)/height]: row 0
is v = 0 (``stages`` flips rows when it writes an image file, whose first row is the top).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

DEGENERATE_UV_AREA = 1e-9
"""Twice the signed area, in texels^2, under which a triangle covers no texel (a degenerate UV triangle)."""


@wp.func
def cross2(a: wp.vec2, b: wp.vec2) -> float:
    return a[0] * b[1] - a[1] * b[0]


@wp.func
def square_overlaps_edge(centre: wp.vec2, start: wp.vec2, end: wp.vec2, orientation: float) -> bool:
    """Whether the unit texel square at ``centre`` reaches the inner side of edge start -> end (of a triangle
    whose signed doubled area has the sign ``orientation``) by a positive distance: one SAT axis."""
    edge = end - start
    outward = wp.vec2(edge[1], -edge[0]) * orientation  # right of the edge for counter-clockwise triangles
    reach = 0.5 * (wp.abs(outward[0]) + wp.abs(outward[1]))
    return wp.dot(outward, centre - start) < reach


@wp.func
def closest_barycentric(p: wp.vec2, a: wp.vec2, b: wp.vec2, c: wp.vec2) -> wp.vec3:
    """Barycentric coordinates (of a, b, c) of the triangle's point nearest p (Ericson 2005, Section 5.1.5)."""
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = wp.dot(ab, ap)
    d2 = wp.dot(ac, ap)
    if d1 <= 0.0 and d2 <= 0.0:
        return wp.vec3(1.0, 0.0, 0.0)
    bp = p - b
    d3 = wp.dot(ab, bp)
    d4 = wp.dot(ac, bp)
    if d3 >= 0.0 and d4 <= d3:
        return wp.vec3(0.0, 1.0, 0.0)
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        return wp.vec3(1.0 - t, t, 0.0)
    cp = p - c
    d5 = wp.dot(ab, cp)
    d6 = wp.dot(ac, cp)
    if d6 >= 0.0 and d5 <= d6:
        return wp.vec3(0.0, 0.0, 1.0)
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        return wp.vec3(1.0 - t, 0.0, t)
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return wp.vec3(0.0, 1.0 - t, t)
    scale = 1.0 / (va + vb + vc)
    v = vb * scale
    w = vc * scale
    return wp.vec3(1.0 - v - w, v, w)


@wp.func
def texel_distance(uv: wp.array(dtype=wp.vec2), tri: int, x: int, y: int) -> float:
    """Distance (texels) from texel (x, y)'s centre to triangle ``tri`` when the texel's square overlaps it,
    else -1. ``uv`` holds three corners per triangle in texel units."""
    a = uv[3 * tri]
    b = uv[3 * tri + 1]
    c = uv[3 * tri + 2]
    orientation = wp.sign(cross2(b - a, c - a))
    centre = wp.vec2(float(x) + 0.5, float(y) + 0.5)
    if not (square_overlaps_edge(centre, a, b, orientation) and square_overlaps_edge(centre, b, c, orientation)
            and square_overlaps_edge(centre, c, a, orientation)):
        return -1.0
    w = closest_barycentric(centre, a, b, c)
    return wp.length(centre - (a * w[0] + b * w[1] + c * w[2]))


@wp.func
def texel_span(uv: wp.array(dtype=wp.vec2), tri: int, axis: int, size: int) -> wp.vec2i:
    """[first, last] texel index along ``axis`` whose extent overlaps the triangle's (empty: last < first)."""
    lo = wp.min(wp.min(uv[3 * tri][axis], uv[3 * tri + 1][axis]), uv[3 * tri + 2][axis])
    hi = wp.max(wp.max(uv[3 * tri][axis], uv[3 * tri + 1][axis]), uv[3 * tri + 2][axis])
    first = wp.max(int(wp.floor(wp.clamp(lo, -1.0, float(size) + 1.0))), 0)
    last = wp.min(int(wp.ceil(wp.clamp(hi, -1.0, float(size) + 1.0))) - 1, size - 1)
    return wp.vec2i(first, last)


@wp.kernel
def nearest_kernel(uv: wp.array(dtype=wp.vec2), live: wp.array(dtype=wp.int32), nearest: wp.array2d(dtype=float)):
    """nearest[y, x] = min over live triangles whose area the texel's square overlaps of the distance from its
    centre to the triangle (texels)."""
    tri = wp.tid()
    if live[tri] == 0:
        return
    xs = texel_span(uv, tri, 0, nearest.shape[1])
    ys = texel_span(uv, tri, 1, nearest.shape[0])
    for y in range(ys[0], ys[1] + 1):
        for x in range(xs[0], xs[1] + 1):
            d = texel_distance(uv, tri, x, y)
            if d >= 0.0:
                wp.atomic_min(nearest, y, x, d)


@wp.kernel
def owner_kernel(uv: wp.array(dtype=wp.vec2), live: wp.array(dtype=wp.int32), nearest: wp.array2d(dtype=float),
                 owner: wp.array2d(dtype=wp.int32)):
    """owner[y, x] = the lowest index of the covering triangles at the texel's ``nearest`` distance."""
    tri = wp.tid()
    if live[tri] == 0:
        return
    xs = texel_span(uv, tri, 0, owner.shape[1])
    ys = texel_span(uv, tri, 1, owner.shape[0])
    for y in range(ys[0], ys[1] + 1):
        for x in range(xs[0], xs[1] + 1):
            d = texel_distance(uv, tri, x, y)
            if d >= 0.0 and d == nearest[y, x]:
                wp.atomic_min(owner, y, x, tri)


@wp.kernel
def barycentric_kernel(uv: wp.array(dtype=wp.vec2), width: int, texel: wp.array(dtype=wp.int32),
                       owner: wp.array(dtype=wp.int32), weights: wp.array(dtype=wp.vec3)):
    """weights[i]: barycentric coordinates of the point of triangle owner[i] nearest texel[i]'s centre."""
    i = wp.tid()
    tri = owner[i]
    centre = wp.vec2(float(texel[i] % width) + 0.5, float(texel[i] / width) + 0.5)
    weights[i] = closest_barycentric(centre, uv[3 * tri], uv[3 * tri + 1], uv[3 * tri + 2])


@wp.kernel
def centre_count_kernel(uv: wp.array(dtype=wp.vec2), live: wp.array(dtype=wp.int32), count: wp.array2d(dtype=wp.int32)):
    """count[y, x] += 1 for each live triangle whose open interior holds the texel's centre (an edge or
    corner through the centre counts for no triangle, so neighbours never count twice)."""
    tri = wp.tid()
    if live[tri] == 0:
        return
    a = uv[3 * tri]
    b = uv[3 * tri + 1]
    c = uv[3 * tri + 2]
    orientation = wp.sign(cross2(b - a, c - a))
    xs = texel_span(uv, tri, 0, count.shape[1])
    ys = texel_span(uv, tri, 1, count.shape[0])
    for y in range(ys[0], ys[1] + 1):
        for x in range(xs[0], xs[1] + 1):
            p = wp.vec2(float(x) + 0.5, float(y) + 0.5)
            if (cross2(b - a, p - a) * orientation > 0.0 and cross2(c - b, p - b) * orientation > 0.0
                    and cross2(a - c, p - c) * orientation > 0.0):
                wp.atomic_add(count, y, x, 1)


@dataclass(frozen=True)
class PageTexels:
    """The covered texels of one page: texel (flat index y * width + x), its triangle, its point's weights."""

    width: int
    height: int
    texel: np.ndarray
    """(N,) int64 flat texel indices, ascending."""
    triangle: np.ndarray
    """(N,) int64 index into the triangles given to ``page_texels``."""
    weights: np.ndarray
    """(N, 3) float32 barycentric coordinates of the baked point in its triangle (corner order of the UVs)."""


def _texel_uvs(tri_uv: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(3T, 2) float32 corners in texel units, and (T,) int32 1 where the triangle has area there (else 0)."""
    corners = np.asarray(tri_uv, np.float64).reshape(-1, 3, 2) * np.array([width, height], np.float64)
    doubled = ((corners[:, 1, 0] - corners[:, 0, 0]) * (corners[:, 2, 1] - corners[:, 0, 1])
               - (corners[:, 1, 1] - corners[:, 0, 1]) * (corners[:, 2, 0] - corners[:, 0, 0]))
    live = np.isfinite(corners).all(axis=(1, 2)) & (np.abs(np.nan_to_num(doubled)) > DEGENERATE_UV_AREA)
    corners = np.where(live[:, None, None], np.nan_to_num(corners), 0.0)
    return corners.astype(np.float32).reshape(-1, 2), live.astype(np.int32)


def degenerate_uv_triangles(tri_uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """(T,) bool: triangles that cover no texel (zero or non-finite UV area at this page size)."""
    return _texel_uvs(tri_uv, width, height)[1] == 0


def page_texels(tri_uv: np.ndarray, width: int, height: int, device: str = "cpu") -> PageTexels:
    """The texels (T, 3, 2) UV triangles in [0, 1]^2 cover on a width x height page, each with its owning
    triangle and the barycentric coordinates of the point it is baked at (module docstring)."""
    uv, live = _texel_uvs(tri_uv, width, height)
    uv_wp = wp.array(uv, dtype=wp.vec2, device=device)
    live_wp = wp.array(live, dtype=wp.int32, device=device)
    nearest = wp.full((height, width), np.inf, dtype=float, device=device)
    owner = wp.full((height, width), np.iinfo(np.int32).max, dtype=wp.int32, device=device)
    count = len(live)
    if count:
        wp.launch(nearest_kernel, dim=count, inputs=[uv_wp, live_wp, nearest], device=device)
        wp.launch(owner_kernel, dim=count, inputs=[uv_wp, live_wp, nearest, owner], device=device)
    owners = owner.numpy().reshape(-1)
    texel = np.flatnonzero(owners != np.iinfo(np.int32).max)
    weights = wp.zeros(len(texel), dtype=wp.vec3, device=device)
    if len(texel):
        wp.launch(barycentric_kernel, dim=len(texel), device=device,
                  inputs=[uv_wp, width, wp.array(texel.astype(np.int32), dtype=wp.int32, device=device),
                          wp.array(owners[texel], dtype=wp.int32, device=device), weights])
    return PageTexels(width, height, texel.astype(np.int64), owners[texel].astype(np.int64),
                      weights.numpy().astype(np.float32))


def overlap_share(tri_uv: np.ndarray, width: int, height: int, device: str = "cpu") -> float:
    """Share of the texel centres inside some triangle that lie inside two or more: how much of a UV set
    overlaps itself (0 for a set a lightmap can use), measured on a width x height grid over [0, 1]^2."""
    uv, live = _texel_uvs(tri_uv, width, height)
    counts = wp.zeros((height, width), dtype=wp.int32, device=device)
    if len(live):
        wp.launch(centre_count_kernel, dim=len(live), device=device,
                  inputs=[wp.array(uv, dtype=wp.vec2, device=device), wp.array(live, dtype=wp.int32, device=device),
                          counts])
    counts = counts.numpy()
    covered = int((counts > 0).sum())
    return float((counts > 1).sum()) / covered if covered else 0.0
