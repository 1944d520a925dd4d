"""Sun visibility: the share of the solar disk each face sees, by shadow rays (Warp).

Shared by ``daylight`` (one sun position per time) and ``annual_daylight`` (one per sun bin).
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .sampling import tangent_frame, triangle_point
from .sky import SUN_ANGULAR_DIAMETER
from .tracer import FAR, triangle_origin

wp.set_module_options({"enable_backward": False})


@wp.kernel
def sun_visibility_kernel(
    start: int,
    mesh: wp.uint64,
    corners: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    sun: wp.vec3,
    cos_half_angle: float,
    samples: int,
    epsilon: float,
    seed: int,
    visible: wp.array(dtype=float),
):
    """Share of rays from random points of face i toward random points of the solar disk that escape.

    The sun's visibility S_i of Bosch, Besuievsky & Martin, Sec. 5 (they use a
    shadow map; here rays): directions uniform in solid angle over the cone of
    half-angle acos(``cos_half_angle``) about ``sun`` (the 0.53 degree disk;
    uniform cone sampling, Pharr, Jakob & Humphreys, "Physically Based
    Rendering" (3rd ed.), sec. 13.6.4), origins uniform on the face.
    Dimensionless in [0, 1]; rays below the face's horizon count as blocked.
    """
    i = start + wp.tid()
    n = normals[i]
    a = corners[3 * i]
    b = corners[3 * i + 1]
    c = corners[3 * i + 2]
    frame = tangent_frame(sun)
    state = wp.rand_init(seed, i)
    hits = int(0)
    for k in range(samples):
        cos_t = 1.0 - wp.randf(state) * (1.0 - cos_half_angle)
        sin_t = wp.sqrt(wp.max(0.0, 1.0 - cos_t * cos_t))
        phi = 2.0 * wp.pi * wp.randf(state)
        d = frame * wp.vec3(sin_t * wp.cos(phi), sin_t * wp.sin(phi), cos_t)
        x = triangle_point(a, b, c, wp.randf(state), wp.randf(state))
        if wp.dot(n, d) > 0.0:
            if not wp.mesh_query_ray_anyhit(mesh, triangle_origin(mesh, a, b, c, x, n, epsilon), d, FAR):
                hits += 1
    visible[i] = float(hits) / float(samples)


def compute_sun_visibility(tracer, corners: np.ndarray, normals: np.ndarray, sun: np.ndarray, *,
                           samples: int = 4, seed: int = 0) -> np.ndarray:
    """(F,) float32 share of the solar disk visible from each face (0 for faces turned away).

    S_i of the module docstring (Bosch, Besuievsky & Martin, Sec. 5: the sun's
    visibility from its current position); dimensionless, launches
    ``sun_visibility_kernel`` on the faces not wholly turned away.
    """
    corners = np.ascontiguousarray(corners, np.float32).reshape(-1, 3, 3)
    normals = np.ascontiguousarray(normals, np.float32).reshape(-1, 3)
    sun = np.asarray(sun, np.float64)
    sun = (sun / np.linalg.norm(sun)).astype(np.float32)
    result = np.zeros(len(corners), np.float32)
    facing = np.flatnonzero(normals @ sun > -math.sin(math.radians(SUN_ANGULAR_DIAMETER / 2)))
    if len(facing) == 0:
        return result
    visible = wp.zeros(len(facing), dtype=float, device=tracer.device)
    cos_half = math.cos(math.radians(SUN_ANGULAR_DIAMETER / 2))
    tracer.launch(sun_visibility_kernel, len(facing), [
        tracer.mesh.id, tracer.array(corners[facing].reshape(-1, 3), wp.vec3), tracer.array(normals[facing], wp.vec3),
        wp.vec3(*sun.tolist()), cos_half, int(samples), tracer.epsilon, int(seed), visible])
    tracer.rays_cast += len(facing) * samples
    result[facing] = visible.numpy()
    return result
