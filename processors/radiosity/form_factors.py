"""Radiosity precompute: voxel-clustered patches, ray-cast form factors, a compressed multi-bounce operator.

Implements the precompute half of Shcherbakov (MSU 2017), "radiosity with a
multi-bounce form-factor matrix and DXT compression" (section 5's precompute
steps 1-6, with the optimizations of sections 4.1 and 4.2). This module holds
the technique (form factors, the multi-bounce sum, the processor); the patches
come from processors/radiosity/patches.py, the compression from processors/radiosity/operator_codec.py,
the file bytes from processors/radiosity/dds.py and processors/radiosity/sparse_operator.py.

1. **Patches by voxelization** (section 5, step 1; processors/radiosity/patches.py).
   Triangles longer than the voxel are split into ``m x m`` congruent
   sub-triangles (fragments, ``m = ceil(longest edge / voxel)``); fragments
   are clustered per voxel (of their centroid), per dominant signed axis
   of their normal (6 bins) and per receiver prim; triangles radiosity writes
   nothing to (instances) cluster across prims, per albedo step instead, so
   the patch count follows ``target_patches`` whatever the instance count.
   A patch keeps its area, area-weighted centroid, unit mean normal and
   area-weighted mean albedo.
2. **Form factors** ``F_ij`` (section 3.5; Malley's method): the fraction of
   the cosine-weighted hemisphere of patch i covered by patch j, by
   cosine-weighted rays from stratified points on each patch; a hit is mapped
   to the fragment (so the patch) of the hit point. Back-face hits are
   absorbed (patches are one-sided).
3. **Multi-bounce operator** (section 4.1, eq. 4-7). With ``A = F diag(rho_c)``
   per colour channel c (``F^C`` with the colour of the reflecting patch),
   ``M_c = sum_{h=1..k} A^h``, or the infinite-bounce closed form
   ``(I - A)^-1 - I``. Given direct irradiance ``E0`` (W/m^2) at the patches,
   ``M E0`` is the indirect irradiance after 1..k reflections (W/m^2). (The
   thesis multiplies rows by the receiver's colour and applies the operator
   to emitted radiosity; ``diag(rho) M = M_thesis diag(rho)``, the same
   polynomial.)
4. **Compression** (section 4.2; processors/radiosity/operator_codec.py). The largest
   ``exact_fraction`` (4 %) of the entries are kept exact in a sparse CSR
   part; the rest is divided by its largest value, log-quantized to byte codes
   (code 0 = zero), reordered by the thesis' greedy nearest-neighbour passes
   (the same permutation on rows and columns), BC1 (DXT1) encoded and written
   as a standard .dds texture (texel (x=j, y=i) = stored entry (i, j)).
   Beyond the thesis: a per-row, per-channel rescaling to the exact row sums
   (``row_correction``) and ``quantization = linear`` (see docs/radiosity.md).

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

Parameters: ``usdbake list form_factors`` or docs/radiosity.md, both generated from ``Params`` below.
"""

from __future__ import annotations

import dataclasses

import hashlib
import math
import time
from dataclasses import dataclass

import numpy as np
import warp as wp

from ...core import Attribute, Context, File, Params, Prim, Processor, Result, param
from ...core.chunks import SceneChunks
from .products import FormFactorProduct, Patches
from ...core.scene import Scene
from . import dds
from .sparse_operator import sparse_file_bytes
from ...geometry.mesh import receiver_detail_box, receiver_prims
from .patches import MAX_PATCHES, build_patches, choose_voxel_size, patch_groups
from .operator_codec import MAX_ERROR, compress_operator
from .patch_kernels import fragment_of_hit
from ...kernels.sampling import cosine_hemisphere, stratified_pair, tangent_frame, triangle_point
from ...kernels.tracer import FAR, launch_chunked, triangle_origin
from ...kernels.traversal import TraceScene, trace_closest

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

PATCHES_PRIM = "/usdbake/RadiosityPatches"


# ---------------------------------------------------------------------------
# Warp kernels


@wp.func
def sample_fragment(patch: int, u0: float, patch_fragment_start: wp.array(dtype=int),
                    patch_fragment_cdf: wp.array(dtype=float)) -> int:
    """Slot in the patch-sorted fragment list whose area CDF first exceeds ``u0`` in [0, 1) (binary search).

    Chooses a fragment of ``patch`` with probability proportional to its area
    (stage units^2), so points drawn on it are uniform over the patch area, as
    the area average of the form factor F_ij = (1/A_i) int_{A_i} F_{dA_i, A_j}
    dA_i requires (Cohen & Wallace 1993, "Radiosity and Realistic Image
    Synthesis", ch. 4). ``patch_fragment_cdf`` ends at exactly 1.0 per patch.
    """
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
    scene: TraceScene,
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

    One sample of Malley's method for the form factor F_ij of Shcherbakov (MSU
    2017), section 3.5 ("what part of the energy arriving at the first
    patch is reflected onto the second"): rays leave patch i with the cosine-weighted
    density cos(theta) / pi (sr^-1), so the share of them that first hits patch
    j estimates F_ij = (1/A_i) int int cos th_i cos th_j / (pi r^2) V dA_j dA_i
    (dimensionless; Cohen & Wallace 1993, "Radiosity and Realistic Image
    Synthesis", ch. 4, Nusselt analog; Malley 1988). The thesis names the step
    only (section 5, precompute step 2).

    The origin is stratified over the patch area (fragment chosen by area CDF at (k + xi) / rays),
    the direction over the hemisphere (stratum k * stride mod rays, stride coprime to rays, so
    position and direction strata are not correlated). Hits on a back face count as misses
    (patches are one-sided); origins are offset by ``epsilon`` (stage units) along the normal.
    """
    item = start + wp.tid()
    i = item // rays
    k = item % rays
    state = wp.rand_init(seed, item)
    slot = sample_fragment(i, (float(k) + wp.randf(state)) / float(rays), patch_fragment_start, patch_fragment_cdf)
    fragment = patch_fragments[slot]
    t = fragment_tri[fragment]
    n = tri_normals[t]
    fa = fragment_vertices[3 * fragment]
    fb = fragment_vertices[3 * fragment + 1]
    fc = fragment_vertices[3 * fragment + 2]
    x = triangle_point(fa, fb, fc, wp.randf(state), wp.randf(state))
    uv = stratified_pair((k * stride) % rays, strata, state)
    direction = tangent_frame(n) * cosine_hemisphere(uv[0], uv[1])
    hit_patch[item - base] = -1
    q = trace_closest(scene, triangle_origin(scene, fa, fb, fc, x, n, epsilon), direction, FAR)
    if q.result:
        if wp.dot(direction, tri_normals[q.face]) < 0.0:
            hit_patch[item - base] = fragment_patch[fragment_of_hit(q.face, q.u, q.v, tri_subdivision, tri_fragment_start)]


# ---------------------------------------------------------------------------
# Form factors


def rays_square(rays: int) -> tuple[int, int]:
    """(rays rounded to a square, its side): the strata x strata grid of form_factor_kernel's directions."""
    strata = max(1, int(round(math.sqrt(rays))))
    return strata * strata, strata


def compute_form_factors(tracer, patches: Patches, tri_normals: np.ndarray, *, rays: int, seed: int = 0,
                         progress=None, rows: tuple[int, int] | None = None) -> np.ndarray:
    """Dense (n, n) float32 form factors F_ij (dimensionless): the share of patch i's cosine-weighted rays
    that first land on the front of patch j; with ``rows=(lo, hi)`` only rows lo .. hi - 1, (hi - lo, n).

    Malley's method (Cohen & Wallace 1993, ch. 4) for the form factors of
    Shcherbakov (MSU 2017), section 3.5 and section 5, precompute step 2;
    launches ``form_factor_kernel``. Rows sum to at most 1 (the rest escapes or
    hits back faces); reciprocity A_i F_ij = A_j F_ji holds up to sampling noise
    (``form_factor_checks``).

    Parameters
    ----------
    tracer : kernels.tracer.Tracer over the scene's triangles
    patches : products.Patches from processors.radiosity.patches.build_patches
    tri_normals : (T, 3) float32 unit triangle normals
    rays : rays per patch, rounded to a square (``rays_square``)
    seed : random seed; ray k of patch i draws from (seed, i * rays + k), so results depend neither on
        thread counts nor on which rows a call computes (core.chunks)

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
    first, last = rows if rows is not None else (0, n)
    counts = np.zeros((last - first) * n, np.float64)
    batch = max(1, (16 << 20) // rays)
    for lo in range(first, last, batch):
        hi = min(last, lo + batch)
        total = (hi - lo) * rays
        hit = wp.empty(total, dtype=int, device=device)
        launch_chunked(form_factor_kernel, total,
                       [tracer.scene, rays, strata, stride, *arrays, tracer.epsilon, seed, lo * rays, hit],
                       device=tracer.device, threads=tracer.threads, offset=lo * rays)
        hits = hit.numpy()
        if hits.size and int(hits.max()) >= n:
            raise RuntimeError(f"form factors on {device}: ray hits name patch {int(hits.max())} of {n}; the "
                               f"closest-hit traversal is not reliable on this device (see docs/radiosity.md, "
                               f"CUDA); run with --device cpu")
        source = np.repeat(np.arange(lo - first, hi - first, dtype=np.int64), rays)
        ok = hits >= 0
        counts += np.bincount(source[ok] * n + hits[ok], minlength=len(counts))
        tracer.rays_cast += total
        if progress:
            progress((hi - first) / max(1, last - first))
    return (counts / rays).reshape(last - first, n).astype(np.float32)


def form_factor_rows_chunk(tracer, first: int, patch_ids: np.ndarray, *, scene: Scene, patches: Patches, rays: int,
                           seed: int) -> np.ndarray:
    """Rows first .. first + len(patch_ids) - 1 of ``compute_form_factors``: one chunk (core.chunks). The
    scene's triangle normals come with the scene, which a cluster worker already holds."""
    return compute_form_factors(tracer, patches, scene.tri_normals, rays=rays, seed=seed,
                                rows=(first, first + len(patch_ids)))


def form_factor_checks(form: np.ndarray, areas: np.ndarray) -> dict[str, float]:
    """Reciprocity and row sums: relative |A_i F_ij - A_j F_ji| mass, and row-sum mean/min/max.

    Checks of the form factor's two standard properties (Cohen & Wallace 1993,
    ch. 4): reciprocity A_i F_ij = A_j F_ji and, in an enclosure, sum_j F_ij = 1.
    ``areas`` : (n,) float32 patch areas (stage units^2); all results dimensionless.
    """
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

    Shcherbakov (MSU 2017), section 4.1, eq. 4-7: the multi-bounce matrix
    F^{k-reflections} = sum_{h=1..k} (F^C)^h, computed once so a relight is one
    matrix-vector product. Here the colour is the reflecting patch's,
    A = F diag(rho_c) with ``albedo`` (n, 3) float32 in [0, 1], where eq. 4
    takes the receiver's (F^C_ij = F_ij colors_i); diag(rho) M = M_thesis
    diag(rho), the same polynomial. M E0 maps direct irradiance E0 (W/m^2) at
    the patches to the indirect irradiance after 1..k reflections (W/m^2); M
    itself is dimensionless. ``infinite`` sums all bounces in closed form (the
    Neumann series of the radiosity equation; needs every albedo < 1).

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
# Processor


def precompute(tracer, scene: Scene, p, progress=lambda f: None, chunks=None) -> tuple[FormFactorProduct, dict]:
    """Patches -> form factors -> multi-bounce operator -> compression (pure; used by run and benchmarks).
    ``chunks`` (core.chunks; default: in process on ``tracer``) computes the form factors by rows. The dict
    holds the dense form factors and operator, and ``seconds`` of each part (for the scale benchmark)."""
    seconds, started = {}, time.perf_counter()

    def part(name: str) -> None:
        nonlocal started
        seconds[name] = time.perf_counter() - started
        started = time.perf_counter()

    detail = receiver_detail_box(scene)
    groups = patch_groups(scene.tri_prim, scene.tri_albedo, ~np.isin(scene.tri_prim, receiver_prims(scene)))
    voxel = p.voxel_size or choose_voxel_size(scene.points, scene.tri_vertices, scene.tri_normals,
                                              scene.tri_areas, p.target_patches, groups, detail)
    patches = build_patches(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas,
                            scene.tri_albedo, scene.tri_emission, voxel_size=voxel, tri_group=groups,
                            detail_box=detail)
    part("patches")
    progress(0.05)
    chunks = chunks if chunks is not None else SceneChunks(tracer)
    form = chunks.map(form_factor_rows_chunk, (np.arange(patches.count),), scene=scene, patches=patches,
                      rays=p.rays, seed=p.seed,
                      progress=lambda f: progress(0.05 + 0.6 * f))
    checks = form_factor_checks(form, patches.patch_areas)
    part("form_factors")
    operator = multibounce_operator(form, patches.patch_albedo, bounces=p.bounces, infinite=p.infinite)
    part("operator")
    progress(0.75)
    compressed = compress_operator(operator, exact_fraction=p.exact_fraction, log_floor=p.log_floor,
                                   reorder_passes=p.reorder_passes, row_correction=p.row_correction,
                                   quantization=p.quantization, max_error=p.max_error)
    part("compression")
    progress(1.0)
    return (FormFactorProduct(patches, compressed, p.bounces, p.infinite, checks),
            {"form": form, "operator": operator, "seconds": seconds})


class FormFactors(Processor):
    name = "form_factors"
    version = "8"
    summary = "Radiosity precompute: voxel patches, ray-cast form factors, compressed multi-bounce matrix (BC1)."
    facets = ("geometry", "materials")
    provides = (FormFactorProduct,)

    @dataclass(frozen=True)
    class Params(Params):
        voxel_size: float = param(0.0, "voxel edge in stage units; 0 = chosen to give target_patches", low=0.0)
        target_patches: int = param(2000, "patch count aimed at when voxel_size is 0", low=1, high=MAX_PATCHES)
        rays: int = param(1024, "form-factor rays per patch (rounded to a square)", low=1, high=1 << 20)
        bounces: int = param(3, "k: reflections in sum_{h=1..k} (F^C)^h", low=1, high=64)
        infinite: bool = param(True, "all bounces by the closed form (I - F^C)^-1 - I; false, or a scene with an "
                               "albedo of 1: the k = bounces terms of the series")
        exact_fraction: float = param(0.04, "share of the largest entries kept exact (sparse part)",
                                      low=0.0, high=1.0)
        log_floor: float = param(0.0, "smallest coded value / largest remaining one; 0 = automatic",
                                 low=0.0, high=0.5)
        reorder_passes: int = param(2, "greedy reordering passes: 0 none, 1 rows, 2 rows + columns",
                                    low=0, high=2)
        quantization: str = param("log", "code mapping before BC1: 'log' (thesis) or 'linear'",
                                  choices=("log", "linear"))
        row_correction: bool = param(True, "rescale decoded BC1 rows to their exact row sums ((n, 3) floats)")
        max_error: float = param(MAX_ERROR, "a coded entry decoding further than this share of the largest "
                                 "coded value from its value joins the exact part", low=0.0, high=1.0)
        seed: int = param(0, "random seed (identical results across thread counts)", low=0)

    def applies(self, ctx: Context) -> tuple[bool, str]:
        scene = ctx.scene
        if not (scene.tri_areas > 0).any():
            return False, "no triangles with area"
        return True, ""

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        messages = []
        if p.infinite and float(scene.tri_albedo.max(initial=0.0)) >= 1.0:
            brightest = scene.prim_paths[int(scene.tri_prim[int(scene.tri_albedo.max(axis=1).argmax())])]
            p = dataclasses.replace(p, infinite=False)
            messages.append(f"{brightest} has an albedo of 1, so all bounces have no closed form: {p.bounces} "
                            f"bounces instead (the bounces parameter)")
        product, _ = precompute(ctx.tracer, scene, p, ctx.progress, chunks=ctx.chunks)
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
        if product.checks["row_sum_max"] > 1.0 + 1e-6:
            messages.append(f"form-factor row sums exceed 1 ({product.checks['row_sum_max']:.4f})")
        return Result(products={FormFactorProduct: product}, outputs=outputs, stats=stats, messages=messages)
