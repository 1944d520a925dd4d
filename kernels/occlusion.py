"""The ambient-occlusion estimator: one ray sequence for ``ambient_occlusion`` and ``instance_ao``.

Ambient occlusion is the cosine-weighted visibility over the hemisphere
around the normal n (the obscurance of Zhukov, Iones & Kronin, "An ambient
light illumination model", EGWR 1998, with the distance mapping a step at
``max_distance``; the same integral opens Gaitatzes et al. 2008, Section 1)::

    AO(x) = 1/pi * integral_{H(n)} V(x, w) cos(theta) dw          (dimensionless, in [0, 1])

Drawing w with pdf cos(theta)/pi (Malley's method: the concentric disk map lifted to the hemisphere;
Pharr, Jakob & Humphreys, PBRT 3rd ed., Sections 13.6.2-13.6.3) cancels the cosine and the 1/pi in the
Monte Carlo estimator f/p (PBRT Section 13.2), so AO is the mean of V over the rays.

The rays are stratified: ray k of strata^2 is jittered inside cell k of a strata x strata grid over the
unit square (PBRT Section 7.3; column k % strata, row k // strata, corners from a table rather than an
integer division per ray). The jitter of ray k is one hash of (point, k) (``wp.rand_init(seed, point) + k``
through PCG; Jarzynski & Olano, "Hash functions for GPU rendering", JCGT 9(3), 2020) split into two 16-bit
uniforms, where a generator seeded per ray and two draws from it cost four, so results do not depend on
thread count or chunking. The kernels make ray k + 1's direction before tracing ray k (``occlusion_at``):
the trace cannot start before its direction, and made in advance its latency hides behind the trace.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .sampling import cosine_hemisphere, strata_for, tangent_frame
from .tracer import FAR
from .traversal import TraceScene

wp.set_module_options({"enable_backward": False, "fuse_fp": False})



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
    """Random seed; ray k of point i jitters by a hash of (``wp.rand_init(seed, i)``, k)."""
    cells: wp.array(dtype=wp.vec2)
    """(strata^2,) cell k's corner (column / strata, row / strata): a table, not an integer division per ray."""


@wp.struct
class AOPoint:
    """One point's rays: its frame (the normal as third column) and the state its jitters hash."""

    frame: wp.mat33
    state: wp.uint32


def ao_rays(scene: TraceScene, *, samples: int, max_distance: float, epsilon: float, seed: int,
            device=None) -> AORays:
    """An ``AORays`` for ``samples`` rays per point (rounded to a square, ``strata_for``), its cell table
    stored on ``device`` (default: Warp's)."""
    rays = AORays()
    rays.scene = scene
    rays.strata = strata_for(samples)
    rays.max_distance = float(min(max_distance, FAR))
    rays.epsilon = float(epsilon)
    rays.seed = int(seed)
    rays.cells = wp.array(stratum_table(rays.strata), dtype=wp.vec2, device=device)
    return rays


def stratum_table(strata: int) -> np.ndarray:
    """(strata^2, 2) float32 corners (column / strata, row / strata) of cell k, at column k % strata and row
    k // strata of the strata x strata grid over the unit square."""
    cells = np.arange(strata * strata)
    return (np.stack([cells % strata, cells // strata], axis=1) / strata).astype(np.float32)


@wp.func
def ao_point(rays: AORays, n: wp.vec3, point: int) -> AOPoint:
    """The rays of point ``point`` (its index seeds them) with unit normal n."""
    point_rays = AOPoint()
    point_rays.frame = tangent_frame(n)
    point_rays.state = wp.rand_init(rays.seed, point)
    return point_rays


@wp.func
def ao_direction(rays: AORays, point: AOPoint, k: int) -> wp.vec3:
    """Unit direction of ray k (0 <= k < strata^2): a uniform point of cell k, jittered by the hash of
    (point.state + k), mapped by Malley's method (``cosine_hemisphere``), pdf cos(theta)/pi per sr (PBRT 3rd
    ed., Section 13.6.3), in the point's frame."""
    bits = wp.rand_init(wp.int32(point.state + wp.uint32(k)))
    cell = rays.cells[k] + wp.vec2(float(bits >> wp.uint32(16)), float(bits & wp.uint32(65535))) * (
        1.0 / (65536.0 * float(rays.strata)))
    return point.frame * cosine_hemisphere(cell[0], cell[1])


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
