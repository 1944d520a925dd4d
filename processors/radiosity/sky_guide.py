"""Guided sky irradiance: the dome term of direct light with low variance where the sky is seen through
small openings.

Cosine-weighted rays estimate the sky's irradiance ``E = integral L(w) V(w) cos(theta) dw`` well under an
open sky, but in a room lit through a window only the few rays that leave through it carry light: with
64 rays and a window that fills 5 % of the cosine-weighted hemisphere, three rays decide a vertex.

Path guiding (Vorba, Karlik, Sik, Ritschel & Krivanek, "On-line learning of parametric mixture models for
light transport simulation", SIGGRAPH 2014; Mueller, Gross & Novak, "Practical path guiding", EGSR 2017)
learns where light arrives from and samples there. Here the learned density is piecewise constant over the
*primary sample square* of cosine-weighted directions: a direction is ``cosine_hemisphere(u)`` in the point's
``guide_frame`` for u in [0, 1)^2, and the square is split into GUIDE_SIDE^2 cells of equal cosine-weighted
solid angle (Malley's map preserves area). One density serves a *guide*: a group of nearby points facing one
axis (``guide_groups``), whose frames are continuous within the group.

1. **Learn** (``guide_training_kernel``): ``training`` stratified cosine rays a point; a ray that escapes
   adds the sky's luminance to its cell of the point's guide. As cos / pdf = pi is constant, the histogram
   estimates the integral of L V over each cell's cosine-weighted measure, pooled over the guide's points.
2. **Estimate** (``guided_sky_irradiance``): ``n_c`` stratified cosine rays and ``n_g`` rays that pick a
   cell by the guide's CDF and a uniform u inside it, combined by the balance heuristic (Veach & Guibas,
   SIGGRAPH 1995, eq. 11). Both densities carry the cosine (``p_c = cos / pi``, ``p_g = N P(cell) cos / pi``),
   so every sample w adds::

       pi L(w) V(w) / (n_c + n_g N P(cell(w)))

   Unbiased for any histogram (the cosine rays cover the hemisphere); under an open uniform sky every
   sample adds about pi L / (n_c + n_g), as cosine rays alone; and the training rays have a seed of their own,
   so the guide is not fitted to the samples it weighs.

Written here rather than taken from a library: the sampler runs inside Warp kernels next to the traversal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp
from scipy.ndimage import uniform_filter

from ...kernels.lights import LUMINANCE, Lights, shadow_visible, sky_radiance
from ...kernels.sampling import cosine_hemisphere, strata_for, stratified_pair
from ...kernels.tracer import FAR, surface_origin
from ...kernels.traversal import TraceScene

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

GUIDE_SIDE = 16
"""Cells along each side of the primary sample square."""
GUIDE_CELLS = GUIDE_SIDE * GUIDE_SIDE

GUIDE_POINTS = 256
"""Points per guide: groups are split at the median of their longest axis until they hold at most this many."""

GUIDE_SHARE = 0.75
"""Share of a point's estimate rays drawn from its guide (the rest cosine-weighted, stratified)."""


@wp.func
def guide_frame(n: wp.vec3) -> wp.mat33:
    """Orthonormal frame with n as third column, continuous over the normals of one guide group (those
    nearest one axis a): the tangent is built from the next axis (a + 1) mod 3, never near n."""
    a = int(0)
    if wp.abs(n[1]) > wp.abs(n[0]) and wp.abs(n[1]) >= wp.abs(n[2]):
        a = 1
    elif wp.abs(n[2]) > wp.abs(n[0]) and wp.abs(n[2]) > wp.abs(n[1]):
        a = 2
    reference = wp.vec3(0.0, 0.0, 0.0)
    reference[(a + 1) % 3] = 1.0
    t = wp.normalize(wp.cross(reference, n))
    return wp.matrix_from_cols(t, wp.cross(n, t), n)


@wp.func
def sample_cell(u: wp.vec2) -> int:
    x = wp.clamp(int(u[0] * float(GUIDE_SIDE)), 0, GUIDE_SIDE - 1)
    y = wp.clamp(int(u[1] * float(GUIDE_SIDE)), 0, GUIDE_SIDE - 1)
    return y * GUIDE_SIDE + x


@wp.func
def cell_probability(cdf: wp.array2d(dtype=float), g: int, b: int) -> float:
    below = float(0.0)
    if b > 0:
        below = cdf[g, b - 1]
    return cdf[g, b] - below


@wp.func
def pick_cell(cdf: wp.array2d(dtype=float), g: int, u: float) -> int:
    """The first cell whose running sum exceeds u (binary search over the guide's CDF row)."""
    lo = int(0)
    hi = GUIDE_CELLS - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if cdf[g, mid] > u:
            hi = mid
        else:
            lo = mid + 1
    return lo


@wp.func
def guided_sky_irradiance(scene: TraceScene, lights: Lights, p: wp.vec3, n: wp.vec3, cdf: wp.array2d(dtype=float),
                          g: int, split: wp.vec3i, epsilon: float, state: wp.uint32) -> wp.vec3:
    """Irradiance (W/m^2) at p with unit normal n from the dome lights (``sky_radiance``). ``split`` =
    (strata without a guide, cosine strata with one, guided rays): with guide g >= 0, cosine_strata^2
    stratified cosine rays and the guided rays from g's histogram under balance-heuristic weights (module
    docstring); without (g < 0), strata^2 cosine rays alone."""
    origin = surface_origin(scene, p, n, wp.vec3(0.0, 0.0, 0.0), epsilon)
    frame = guide_frame(n)
    cosine_strata = split[0]
    guided = int(0)
    if g >= 0:
        cosine_strata = split[1]
        guided = split[2]
    n_c = float(cosine_strata * cosine_strata)
    n_g = float(guided)
    e = wp.vec3(0.0, 0.0, 0.0)
    for k in range(cosine_strata * cosine_strata + guided):
        u = wp.vec2(0.0, 0.0)
        if k < cosine_strata * cosine_strata:
            u = stratified_pair(k, cosine_strata, state)
        else:
            rng = wp.rand_init(wp.int32(state), 0x6a09 + k)
            b = pick_cell(cdf, g, (float(k - cosine_strata * cosine_strata) + wp.randf(rng)) / n_g)
            y = b // GUIDE_SIDE
            u = wp.vec2(float(b - y * GUIDE_SIDE) + wp.randf(rng), float(y) + wp.randf(rng)) / float(GUIDE_SIDE)
        w = frame * cosine_hemisphere(u[0], u[1])
        if shadow_visible(scene, origin, w, FAR, epsilon) > 0.0:
            share = float(0.0)
            if guided > 0:
                share = n_g * float(GUIDE_CELLS) * cell_probability(cdf, g, sample_cell(u))
            e += sky_radiance(lights, w) * (wp.pi / (n_c + share))
    return e


@wp.kernel
def guide_training_kernel(start: int, scene: TraceScene, lights: Lights, positions: wp.array(dtype=wp.vec3),
                          normals: wp.array(dtype=wp.vec3), strata: int, luminance: wp.vec3, epsilon: float,
                          seed: int, cells: wp.array(dtype=int), weights: wp.array(dtype=float)):
    """Point i: strata^2 cosine rays; ray k writes the cell it was drawn in and, when it escapes, the sky's
    luminance along it (0 otherwise), at i * strata^2 + k. Summed per guide on the host, in a fixed order:
    float atomics would make the guide, and every estimate, depend on the thread schedule."""
    i = start + wp.tid()
    n = normals[i]
    samples = strata * strata
    if wp.length(n) < 0.5:
        for k in range(samples):
            cells[i * samples + k] = 0
            weights[i * samples + k] = 0.0
        return
    state = wp.rand_init(seed, i)
    origin = surface_origin(scene, positions[i], n, wp.vec3(0.0, 0.0, 0.0), epsilon)
    frame = guide_frame(n)
    for k in range(samples):
        u = stratified_pair(k, strata, state)
        w = frame * cosine_hemisphere(u[0], u[1])
        cells[i * samples + k] = sample_cell(u)
        weights[i * samples + k] = 0.0
        if shadow_visible(scene, origin, w, FAR, epsilon) > 0.0:
            weights[i * samples + k] = wp.dot(sky_radiance(lights, w), luminance)


@dataclass(frozen=True)
class SkyGuides:
    """Learned directional densities: ``cdf`` (G, GUIDE_CELLS) running sums, ``guide_of`` (N,) each point's
    guide or -1 (its guide saw no sky: cosine rays alone)."""

    cdf: wp.array2d
    guide_of: wp.array


def guide_groups(positions: np.ndarray, normals: np.ndarray, max_points: int = GUIDE_POINTS) -> np.ndarray:
    """(N,) group per point: points facing the same axis (+-x, +-y, +-z) split at the median of their
    longest extent until a group holds at most ``max_points``; a point without a normal gets -1."""
    positions = np.asarray(positions, np.float64).reshape(-1, 3)
    normals = np.asarray(normals, np.float64).reshape(-1, 3)
    axis = np.abs(normals).argmax(axis=1)
    facing = 2 * axis + (normals[np.arange(len(normals)), axis] < 0)
    groups = np.full(len(positions), -1, np.int64)
    pending = [np.flatnonzero((facing == f) & (np.linalg.norm(normals, axis=1) > 0.5)) for f in range(6)]
    count = 0
    while pending:
        members = pending.pop()
        if not len(members):
            continue
        if len(members) <= max_points:
            groups[members] = count
            count += 1
            continue
        span = positions[members].max(axis=0) - positions[members].min(axis=0)
        order = members[np.argsort(positions[members, int(span.argmax())], kind="stable")]
        half = len(order) // 2
        pending += [order[:half], order[half:]]
    return groups


def learn_sky_guides(tracer, lights: Lights, positions: np.ndarray, normals: np.ndarray, *, training: int,
                     seed: int) -> SkyGuides:
    """Guides for the points (scene frame, unit normals): ``training`` cosine rays per point (stratified,
    ``strata_for``) into each group's histogram, normalized to CDFs; groups that saw no sky get -1 (and
    every point with ``training`` 0)."""
    groups = guide_groups(positions, normals) if training > 0 else np.full(len(positions), -1)
    count = int(groups.max()) + 1 if len(groups) else 0
    strata = strata_for(training)
    sums = np.zeros((max(count, 1), GUIDE_CELLS))
    if count:
        samples = strata * strata
        cells = wp.zeros(len(positions) * samples, dtype=int, device=tracer.device)
        weights = wp.zeros(len(positions) * samples, dtype=float, device=tracer.device)
        tracer.launch(guide_training_kernel, len(positions), [
            tracer.scene, lights, tracer.array(positions, wp.vec3), tracer.array(normals, wp.vec3), strata,
            wp.vec3(*LUMINANCE.astype(np.float32)), tracer.epsilon, seed, cells, weights])
        tracer.rays_cast += len(positions) * samples
        bins = np.repeat(np.maximum(groups, 0), samples) * GUIDE_CELLS + cells.numpy()
        sums = np.bincount(bins, weights=weights.numpy().astype(np.float64),
                           minlength=count * GUIDE_CELLS).reshape(count, GUIDE_CELLS)
    # A 3 x 3 box over the cells: a histogram of a few rays a cell is noisy, and every sample's weight
    # pi L / (n_c + n_g N P) carries that noise to the estimate (an open sky's flat P most of all).
    sums = uniform_filter(sums.reshape(-1, GUIDE_SIDE, GUIDE_SIDE), size=(1, 3, 3),
                          mode="nearest").reshape(-1, GUIDE_CELLS)
    totals = sums.sum(axis=1)
    cdf = np.cumsum(sums, axis=1) / np.where(totals > 0, totals, 1.0)[:, None]
    cdf[:, -1] = np.where(totals > 0, 1.0, 0.0)
    seen = totals > 0
    guide_of = np.where((groups >= 0) & seen[np.maximum(groups, 0)], groups, -1).astype(np.int32)
    return SkyGuides(wp.array(cdf.astype(np.float32), dtype=float, device=tracer.device),
                     tracer.array(guide_of, int))


def guided_ray_split(sky_samples: int) -> wp.vec3i:
    """``split`` of ``guided_sky_irradiance`` for ``sky_samples`` rays a point: (strata of all of them as
    cosine rays, cosine strata and guided rays with GUIDE_SHARE of them guided)."""
    cosine = strata_for(max(1, round(sky_samples * (1.0 - GUIDE_SHARE))))
    return wp.vec3i(strata_for(sky_samples), cosine, max(0, sky_samples - cosine * cosine))
