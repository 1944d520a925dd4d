"""Face-to-face gather rays for interreflected daylight (Warp).

Every face casts ``rays`` cosine-weighted rays from uniform points of itself (the final gather of
radiosity, Cohen & Wallace, "Radiosity and Realistic Image Synthesis", sec. 9.3.3, here kept as a
sparse matrix instead of being evaluated once): the mean over the rays of rho_k E_k at the face k
each ray lands on is the irradiance reflected towards the face once,

    E_ind(i) = (1 / R) sum_r T_r rho_{k(r)} E_{k(r)}

with T_r the transmittance of the glazing the ray crossed (1 without glass). So the gather is a
sparse (F, F) matrix G with G[i, k] = (number of rays of i landing on k, times T) / R, and one
bounce is ``G @ (rho * E)``. A ray that leaves the scene below the horizon sees the ground that
``gendaymtx`` adds outside the model; its share is the face's ground view.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import warp as wp

from ...kernels.sampling import cosine_hemisphere, stratified_pair, tangent_frame, triangle_point
from ...kernels.tracer import FAR, triangle_origin
from ...kernels.traversal import TraceScene, trace_closest
from .glazing import glass_arguments, segment_transmittance

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

ESCAPED_SKY = -1
"""A gather ray that left the scene above the horizon (the sky, counted by V already)."""
ESCAPED_GROUND = -2
"""A gather ray that left the scene below the horizon: it sees the ground outside the model."""
BLOCKED = -3
"""A gather ray that met the back of a face (one-sided surfaces reflect from the front only)."""
FACES_PER_LAUNCH = 65536


@wp.kernel
def gather_kernel(
    start: int,
    scene: TraceScene,
    corners: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    rays: int,
    strata: int,
    up: wp.vec3,
    epsilon: float,
    seed: int,
    first_face: int,
    has_glass: int,
    glass: TraceScene,
    glass_tn: wp.array(dtype=float),
    glass_normal: wp.array(dtype=wp.vec3),
    hit_face: wp.array(dtype=int),
    hit_weight: wp.array(dtype=float),
):
    """Ray r of face i (item k = i * rays + r): the face it lands on (or ESCAPED_SKY, ESCAPED_GROUND,
    BLOCKED) and the glazing transmittance along the way. Directions cosine-weighted about the face's
    normal (Malley), stratified over ``strata`` x ``strata`` cells, origins uniform on the face."""
    k = start + wp.tid()
    i = k // rays
    r = k - i * rays
    hit_face[k] = BLOCKED
    hit_weight[k] = 0.0
    n = normals[i]
    if wp.length(n) < 0.5:
        return
    a = corners[3 * i]
    b = corners[3 * i + 1]
    c = corners[3 * i + 2]
    state = wp.rand_init(seed, (first_face + i) * rays + r)
    u = wp.vec2(wp.randf(state), wp.randf(state))
    if r < strata * strata:  # the rays beyond the largest square are drawn at random
        u = stratified_pair(r, strata, state)
    d = tangent_frame(n) * cosine_hemisphere(u[0], u[1])
    x = triangle_point(a, b, c, wp.randf(state), wp.randf(state))
    origin = triangle_origin(scene, a, b, c, x, n, epsilon)
    q = trace_closest(scene, origin, d, FAR)
    reach = float(FAR)
    if q.result:
        reach = q.t
    weight = float(1.0)
    if has_glass != 0:
        weight = segment_transmittance(glass, glass_tn, glass_normal, origin, d, reach, epsilon)
    hit_weight[k] = weight
    if not q.result:
        if wp.dot(d, up) < 0.0:
            hit_face[k] = ESCAPED_GROUND
        else:
            hit_face[k] = ESCAPED_SKY
    elif q.sign > 0.0:
        hit_face[k] = q.face


@dataclass(frozen=True)
class GatherMatrix:
    """The traced gather of every face: G and the ground view."""

    matrix: sp.csr_matrix
    """(F, F) (or (F, columns)) float32: G[i, k] = sum of the transmittances of face i's rays that land on the front of face k,
    over the rays per face."""
    ground_view: np.ndarray
    """(F,) float32 share of face i's cosine-weighted hemisphere that leaves the scene below the horizon
    (times the glazing transmittance): its irradiance from a uniform ground of radiance L is pi L g_i."""
    rays: int


def trace_gather(tracer, corners: np.ndarray, normals: np.ndarray, *, rays: int, up: np.ndarray,
                 landing: np.ndarray, seed: int = 0, glazing=None, columns: int | None = None,
                 progress=lambda f: None) -> GatherMatrix:
    """Trace ``rays`` gather rays from each of the (F, 3, 3) faces through ``tracer``, whose triangle t is face
    ``landing[t]``, with the glass of ``glazing`` (``glazing.Glazing`` or None) attenuating them. The matrix is
    (F, F), or (F, ``columns``) when the faces that gather are not the faces light lands on (lightmap texels)."""
    corners = np.ascontiguousarray(corners, np.float32).reshape(-1, 3)
    normals = np.ascontiguousarray(normals, np.float32).reshape(-1, 3)
    count = len(normals)
    rays = int(rays)
    strata = max(1, int(np.floor(np.sqrt(rays))))
    glass = glass_arguments(tracer, glazing)
    up_wp = wp.vec3(*np.asarray(up, np.float32).tolist())
    rows, cols, weights = [], [], []
    ground = np.zeros(count, np.float64)
    for lo in range(0, count, FACES_PER_LAUNCH):
        hi = min(count, lo + FACES_PER_LAUNCH)
        items = (hi - lo) * rays
        face = wp.empty(items, dtype=int, device=tracer.device)
        weight = wp.empty(items, dtype=float, device=tracer.device)
        tracer.launch(gather_kernel, items, [
            tracer.scene, tracer.array(corners[3 * lo:3 * hi], wp.vec3), tracer.array(normals[lo:hi], wp.vec3),
            rays, strata, up_wp, tracer.epsilon, int(seed), lo, *glass, face, weight])
        face, weight = face.numpy(), weight.numpy()
        row = np.repeat(np.arange(lo, hi, dtype=np.int64), rays)
        landed = (face >= 0) & (weight > 0)
        rows.append(row[landed])
        cols.append(landing[face[landed]])
        weights.append(weight[landed])
        below = face == ESCAPED_GROUND
        np.add.at(ground, row[below], weight[below])
        progress(hi / max(1, count))
    tracer.rays_cast += int((np.linalg.norm(normals, axis=1) >= 0.5).sum()) * rays  # degenerate faces cast none
    matrix = sp.csr_matrix((np.concatenate(weights).astype(np.float32) / np.float32(rays),
                            (np.concatenate(rows), np.concatenate(cols))), shape=(count, count if columns is None else int(columns)),
                           dtype=np.float32)
    matrix.sum_duplicates()
    return GatherMatrix(matrix, (ground / rays).astype(np.float32), rays)
