"""The ambient-occlusion estimator: one ray sequence for ``ambient_occlusion`` and ``instance_ao``.

Ambient occlusion is the cosine-weighted visibility over the hemisphere
around the normal n (the obscurance of Zhukov, Iones & Kronin, "An ambient
light illumination model", EGWR 1998, with the distance mapping a step at
``max_distance``; the same integral opens Gaitatzes et al. 2008, Section 1)::

    AO(x) = 1/pi * integral_{H(n)} V(x, w) cos(theta) dw          (dimensionless, in [0, 1])

Drawing w with pdf cos(theta)/pi (Malley's method: the concentric disk map
lifted to the hemisphere; Pharr, Jakob & Humphreys, PBRT 3rd ed., Sections
13.6.2-13.6.3) cancels the cosine and the 1/pi in the Monte Carlo estimator
f/p (PBRT Section 13.2), so AO is the mean of V over the rays. The rays are
stratified: ray k of strata^2 draws its jitter in cell k of a strata x strata
grid over the unit square (PBRT Section 7.3), from a generator seeded by
(seed, point), so results do not depend on thread count or chunking.

Both AO processors take their rays from ``ao_direction`` and their settings
from one ``AORays``, so with the same seed they cast the same rays and differ
only in how V is found.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .sampling import cosine_hemisphere, strata_for, stratified_pair
from .tracer import FAR
from .traversal import TraceScene

wp.set_module_options({"enable_backward": False})



@wp.struct
class AORays:
    """How an AO kernel casts its rays (one struct for every AO kernel)."""

    scene: TraceScene
    """BVH the rays are tested against."""
    strata: int
    """strata x strata stratified directions per point."""
    max_distance: float
    """Hits farther than this (stage units) do not occlude; FAR for no limit."""
    epsilon: float
    """Ray origin offset along the normal (stage units): the tracer's ``epsilon``."""
    seed: int
    """Random seed; point i draws from ``wp.rand_init(seed, i)``."""


def ao_rays(scene: TraceScene, *, samples: int, max_distance: float, epsilon: float, seed: int) -> AORays:
    """An ``AORays`` for ``samples`` rays per point (rounded to a square, ``strata_for``)."""
    rays = AORays()
    rays.scene = scene
    rays.strata = strata_for(samples)
    rays.max_distance = float(min(max_distance, FAR))
    rays.epsilon = float(epsilon)
    rays.seed = int(seed)
    return rays


@wp.func
def ao_direction(rays: AORays, frame: wp.mat33, k: int, state: wp.uint32) -> wp.vec3:
    """Unit direction of ray k (0 <= k < strata^2) around the third column of ``frame`` (the normal).

    Stratum k of the unit square, jittered from ``state`` (``stratified_pair``), mapped by Malley's
    method (``cosine_hemisphere``): pdf cos(theta)/pi per sr (PBRT 3rd ed., Section 13.6.3).
    """
    u = stratified_pair(k, rays.strata, state)
    return frame * cosine_hemisphere(u[0], u[1])


def launch_ao(tracer, kernel, count: int, rays: AORays, inputs: list) -> np.ndarray:
    """Run ``kernel(start, rays, *inputs, ao)`` over ``count`` points on the tracer's device.

    Returns the (count,) float32 AO the kernel writes and adds the rays cast to ``tracer.rays_cast``.
    """
    ao = wp.zeros(count, dtype=float, device=tracer.device)
    tracer.launch(kernel, count, [rays, *inputs, ao])
    tracer.rays_cast += count * rays.strata * rays.strata
    return ao.numpy()


def as_points_and_normals(positions: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (N, 3) float32 contiguous points and normals an AO kernel takes; ValueError if they differ in shape."""
    positions = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    normals = np.ascontiguousarray(normals, np.float32).reshape(-1, 3)
    if positions.shape != normals.shape:
        raise ValueError(f"positions {positions.shape} and normals {normals.shape} differ")
    return positions, normals
