"""Sky patch visibility factors of triangles: the ray casts of ``sky_visibility`` (Bosch, Besuievsky &
Martin, Sec. 4.1, with ray-core casts instead of occlusion queries; the ``sky_visibility`` docstring has
the math), per (triangle, patch) pair, and the per-triangle reduction a refinement pass keeps.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ...kernels.sampling import strata_for, stratified_pair, triangle_point
from ...kernels.sky import SkyPatches, patch_jittered_samples, patch_mean_directions, patch_outlines
from ...kernels.tracer import FAR, MIN_CHUNK, triangle_origin
from ...kernels.traversal import TraceScene, trace_any
from .glazing import GlassPanes, glass_arguments, segment_transmittance

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

QUANT_LEVELS = 255
"""V is stored as round(V * 255) in uint8: error <= 0.5 / 255 per factor."""

PAIRS_PER_BATCH = 4_000_000
"""(triangle, patch) pairs per launch: bounds the temporary V/partial arrays to ~32 MB."""

SAMPLE_SETS_BYTES = 2 ** 21
"""Room for the patch sample sets (``sky.patch_jittered_samples``), up to MAX_SAMPLE_SETS of them: about a
core's cache, so a sample costs a load from it."""
MAX_SAMPLE_SETS = 64
"""Sample sets a face draws one of: an average over many faces keeps 1 / sqrt(64) of one set's error."""

ORIGIN_SETS = 8
"""Sets of origins a triangle's patches take in turn (at most one per patch): a large face partly in shade
is sampled at ORIGIN_SETS x samples places, not at samples places only. Measured on building, relative RMS
of the faces' sky view against 4096-ray references over 4 seeds: one set 0.0162 (0.0116-0.0211), 4 sets
0.0131, 8 sets 0.0105, 16 sets 0.0105; rays from their own point per pair, as before, 0.0106."""
ORIGINS_PER_BATCH = 1_000_000
"""Ray origins per launch: bounds the origin array to 12 MB, whatever the patch count."""


@wp.kernel
def sample_origins_kernel(start: int, scene: TraceScene, corners: wp.array(dtype=wp.vec3),
                          normals: wp.array(dtype=wp.vec3), tri_ids: wp.array(dtype=int), strata: int, sets: int,
                          epsilon: float, seed: int, origins: wp.array(dtype=wp.vec3)):
    """``sets`` sets of ray origins of triangle i, strata^2 each: origin s of set m is a uniform point in
    cell s of a strata x strata grid over the unit square (``stratified_pair``, seeded by (seed, tri_ids[i], m)),
    taken to the triangle by the square-root warp (``triangle_point``), off its surface by
    ``triangle_origin``. Patch j's sample s leaves from origin s of set j % sets: the origins are made once
    per triangle, not once per (triangle, patch) pair, and still sample a face at sets x strata^2 places."""
    i = start + wp.tid()
    n = normals[i]
    count = strata * strata
    a = corners[3 * i]
    b = corners[3 * i + 1]
    c = corners[3 * i + 2]
    state = wp.rand_init(seed, tri_ids[i])
    for m in range(sets):
        set_state = wp.rand_init(wp.int32(state), m)
        for s in range(count):
            u = stratified_pair(s, strata, set_state)
            origins[(i * sets + m) * count + s] = triangle_origin(scene, a, b, c, triangle_point(a, b, c, u[0], u[1]),
                                                                  n, epsilon)


@wp.kernel
def patch_visibility_kernel(
    start: int,
    scene: TraceScene,
    normals: wp.array(dtype=wp.vec3),
    tri_ids: wp.array(dtype=int),
    origins: wp.array(dtype=wp.vec3),
    origin_sets: int,
    samples: wp.array(dtype=wp.vec3),
    sample_sets: int,
    patch_centers: wp.array(dtype=wp.vec3),
    patch_horizon: wp.array(dtype=float),
    patch_outlines: wp.array(dtype=wp.vec3),
    patch_means: wp.array(dtype=wp.vec3),
    num_patches: int,
    count: int,
    epsilon: float,
    any_partial: int,
    has_glass: int,
    glass: TraceScene,
    glass_tn: wp.array(dtype=float),
    glass_normal: wp.array(dtype=wp.vec3),
    visible: wp.array(dtype=float),
    partial: wp.array(dtype=float),
):
    """V_ij (cosine-weighted visible share) and min(visible, occluded) of triangle i for every patch j, at
    k = i * N + j.

    The visibility factor of Bosch, Besuievsky & Martin, Sec. 4.1 (Fig. 4:
    V_ij += (f_v / f_c) cos theta_ik over the patch's samples k, then averaged),
    with a ray per sample (``samples``: the patch's directions in one of ``sample_sets`` sets, the one a hash
    of tri_ids[i] picks, read in order; ``origins``: the triangle's points, set j % ``origin_sets``) instead
    of the occlusion query's
    visible-fragment share f_v / f_c: V_ij = (1/s) sum_k vis_k max(0, n_i . w_k), dimensionless in
    [0, 1]; for a patch wholly above the triangle's plane (its ``patch_outlines`` on or above it), scaled
    to the exact mean cosine C_ij = n_i . ``patch_means``_j: V_ij = C_ij sum_k vis_k cos_k / sum_k cos_k.
    ``partial`` feeds the refinement test of Sec. 4.2 (0 < V_ij < 1 in the paper): min of the
    visible and occluded cosine-weighted shares (``criterion = share``), or
    their sum when both are non-zero (``any_partial``). With glazing (``has_glass``), ``scene`` holds the
    opaque triangles and a ray that escapes them counts its transmittance through the panes of ``glass``
    (``glazing.segment_transmittance``); for ``partial`` it counts as seen, so a face behind a window is not
    refined for the glass alone. A sample below the triangle's horizon costs a dot product, not a ray.
    """
    i = start + wp.tid()
    n = normals[i]
    facing = wp.length(n) >= 0.5
    sample_set = int(wp.rand_init(tri_ids[i]) % wp.uint32(sample_sets))
    origin_set = int(-1)  # j % origin_sets, counted (an integer division per pair costs as much as a ray's setup)
    for j in range(num_patches):
        origin_set = wp.where(origin_set + 1 == origin_sets, 0, origin_set + 1)
        k = i * num_patches + j
        visible[k] = 0.0
        partial[k] = 0.0
        center_cos = wp.dot(n, patch_centers[j])
        if not facing or center_cos < patch_horizon[j]:
            continue  # the whole patch is below the triangle's horizon
        first = (sample_set * num_patches + j) * count
        first_origin = (i * origin_sets + origin_set) * count
        vis = float(0.0)
        seen = float(0.0)
        occ = float(0.0)
        for s in range(count):
            d = samples[first + s]
            cos_theta = wp.dot(n, d)
            if cos_theta > 0.0:
                origin = origins[first_origin + s]
                if trace_any(scene, origin, d, FAR):
                    occ += cos_theta
                else:
                    seen += cos_theta
                    through = float(1.0)
                    if has_glass != 0:
                        through = segment_transmittance(glass, glass_tn, glass_normal, origin, d, FAR, epsilon)
                    vis += cos_theta * through
        # A patch wholly above the triangle's plane: its cosine-weighted share is known exactly, so the samples
        # only split it into visible and occluded (a ratio estimate): an open face sums to exactly 1, not 1 +- noise.
        # (-patch_horizon is sin of the patch's angular radius: a centre that high has the whole patch above.)
        if seen + occ > 0.0 and (center_cos > -patch_horizon[j] or above_plane(n, patch_outlines, j)):
            scale = wp.dot(n, patch_means[j]) * float(count) / (seen + occ)
            vis = vis * scale
            seen = seen * scale
            occ = occ * scale
        visible[k] = vis / float(count)
        if any_partial != 0:
            if seen > 0.0 and occ > 0.0:
                partial[k] = (seen + occ) / float(count)
        else:
            partial[k] = wp.min(seen, occ) / float(count)


@wp.func
def above_plane(n: wp.vec3, outlines: wp.array(dtype=wp.vec3), j: int) -> bool:
    """Patch j's four corners lie on or above the plane of n (to float rounding: a horizontal face and the
    patches resting on the horizon) and its midpoint above it (``sky.patch_outlines``)."""
    tolerance = -1.0e-6
    return (wp.dot(n, outlines[5 * j]) >= tolerance and wp.dot(n, outlines[5 * j + 1]) >= tolerance
            and wp.dot(n, outlines[5 * j + 2]) >= tolerance and wp.dot(n, outlines[5 * j + 3]) >= tolerance
            and wp.dot(n, outlines[5 * j + 4]) > 0.0)


def compute_patch_visibility(tracer, corners: np.ndarray, normals: np.ndarray, patches: SkyPatches,
                             to_world: np.ndarray, *, samples: int = 4, seed: int = 0,
                             tri_ids: np.ndarray | None = None, criterion: str = "share", glazing=None
                             ) -> tuple[np.ndarray, np.ndarray]:
    """Visibility factors of triangles for sky patches.

    Bosch, Besuievsky & Martin, Sec. 4.1 (launches ``patch_visibility_kernel``):
    V_ij = 1 / (A_i dw_j) * integral_{A_i} integral_{patch j} vis(x, w) max(0, n_i . w) dw dA,
    dimensionless; with patch radiances Lhat_j in W/(m^2 sr), sum_j Lhat_j V_ij
    dw_j is the sky irradiance of triangle i in W/m^2 (their Eq. 1 without the
    reflectance).

    Parameters
    ----------
    tracer : Tracer over the occluding scene
    corners : (T, 3, 3) float32 triangle corners (scene frame)
    normals : (T, 3) float32 unit normals (zero: the triangle gets V = 0)
    patches : the patch layout (ENU); ``to_world`` (3, 3) maps ENU to the scene frame
    samples : rays per (triangle, patch) pair
    tri_ids : (T,) int, optional, stable ids seeding each triangle's random numbers
    glazing : ``glazing.Glazing``, optional: rays cross its panes with their transmittance (``tracer`` is
        then its opaque tracer)

    Returns
    -------
    V : (T, N) float32 cosine-weighted visible share, in [0, 1]
    partial : (T, N) float32 min(visible, occluded) cosine-weighted shares
    """
    corners = np.ascontiguousarray(corners, np.float32).reshape(-1, 3, 3)
    normals = np.ascontiguousarray(normals, np.float32).reshape(-1, 3)
    n_tri, n_patch = len(corners), len(patches)
    tri_ids = np.arange(n_tri, dtype=np.int32) if tri_ids is None else np.asarray(tri_ids, np.int32)
    to_world = np.asarray(to_world, np.float64)
    strata = strata_for(samples)
    count = strata * strata

    def world(enu: np.ndarray) -> wp.array:
        return tracer.array((enu @ to_world.T).reshape(-1, 3).astype(np.float32), wp.vec3)

    sets = sample_set_count(n_patch, count)
    patch_arrays = [world(patch_jittered_samples(patches, strata, seed, sets)), sets, world(patches.patch_directions),
                    tracer.array((-np.sin(np.minimum(patches.patch_radius, np.pi / 2))).astype(np.float32), float),
                    world(patch_outlines(patches.patch_bounds)), world(patch_mean_directions(patches.patch_bounds))]
    glass = glass_arguments(tracer, glazing)
    visible = np.zeros((n_tri, n_patch), np.float32)
    partial = np.zeros((n_tri, n_patch), np.float32)
    origin_sets = max(1, min(ORIGIN_SETS, n_patch))
    batch = max(1, min(PAIRS_PER_BATCH // max(n_patch, 1), ORIGINS_PER_BATCH // (origin_sets * count)))
    for lo in range(0, n_tri, batch):
        hi = min(n_tri, lo + batch)
        normals_wp = tracer.array(normals[lo:hi], wp.vec3)
        ids_wp = tracer.array(tri_ids[lo:hi], int)
        origins = wp.empty((hi - lo) * origin_sets * count, dtype=wp.vec3, device=tracer.device)
        tracer.launch(sample_origins_kernel, hi - lo, [
            tracer.scene, tracer.array(corners[lo:hi].reshape(-1, 3), wp.vec3), normals_wp,
            ids_wp, strata, origin_sets, tracer.epsilon, int(seed), origins],
            min_chunk=max(1, MIN_CHUNK // (origin_sets * count)))
        vis_wp = wp.empty((hi - lo) * n_patch, dtype=float, device=tracer.device)
        part_wp = wp.empty((hi - lo) * n_patch, dtype=float, device=tracer.device)
        tracer.launch(patch_visibility_kernel, hi - lo, [
            tracer.scene, normals_wp, ids_wp, origins, origin_sets, *patch_arrays, n_patch, count, tracer.epsilon,
            int(criterion == "any"), *glass, vis_wp, part_wp,
        ], min_chunk=max(1, MIN_CHUNK // (n_patch * count)))  # a triangle is up to n_patch * count rays
        visible[lo:hi] = vis_wp.numpy().reshape(hi - lo, n_patch)
        partial[lo:hi] = part_wp.numpy().reshape(hi - lo, n_patch)
    tracer.rays_cast += traced_rays(normals, patches, to_world, samples)
    return visible, partial


def sample_set_count(n_patch: int, count: int) -> int:
    """How many sets of patch samples a pass draws: as many as SAMPLE_SETS_BYTES holds, 1 to MAX_SAMPLE_SETS."""
    return int(np.clip(SAMPLE_SETS_BYTES // (n_patch * count * 12), 1, MAX_SAMPLE_SETS))


def traced_rays(normals: np.ndarray, patches: SkyPatches, to_world: np.ndarray, samples: int) -> int:
    """Rays ``patch_visibility_kernel`` casts for triangles with these (T, 3) normals: strata^2 per pair
    whose patch is not wholly below the triangle's horizon (samples below the horizon inside such a
    patch included)."""
    return int(patches_above(normals, patches, to_world).sum()) * strata_for(samples) ** 2


def patches_above(normals: np.ndarray, patches: SkyPatches, to_world: np.ndarray) -> np.ndarray:
    """(T,) int: the patches not wholly below each triangle's horizon (0 for a degenerate face): the
    pairs ``patch_visibility_kernel`` samples."""
    centers = patches.patch_directions @ np.asarray(to_world, np.float64).T
    horizon = -np.sin(np.minimum(patches.patch_radius, np.pi / 2))
    normals = np.asarray(normals, np.float64)
    above = (normals @ centers.T >= horizon[None, :]).sum(axis=1)
    return np.where(np.linalg.norm(normals, axis=1) >= 0.5, above, 0)


def visibility_pass_chunk(tracer, first: int, corners: np.ndarray, normals: np.ndarray, tri_ids: np.ndarray, *,
                          patches: SkyPatches, to_world: np.ndarray, samples: int, seed: int, criterion: str,
                          glass: GlassPanes | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One chunk of a refinement pass (core.chunks): ``compute_patch_visibility`` of the triangles,
    reduced per triangle to what the pass keeps, so a chunk returns ~N bytes a triangle, not 8 N.

    ``tri_ids`` seed the triangles, so the result does not depend on where the chunk starts. ``glass``: the
    scene's panes (plain arrays, so a chunk can travel to another process), traced as ``Glazing``.
    Returns V quantized ((T, N) uint8, V * QUANT_LEVELS rounded), exposure sum_j V_ij dw_j / pi and
    its quantization error ((T,) float64 each), and the refinement score ((T,) float64; the
    ``sky_visibility`` docstring).
    """
    glazing = glass.glazing(tracer) if glass is not None else None
    v, part = compute_patch_visibility(glazing.opaque_tracer if glazing else tracer, corners, normals, patches,
                                       to_world, samples=samples, seed=seed, tri_ids=tri_ids,
                                       criterion="any" if criterion == "paper" else criterion, glazing=glazing)
    solid = patches.patch_solid_angles.astype(np.float64)
    quantized = np.clip(np.rint(v * QUANT_LEVELS), 0, QUANT_LEVELS).astype(np.uint8)
    exposure = row_sums(v, solid) / np.pi
    quant_error = np.abs(row_sums(quantized / QUANT_LEVELS - v, solid) / np.pi)
    if criterion == "paper":  # the largest projected-area factor over the partly visible patches
        centers = patches.patch_directions @ np.asarray(to_world, np.float64).T
        cosines = row_sums(np.asarray(normals, np.float64)[:, :, None], centers.T)  # (T, N): n_i . c_j
        score = np.where(part > 0, np.maximum(cosines, 0.0), 0.0).max(axis=1, initial=0.0)
    else:
        score = (2.0 if criterion == "share" else 1.0) / np.pi * row_sums(part, solid)
    return quantized, exposure, quant_error, score


def row_sums(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """sum_j values[:, j] * weights[j] in float64, accumulated column by column in a fixed order.

    A BLAS product (``values @ weights``) may round a row differently with the number of rows around
    it (its kernels block and vectorize by size), so a chunk of faces would not reproduce the whole
    pass bit for bit; elementwise sums in one order do. ``values`` (T, N) or (T, K, ...) with
    ``weights`` (N,) or (K, ...) broadcasting against ``values[:, j]``.
    """
    total = np.zeros((len(values), *np.shape(weights)[1:]), np.float64)
    for j in range(values.shape[1]):
        total += values[:, j].astype(np.float64) * weights[j]
    return total
