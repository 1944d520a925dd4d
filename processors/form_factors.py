"""Radiosity precompute: voxel-clustered patches, ray-cast form factors, a compressed multi-bounce operator.

Implements the precompute half of Shcherbakov (MSU 2017), "radiosity with a
multi-bounce form-factor matrix and DXT compression" (sections 4.1 and 4.2):

1. **Patches by voxelization.** Triangles longer than the voxel are split into
   ``m x m`` congruent sub-triangles (fragments, ``m = ceil(longest edge /
   voxel)``); fragments are clustered per voxel (of their centroid) and per
   dominant signed axis of their normal (6 bins). A patch keeps its area,
   area-weighted centroid, unit mean normal and area-weighted mean albedo.
2. **Form factors** ``F_ij`` (the fraction of the cosine-weighted hemisphere
   of patch i covered by patch j) by cosine-weighted rays from stratified
   points on each patch; a hit is mapped to the fragment (so the patch) of the
   hit point. Back-face hits are absorbed (patches are one-sided).
3. **Multi-bounce operator** (thesis eq. 4-7). With ``A = F diag(rho_c)``
   per colour channel c (``F^C`` with the colour of the reflecting patch),
   ``M_c = sum_{h=1..k} A^h``, or the infinite-bounce closed form
   ``(I - A)^-1 - I``. Given direct irradiance ``E0`` (W/m^2) at the patches,
   ``M E0`` is the indirect irradiance after 1..k reflections (W/m^2). (The
   thesis multiplies rows by the receiver's colour and applies the operator
   to emitted radiosity; ``diag(rho) M = M_thesis diag(rho)``, the same
   polynomial.)
4. **Compression** (thesis 4.2). The largest ``exact_fraction`` (4 %) of the
   entries (by their largest channel) are kept exact in a sparse CSR part and
   zeroed in the rest; the rest is divided by its largest value, log-quantized
   to byte codes (code 0 = zero, codes 1..255 uniform in ln v from a floor to
   the maximum), rows and columns are reordered by the thesis' greedy
   nearest-neighbour passes (L1 distance; the same permutation on rows and
   columns), and the RGB codes are BC1 (DXT1) encoded in 4x4 blocks and
   written as a standard .dds texture (texel (x=j, y=i) = stored entry (i, j)).
   Beyond the thesis: each decoded row is rescaled per channel so its sum
   equals the exact row sum of the coded part (``row_correction``, n x 3
   floats): this removes the bias of the quantization (entries rounded to
   code 0, exp of noisy log codes) for smooth light, and ``quantization =
   linear`` codes v / vmax instead of the logarithm (smaller error on the
   narrow-range matrices of closed rooms; see docs/radiosity.md).

Decoding one stored entry: ``ln v = code * quantizationScale +
quantizationOffset`` for codes 1..255 (8-bit BC1-decoded channel values;
``v = code * scale + offset`` for linear quantization), ``v = 0`` for code 0,
times ``row_scale[i]``; the sparse part is added on top. Stored row/column i
is patch ``permutation[i]``.

USD written (bake layer): a ``RadiosityPatches`` prim at
``/usdbake/RadiosityPatches`` (``/usdbake`` is a Scope; a root prim so it
does not depend on the stage's default prim):

====================== ========== ==================================================
property               type       value
====================== ========== ==================================================
centroids              point3f[]  patch centroids (relative to the stage's world frame)
normals                normal3f[] unit patch normals
areas                  float[]    patch areas (stage units^2)
albedo                 color3f[]  area-weighted mean diffuse albedo
trianglePatch          int[]      patch of each scene triangle's centre (-1: degenerate)
matrixFile             asset      ``usdbake_radiosity_<hash>.dds`` (BC1 codes)
sparseFile             asset      ``usdbake_radiosity_<hash>_sparse.npz`` (CSR: indptr,
                                  indices, values (nnz, 3) float32, lut (256,),
                                  permutation, row_scale (n, 3))
bounces                int        k (0 for the infinite-bounce closed form)
quantizationScale      float      ln v (log) or v (linear) per code step
quantizationOffset     float      ln v (or v) at code 0; code 0 itself decodes to 0
bake:quantization      token      ``log`` or ``linear``
permutation            int[]      patch stored at row/column i
bake:voxelSize         float      voxel edge used (stage units)
bake:exactFraction     float      share of entries kept exact
bake:formFactorRays    int        rays per patch
====================== ========== ==================================================

Parameters
----------
================== ====== ======= =======================================================
name               type   default meaning
================== ====== ======= =======================================================
voxel_size         float  0.0     voxel edge in stage units; 0 = chosen for target_patches
target_patches     int    2000    patch count aimed at when voxel_size is 0
rays               int    1024    form-factor rays per patch (rounded to a square)
bounces            int    3       k in sum_{h=1..k} (F^C)^h
infinite           bool   False   use (I - F^C)^-1 - I instead (all bounces)
exact_fraction     float  0.04    share of the largest entries kept exact (sparse part)
log_floor          float  0.0     smallest coded value / largest remaining one; 0 = auto
reorder_passes     int    2       greedy reordering passes (0, 1 rows, 2 rows + columns)
quantization       str    log     code mapping before BC1: log (thesis) or linear
row_correction     bool   True    rescale each decoded BC1 row to its exact row sum ((n, 3) floats)
seed               int    0       random seed (identical results across thread counts)
================== ====== ======= =======================================================
"""

from __future__ import annotations

import hashlib
import io
import math
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from ..formats import dds
from ..core import (
    Attribute,
    Context,
    File,
    Params,
    Prim,
    Processor,
    Result,
    param,
)
from ..core.products import CompressedOperator, FormFactorProduct, Patches
from ..kernels.bc1 import blocks_to_image, decode_bc1_texels, encode_bc1
from ..kernels.patches import fragment_of_hit, point_in_triangle
from ..kernels.sampling import cosine_hemisphere, stratified_pair, tangent_frame
from ..core.scene import Scene
from ..kernels.tracer import launch_chunked

wp.set_module_options({"enable_backward": False})

PATCHES_PRIM = "/usdbake/RadiosityPatches"
MAX_SUBDIVISION = 64
"""Largest m (m^2 fragments) a triangle is split into: bounds fragment counts on huge ground planes."""
MAX_FRAGMENTS = 8_000_000
"""Refuse voxel sizes that would split the scene into more fragments than this (~300 MB of corners)."""
MAX_PATCHES = 16384
"""The operator is dense: 16384 patches already need 3.2 GB as float32 RGB during the precompute."""
AUTO_FLOOR_MASS = 1e-3
"""Automatic log floor: the residual entries coded as zero sum to at most this share of the residual."""
ROW_SCALE_LIMIT = 4.0
"""Bound on the row-sum correction factor (a row whose decoded sum is off by more is left clipped)."""
SIGNATURE_DIMS = 256
"""Reordering compares rows by L1 distance over at most this many column groups (means), keeping
the greedy pass O(n^2 * 256) instead of O(n^3)."""


# ---------------------------------------------------------------------------
# Warp kernels


@wp.func
def sample_fragment(patch: int, u0: float, patch_fragment_start: wp.array(dtype=int),
                    patch_fragment_cdf: wp.array(dtype=float)) -> int:
    """Index into the patch-sorted fragment list: the first with cdf > u0 (binary search)."""
    lo = patch_fragment_start[patch]
    hi = patch_fragment_start[patch + 1] - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if patch_fragment_cdf[mid] > u0:
            hi = mid
        else:
            lo = mid + 1
    return lo


@wp.kernel
def form_factor_kernel(
    start: int,
    mesh: wp.uint64,
    rays: int,
    strata: int,
    stride: int,
    patch_fragment_start: wp.array(dtype=int),
    patch_fragment_cdf: wp.array(dtype=float),
    patch_fragments: wp.array(dtype=int),
    fragment_vertices: wp.array(dtype=wp.vec3),
    fragment_tri: wp.array(dtype=int),
    tri_normals: wp.array(dtype=wp.vec3),
    tri_subdivision: wp.array(dtype=int),
    tri_fragment_start: wp.array(dtype=int),
    fragment_patch: wp.array(dtype=int),
    epsilon: float,
    seed: int,
    base: int,
    hit_patch: wp.array(dtype=int),
):
    """Ray k of patch i (item i * rays + k, written at item - base): the patch it meets, -1 for none.

    The origin is stratified over the patch area (fragment chosen by area CDF at (k + xi) / rays),
    the direction over the hemisphere (stratum k * stride mod rays, stride coprime to rays, so
    position and direction strata are not correlated).
    """
    item = start + wp.tid()
    i = item // rays
    k = item % rays
    state = wp.rand_init(seed, item)
    slot = sample_fragment(i, (float(k) + wp.randf(state)) / float(rays), patch_fragment_start, patch_fragment_cdf)
    fragment = patch_fragments[slot]
    t = fragment_tri[fragment]
    n = tri_normals[t]
    x = point_in_triangle(fragment_vertices[3 * fragment], fragment_vertices[3 * fragment + 1],
                          fragment_vertices[3 * fragment + 2], wp.randf(state), wp.randf(state))
    uv = stratified_pair((k * stride) % rays, strata, state)
    direction = tangent_frame(n) * cosine_hemisphere(uv[0], uv[1])
    hit_patch[item - base] = -1
    q = wp.mesh_query_ray(mesh, x + n * epsilon, direction, 3.0e38)
    if q.result:
        if wp.dot(direction, tri_normals[q.face]) < 0.0:
            hit_patch[item - base] = fragment_patch[fragment_of_hit(q.face, q.u, q.v, tri_subdivision, tri_fragment_start)]


# ---------------------------------------------------------------------------
# Patches





def fragment_template(m: int) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric-grid corners of the m^2 fragments of a triangle, in fragment_of_hit's order.

    Returns (m^2, 3, 2) float64 corner coordinates (u, v) and (m^2,) float64 area share.
    """
    corners = []
    for j in range(m):
        for i in range(m - j):
            corners.append([(i, j), (i + 1, j), (i, j + 1)])
    for j in range(m - 1):
        for i in range(m - 1 - j):
            corners.append([(i + 1, j), (i + 1, j + 1), (i, j + 1)])
    return np.array(corners, np.float64) / m, np.full(m * m, 1.0 / (m * m))


def _subdivision(points: np.ndarray, tri_vertices: np.ndarray, voxel: float) -> np.ndarray:
    corner = points[tri_vertices].astype(np.float64)
    edges = np.linalg.norm(corner - np.roll(corner, 1, axis=1), axis=2).max(axis=1)
    return np.clip(np.ceil(edges / voxel), 1, MAX_SUBDIVISION).astype(np.int32)


def _fragments(points, tri_vertices, subdivision):
    """(Fr, 3, 3) float32 fragment corners and (Fr,) int32 triangle of each, in triangle order."""
    corner = points[tri_vertices].astype(np.float64)  # (T, 3, 3): v0, v1, v2
    counts = subdivision.astype(np.int64) ** 2
    start = np.zeros(len(subdivision) + 1, np.int64)
    np.cumsum(counts, out=start[1:])
    vertices = np.empty((int(start[-1]), 3, 3), np.float32)
    fragment_tri = np.repeat(np.arange(len(subdivision), dtype=np.int32), counts)
    for m in np.unique(subdivision):
        tris = np.flatnonzero(subdivision == m)
        uv, _ = fragment_template(int(m))  # (m^2, 3, 2)
        w = np.concatenate([uv, 1.0 - uv.sum(-1, keepdims=True)], axis=-1)  # weights of v0, v1, v2
        pos = np.einsum("fcw,twx->tfcx", w, corner[tris])  # (t, m^2, 3, 3)
        rows = (start[tris][:, None] + np.arange(m * m)[None, :]).ravel()
        vertices[rows] = pos.reshape(-1, 3, 3)
    return vertices, fragment_tri, start


def _cluster_keys(centres: np.ndarray, normals: np.ndarray, lo: np.ndarray, voxel: float) -> np.ndarray:
    cell = np.floor((centres - lo) / voxel).astype(np.int64)
    cell = np.clip(cell, 0, (1 << 20) - 1)
    axis = np.abs(normals).argmax(axis=1)
    sign = np.take_along_axis(normals, axis[:, None], 1)[:, 0] < 0
    direction = axis * 2 + sign
    return ((cell[:, 0] << 43) | (cell[:, 1] << 23) | (cell[:, 2] << 3) | direction)


def build_patches(points: np.ndarray, tri_vertices: np.ndarray, tri_normals: np.ndarray, tri_areas: np.ndarray,
                  tri_albedo: np.ndarray, tri_emission: np.ndarray, *, voxel_size: float) -> Patches:
    """Cluster triangle fragments into patches per voxel and per dominant normal axis.

    Parameters
    ----------
    points : (P, 3) float32; tri_vertices : (T, 3) int32; tri_normals : (T, 3) float32;
    tri_areas : (T,) float32; tri_albedo, tri_emission : (T, 3) float32
    voxel_size : voxel edge (stage units), > 0
    """
    if not voxel_size > 0:
        raise ValueError(f"voxel_size={voxel_size} must be > 0")
    subdivision = _subdivision(points, tri_vertices, voxel_size)
    fragments = int((subdivision.astype(np.int64) ** 2).sum())
    if fragments > MAX_FRAGMENTS:
        raise ValueError(f"voxel_size={voxel_size:g} splits the scene into {fragments} fragments "
                         f"(limit {MAX_FRAGMENTS}); use a larger voxel_size")
    vertices, fragment_tri, start = _fragments(points, tri_vertices, subdivision)
    valid_tri = (tri_areas > 0) & (np.linalg.norm(tri_normals, axis=1) > 0.5) & np.isfinite(tri_areas)
    valid = valid_tri[fragment_tri]
    centres = vertices.mean(axis=1).astype(np.float64)
    normals = tri_normals[fragment_tri].astype(np.float64)
    areas = (tri_areas[fragment_tri] / (subdivision[fragment_tri].astype(np.float64) ** 2))
    lo = points.min(axis=0).astype(np.float64) if len(points) else np.zeros(3)
    keys = _cluster_keys(centres[valid], normals[valid], lo, voxel_size)
    _, inverse = np.unique(keys, return_inverse=True)
    if len(inverse) and int(inverse.max()) + 1 > MAX_PATCHES:
        raise ValueError(f"voxel_size={voxel_size:g} gives {int(inverse.max()) + 1} patches (limit {MAX_PATCHES}: "
                         f"the operator is dense, n^2 x 12 bytes); use a larger voxel_size")
    fragment_patch = np.full(len(fragment_tri), -1, np.int32)
    fragment_patch[valid] = inverse.astype(np.int32)
    n = int(inverse.max()) + 1 if len(inverse) else 0

    vp = fragment_patch[valid]
    w = areas[valid]
    area = np.bincount(vp, weights=w, minlength=n)
    safe = np.maximum(area, 1e-300)[:, None]

    def mean(values):
        return np.stack([np.bincount(vp, weights=values[:, c] * w, minlength=n) for c in range(3)], 1) / safe

    centroid = mean(centres[valid])
    normal_sum = mean(normals[valid])
    normal = normal_sum / np.maximum(np.linalg.norm(normal_sum, axis=1, keepdims=True), 1e-30)
    albedo = mean(tri_albedo[fragment_tri][valid].astype(np.float64))
    emission = mean(tri_emission[fragment_tri][valid].astype(np.float64))

    order = np.flatnonzero(valid)[np.argsort(vp, kind="stable")]
    patch_start = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(vp, minlength=n), out=patch_start[1:])
    cdf = np.cumsum(areas[order])
    base = np.repeat(np.concatenate([[0.0], cdf])[patch_start[:-1]], np.diff(patch_start))
    cdf = (cdf - base) / np.repeat(np.maximum(area, 1e-300), np.diff(patch_start))
    cdf[patch_start[1:] - 1] = 1.0  # exact ends, so the search never runs past a patch

    # The fragment holding a triangle's centre: lower cell of the middle row for m = 1, else search.
    tri_patch = np.full(len(tri_vertices), -1, np.int32)
    centre_local = np.array([_centre_fragment(int(m)) for m in range(MAX_SUBDIVISION + 1)], np.int64)
    tri_patch[:] = fragment_patch[start[:-1] + centre_local[subdivision]]
    return Patches(
        patch_centroids=centroid.astype(np.float32), patch_normals=normal.astype(np.float32),
        patch_areas=area.astype(np.float32), patch_albedo=np.clip(albedo, 0, 1).astype(np.float32),
        patch_emission=emission.astype(np.float32), patch_fragment_start=patch_start.astype(np.int32),
        patch_fragments=order.astype(np.int32), patch_fragment_cdf=cdf.astype(np.float32),
        fragment_vertices=vertices, fragment_tri=fragment_tri, fragment_patch=fragment_patch,
        tri_subdivision=subdivision, tri_fragment_start=start.astype(np.int32), tri_patch=tri_patch,
        voxel_size=float(voxel_size))


def _centre_fragment(m: int) -> int:
    """Local index of the fragment containing the barycentre (1/3, 1/3) of an m-split triangle."""
    if m <= 0:
        return 0
    a = b = m / 3.0
    i = min(int(math.floor(a)), m - 1)
    j = min(int(math.floor(b)), m - 1)
    if i + j > m - 1:
        i = m - 1 - j
    if (a - i) + (b - j) > 1.0 and i + j <= m - 2:
        return m * (m + 1) // 2 + j * (m - 1) - j * (j - 1) // 2 + i
    return j * m - j * (j - 1) // 2 + i


def count_patches(points, tri_vertices, tri_normals, tri_areas, voxel: float) -> int:
    """Number of patches build_patches would make (cheaper: no per-patch means)."""
    subdivision = _subdivision(points, tri_vertices, voxel)
    if int((subdivision.astype(np.int64) ** 2).sum()) > MAX_FRAGMENTS:
        return MAX_PATCHES * 4  # far too many: the voxel search grows the voxel
    vertices, fragment_tri, _ = _fragments(points, tri_vertices, subdivision)
    valid = ((tri_areas > 0) & (np.linalg.norm(tri_normals, axis=1) > 0.5))[fragment_tri]
    lo = points.min(axis=0).astype(np.float64)
    keys = _cluster_keys(vertices.mean(axis=1)[valid].astype(np.float64),
                         tri_normals[fragment_tri][valid].astype(np.float64), lo, voxel)
    return len(np.unique(keys))


def choose_voxel_size(points, tri_vertices, tri_normals, tri_areas, target: int) -> float:
    """Voxel edge giving about ``target`` patches (patch count ~ area / voxel^2; a few refinements)."""
    total = float(tri_areas[np.isfinite(tri_areas)].sum())
    if total <= 0:
        return 1.0
    voxel = math.sqrt(total / target)
    best, best_err = voxel, math.inf
    for _ in range(6):
        count = count_patches(points, tri_vertices, tri_normals, tri_areas, voxel)
        err = abs(math.log(max(count, 1) / target))
        if err < best_err:
            best, best_err = voxel, err
        if err < 0.05:
            break
        voxel *= math.sqrt(max(count, 1) / target)
    return best


# ---------------------------------------------------------------------------
# Form factors


def rays_square(rays: int) -> tuple[int, int]:
    strata = max(1, int(round(math.sqrt(rays))))
    return strata * strata, strata


def compute_form_factors(tracer, patches: Patches, tri_normals: np.ndarray, *, rays: int, seed: int = 0,
                         progress=None) -> np.ndarray:
    """Dense (n, n) float32 F_ij = share of patch i's cosine-weighted rays that land on patch j.

    Patches are processed in batches so the per-ray buffer stays below ~64 MB.
    """
    n = patches.count
    rays, strata = rays_square(rays)
    stride = next(s for s in (7919, 104729, 1299709, 1) if math.gcd(s, rays) == 1)
    device = tracer.device
    arrays = [
        tracer.array(patches.patch_fragment_start, wp.int32), tracer.array(patches.patch_fragment_cdf, wp.float32),
        tracer.array(patches.patch_fragments, wp.int32),
        tracer.array(patches.fragment_vertices.reshape(-1, 3), wp.vec3), tracer.array(patches.fragment_tri, wp.int32),
        tracer.array(np.ascontiguousarray(tri_normals, np.float32), wp.vec3),
        tracer.array(patches.tri_subdivision, wp.int32), tracer.array(patches.tri_fragment_start, wp.int32),
        tracer.array(patches.fragment_patch, wp.int32),
    ]
    counts = np.zeros(n * n, np.float64)
    batch = max(1, (16 << 20) // rays)
    for lo in range(0, n, batch):
        hi = min(n, lo + batch)
        total = (hi - lo) * rays
        hit = wp.empty(total, dtype=int, device=device)
        launch_chunked(form_factor_kernel, total,
                       [tracer.mesh.id, rays, strata, stride, *arrays, tracer.epsilon, seed, lo * rays, hit],
                       device=tracer.device, threads=tracer.threads, offset=lo * rays)
        hits = hit.numpy()
        source = np.repeat(np.arange(lo, hi, dtype=np.int64), rays)
        ok = hits >= 0
        counts += np.bincount(source[ok] * n + hits[ok], minlength=n * n)
        tracer.rays_cast += total
        if progress:
            progress(hi / n)
    return (counts / rays).reshape(n, n).astype(np.float32)


def form_factor_checks(form: np.ndarray, areas: np.ndarray) -> dict[str, float]:
    """Reciprocity and row sums: relative |A_i F_ij - A_j F_ji| mass, and row-sum mean/min/max."""
    flux = form.astype(np.float64) * areas[:, None]
    denom = float(np.abs(flux).sum() + np.abs(flux.T).sum())
    rows = form.sum(axis=1, dtype=np.float64)
    return {
        "reciprocity_error": float(np.abs(flux - flux.T).sum() / denom) if denom > 0 else 0.0,
        "row_sum_mean": float(rows.mean()) if len(rows) else 0.0,
        "row_sum_min": float(rows.min()) if len(rows) else 0.0,
        "row_sum_max": float(rows.max()) if len(rows) else 0.0,
    }


# ---------------------------------------------------------------------------
# Multi-bounce operator


def multibounce_operator(form: np.ndarray, albedo: np.ndarray, *, bounces: int = 3,
                         infinite: bool = False) -> np.ndarray:
    """(3, n, n) float32 M_c = sum_{h=1..k} (F diag(rho_c))^h, or (I - F diag(rho_c))^-1 - I.

    Horner form A (I + A (I + ...)): k - 1 matrix products per channel.
    """
    n = len(form)
    out = np.empty((3, n, n), np.float32)
    for c in range(3):
        a = form * albedo[None, :, c].astype(np.float32)
        if infinite:
            eye = np.eye(n, dtype=np.float64)
            out[c] = np.linalg.solve(eye - a.astype(np.float64), a.astype(np.float64)).astype(np.float32)
            continue
        s = a.copy()
        for _ in range(bounces - 1):
            s = a + a @ s
        out[c] = s
    return out


# ---------------------------------------------------------------------------
# Compression





def log_codes(values: np.ndarray, floor: float, vmax: float) -> tuple[np.ndarray, float, float]:
    """Float codes in {0} U [1, 255]: 0 below ``floor``, else 1 + 254 ln(v/floor) / ln(vmax/floor)."""
    span = max(math.log(vmax / floor), 1e-6)
    scale = span / 254.0
    offset = math.log(floor) - scale
    with np.errstate(divide="ignore", invalid="ignore"):
        codes = np.where(values >= floor, 1.0 + 254.0 * np.log(np.maximum(values, floor) / floor) / span, 0.0)
    return np.clip(codes, 0.0, 255.0).astype(np.float32), scale, offset


def linear_codes(values: np.ndarray, vmax: float) -> tuple[np.ndarray, float, float]:
    """Float codes in [0, 255] = 255 v / vmax; value = code * scale + offset (offset 0)."""
    return np.clip(values * (255.0 / vmax), 0.0, 255.0).astype(np.float32), vmax / 255.0, 0.0


def code_lut(scale: float, offset: float, quantization: str = "log") -> np.ndarray:
    """(256,) float32 byte code -> value (code 0 is exactly 0 in both schemes)."""
    codes = np.arange(256, dtype=np.float64)
    lut = np.exp(offset + scale * codes) if quantization == "log" else offset + scale * codes
    lut[0] = 0.0
    return lut.astype(np.float32)


def auto_floor(residual_max: np.ndarray, vmax: float, mass: float = AUTO_FLOOR_MASS) -> float:
    """Largest floor such that entries below it sum to at most ``mass`` of the residual (sampled)."""
    flat = residual_max[residual_max > 0].astype(np.float64)
    if len(flat) == 0:
        return vmax * 1e-6
    if len(flat) > 4_000_000:
        flat = np.random.default_rng(0).choice(flat, 4_000_000, replace=False)
    flat.sort()
    cum = np.cumsum(flat)
    k = int(np.searchsorted(cum, mass * cum[-1], side="right"))
    floor = flat[min(k, len(flat) - 1)]
    return float(min(max(floor, vmax * 1e-12), vmax * 0.5))


def greedy_order(signatures: np.ndarray) -> np.ndarray:
    """The thesis' greedy pass: starting at item 0, repeatedly append the nearest (L1) remaining item."""
    n = len(signatures)
    remaining = np.ones(n, bool)
    order = np.empty(n, np.int64)
    current = 0
    sig = np.ascontiguousarray(signatures, np.float32)
    idx = np.arange(n)
    for step in range(n):
        order[step] = current
        remaining[current] = False
        if step == n - 1:
            break
        candidates = idx[remaining]
        dist = np.abs(sig[candidates] - sig[current]).sum(axis=1)
        current = int(candidates[int(dist.argmin())])
    return order


def _signatures(codes_mean: np.ndarray) -> np.ndarray:
    """Rows of an (n, n) code matrix reduced to at most SIGNATURE_DIMS column-group means."""
    n = codes_mean.shape[1]
    groups = min(n, SIGNATURE_DIMS)
    edges = np.linspace(0, n, groups + 1).astype(np.int64)
    sums = np.add.reduceat(codes_mean, edges[:-1], axis=1)
    return sums / np.diff(edges)[None, :]


def reorder(codes_mean: np.ndarray, passes: int) -> np.ndarray:
    """(n,) permutation from ``passes`` greedy passes: rows first, then columns (same order for both)."""
    n = len(codes_mean)
    perm = np.arange(n)
    for p in range(passes):
        current = codes_mean[np.ix_(perm, perm)]
        sig = _signatures(current if p % 2 == 0 else current.T)
        perm = perm[greedy_order(sig)]
    return perm


def compress_operator(operator: np.ndarray, *, exact_fraction: float = 0.04, log_floor: float = 0.0,
                      reorder_passes: int = 2, row_correction: bool = True,
                      quantization: str = "log") -> CompressedOperator:
    """Compress a (3, n, n) operator: exact top entries + BC1 log codes (thesis 4.2)."""
    _, n, _ = operator.shape
    magnitude = operator.max(axis=0)
    keep = int(round(exact_fraction * n * n))
    exact = np.zeros((n, n), bool)
    if keep > 0:
        flat = magnitude.ravel()
        top = np.argpartition(flat, -keep)[-keep:]
        top = top[flat[top] > 0]
        exact.ravel()[top] = True
    residual = np.where(exact[None], 0.0, operator).astype(np.float32)
    residual_max = residual.max(axis=0)
    vmax = float(residual_max.max()) if n else 0.0
    if vmax <= 0:
        vmax = 1.0
    if quantization == "log":
        floor = log_floor * vmax if log_floor > 0 else auto_floor(residual_max, vmax)
        codes, scale, offset = log_codes(np.moveaxis(residual, 0, -1), floor, vmax)  # (n, n, 3)
    elif quantization == "linear":
        floor = 0.0
        codes, scale, offset = linear_codes(np.moveaxis(residual, 0, -1), vmax)
    else:
        raise ValueError(f"quantization={quantization!r} is not 'log' or 'linear'")
    perm = reorder(codes.mean(axis=2), reorder_passes) if reorder_passes > 0 else np.arange(n)
    n4 = (n + 3) // 4 * 4
    image = np.zeros((n4, n4, 3), np.float32)
    image[:n, :n] = codes[np.ix_(perm, perm)]
    blocks = encode_bc1(image)

    exact_p = exact[np.ix_(perm, perm)]
    rows, cols = np.nonzero(exact_p)
    indptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    values = np.moveaxis(operator, 0, -1)[perm[rows], perm[cols]].astype(np.float32)
    lut = code_lut(scale, offset, quantization)
    compressed = CompressedOperator(
        size=n, blocks=blocks, permutation=perm.astype(np.int32), sparse_indptr=indptr.astype(np.int32),
        sparse_indices=cols.astype(np.int32), sparse_values=values, lut=lut, log_scale=scale, log_offset=offset,
        quantization=quantization,
        row_scale=np.ones((n, 3), np.float32))
    residual_stored = residual[:, perm][:, :, perm]
    stats = compression_errors(compressed, residual_stored, vmax)
    if row_correction:
        # Rescale each decoded row so its sum matches the true residual row sum: removes the bias of
        # quantization (codes rounded to 0, exp of noisy log codes) for smooth inputs; (n, 3) floats.
        decoded_sum = decoded_residual(compressed).sum(axis=2, dtype=np.float64)  # (3, n)
        true_sum = residual_stored.sum(axis=2, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(decoded_sum > 0, true_sum / decoded_sum, 1.0)
        object.__setattr__(compressed, "row_scale",
                           np.clip(ratio, 1.0 / ROW_SCALE_LIMIT, ROW_SCALE_LIMIT).T.astype(np.float32).copy())
        stats.update({f"corrected_{k}": v for k, v in compression_errors(compressed, residual_stored, vmax).items()})
    stats.update({"floor": floor, "residual_max": vmax, "exact_entries": int(len(rows)),
                  "dense_bytes": int(12 * n * n), "compressed_bytes": compressed.nbytes,
                  "memory_ratio": compressed.nbytes / max(12 * n * n, 1)})
    object.__setattr__(compressed, "stats", stats)
    return compressed


def decoded_residual(compressed: CompressedOperator) -> np.ndarray:
    """(3, n, n) float32 BC1 part decoded in stored order, row_scale applied (tests and figures only)."""
    n, n4 = compressed.size, compressed.padded
    codes = blocks_to_image(decode_bc1_texels(compressed.blocks), n4, n4)[:n, :n]
    return np.moveaxis(compressed.lut[codes] * compressed.row_scale[:, None, :], -1, 0)


def compression_errors(compressed: CompressedOperator, residual_stored: np.ndarray, vmax: float) -> dict:
    """Thesis-style errors of the BC1 part, normalized by the largest residual value (its [0, 1] domain).

    ``residual_stored`` : (3, n, n) float32 residual in stored (permuted) order.
    """
    err = np.abs(decoded_residual(compressed) - residual_stored) / vmax
    return {"error_mean": float(err.mean()) if err.size else 0.0, "error_max": float(err.max()) if err.size else 0.0,
            "error_sum": float(err.sum(dtype=np.float64))}


def decompress_operator(compressed: CompressedOperator) -> np.ndarray:
    """(3, n, n) float32 operator in patch order, decoded (reference for tests; relight never does this)."""
    stored = decoded_residual(compressed)
    n = compressed.size
    rows = np.repeat(np.arange(n), np.diff(compressed.sparse_indptr))
    stored[:, rows, compressed.sparse_indices] += compressed.sparse_values.T
    out = np.empty_like(stored)
    perm = compressed.permutation
    out[:, perm[:, None], perm[None, :]] = stored
    return out


# ---------------------------------------------------------------------------
# Product and processor





def sparse_file_bytes(compressed: CompressedOperator) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, indptr=compressed.sparse_indptr, indices=compressed.sparse_indices,
             values=compressed.sparse_values, lut=compressed.lut, permutation=compressed.permutation,
             row_scale=compressed.row_scale)
    return buffer.getvalue()


def precompute(tracer, scene: Scene, p, progress=lambda f: None) -> tuple[FormFactorProduct, dict]:
    """Patches -> form factors -> multi-bounce operator -> compression (pure; used by run and benchmarks)."""
    voxel = p.voxel_size or choose_voxel_size(scene.points, scene.tri_vertices, scene.tri_normals,
                                              scene.tri_areas, p.target_patches)
    patches = build_patches(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas,
                            scene.tri_albedo, scene.tri_emission, voxel_size=voxel)
    progress(0.05)
    form = compute_form_factors(tracer, patches, scene.tri_normals, rays=p.rays, seed=p.seed,
                                progress=lambda f: progress(0.05 + 0.6 * f))
    checks = form_factor_checks(form, patches.patch_areas)
    operator = multibounce_operator(form, patches.patch_albedo, bounces=p.bounces, infinite=p.infinite)
    progress(0.75)
    compressed = compress_operator(operator, exact_fraction=p.exact_fraction, log_floor=p.log_floor,
                                   reorder_passes=p.reorder_passes, row_correction=p.row_correction,
                                   quantization=p.quantization)
    progress(1.0)
    return FormFactorProduct(patches, compressed, p.bounces, p.infinite, checks), {"form": form, "operator": operator}


class FormFactors(Processor):
    name = "form_factors"
    version = "2"
    summary = "Radiosity precompute: voxel patches, ray-cast form factors, compressed multi-bounce matrix (BC1)."
    facets = ("geometry", "materials")
    provides = (FormFactorProduct,)

    @dataclass(frozen=True)
    class Params(Params):
        voxel_size: float = param(0.0, "voxel edge in stage units; 0 = chosen to give target_patches", low=0.0)
        target_patches: int = param(2000, "patch count aimed at when voxel_size is 0", low=1, high=MAX_PATCHES)
        rays: int = param(1024, "form-factor rays per patch (rounded to a square)", low=1, high=1 << 20)
        bounces: int = param(3, "k: reflections in sum_{h=1..k} (F^C)^h", low=1, high=64)
        infinite: bool = param(False, "use the closed form (I - F^C)^-1 - I (all bounces) instead of k")
        exact_fraction: float = param(0.04, "share of the largest entries kept exact (sparse part)",
                                      low=0.0, high=1.0)
        log_floor: float = param(0.0, "smallest coded value / largest remaining one; 0 = automatic",
                                 low=0.0, high=0.5)
        reorder_passes: int = param(2, "greedy reordering passes: 0 none, 1 rows, 2 rows + columns",
                                    low=0, high=2)
        quantization: str = param("log", "code mapping before BC1: 'log' (thesis) or 'linear'",
                                  choices=("log", "linear"))
        row_correction: bool = param(True, "rescale decoded BC1 rows to their exact row sums ((n, 3) floats)")
        seed: int = param(0, "random seed (identical results across thread counts)", low=0)

    def applies(self, ctx: Context) -> tuple[bool, str]:
        scene = ctx.scene
        if not (scene.tri_areas > 0).any():
            return False, "no triangles with area"
        return True, ""

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        if p.infinite and float(scene.tri_albedo.max(initial=0.0)) >= 1.0:
            raise ValueError("form_factors: infinite=true needs every albedo < 1 (the bounce series diverges)")
        product, _ = precompute(ctx.tracer, scene, p, ctx.progress)
        patches, op = product.patches, product.operator
        dds_bytes = dds.dds_bc1_bytes(op.blocks, op.padded, op.padded)
        sparse_bytes = sparse_file_bytes(op)
        digest = hashlib.sha256(dds_bytes + sparse_bytes).hexdigest()[:10]
        matrix_file = f"usdbake_radiosity_{digest}.dds"
        sparse_file = f"usdbake_radiosity_{digest}_sparse.npz"
        origin = np.asarray(scene.origin, np.float64)
        path = PATCHES_PRIM
        outputs = [
            Prim("/usdbake", "Scope"), Prim(path, "RadiosityPatches"),
            File(matrix_file, dds_bytes), File(sparse_file, sparse_bytes),
            Attribute(path, "centroids", (patches.patch_centroids + origin).astype(np.float32), "point3f[]"),
            Attribute(path, "normals", patches.patch_normals, "normal3f[]"),
            Attribute(path, "areas", patches.patch_areas, "float[]"),
            Attribute(path, "albedo", patches.patch_albedo, "color3f[]"),
            Attribute(path, "trianglePatch", patches.tri_patch, "int[]"),
            Attribute(path, "matrixFile", matrix_file, "asset"),
            Attribute(path, "sparseFile", sparse_file, "asset"),
            Attribute(path, "bounces", 0 if p.infinite else int(p.bounces), "int"),
            Attribute(path, "quantizationScale", float(op.log_scale), "float"),
            Attribute(path, "quantizationOffset", float(op.log_offset), "float"),
            Attribute(path, "permutation", op.permutation, "int[]"),
            Attribute(path, "bake:quantization", op.quantization, "token", uniform=True),
            Attribute(path, "bake:voxelSize", float(patches.voxel_size), "float"),
            Attribute(path, "bake:exactFraction", float(p.exact_fraction), "float"),
            Attribute(path, "bake:formFactorRays", int(rays_square(p.rays)[0]), "int"),
        ]
        stats = {"patches": float(patches.count), "rays": float(patches.count * rays_square(p.rays)[0]),
                 **{k: float(v) for k, v in product.checks.items()},
                 **{k: float(v) for k, v in op.stats.items()}}
        messages = []
        if product.checks["row_sum_max"] > 1.0 + 1e-6:
            messages.append(f"form-factor row sums exceed 1 ({product.checks['row_sum_max']:.4f})")
        return Result(products={FormFactorProduct: product}, outputs=outputs, stats=stats, messages=messages)
