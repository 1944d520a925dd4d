"""Independent references the benchmarks and tests measure processors against.

They share the light model (kernels/lights.py) and the ray core (kernels/traversal.py, tested on its
own against a float64 brute force and Embree) with the processors, so they
check the transport, not the reading of lights: a path tracer for multi-bounce
indirect irradiance, a brute-force ray cast of one-bounce irradiance, and the
sky view of a point (cosine-weighted rays that escape, no sky patches).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from usdbake.kernels.light_bundles import emissive_lights, scene_lighting
from usdbake.kernels.lights import (Lights, Surfaces, hit_radiance, light_sample_count, path_indirect_irradiance,
                                     visible_light_sample)
from usdbake.kernels.sampling import cosine_hemisphere, strata_for, stratified_pair, tangent_frame
from usdbake.kernels.tracer import FAR, surface_origin
from usdbake.kernels.traversal import TraceScene, trace_any, trace_closest

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

PATH_CHUNKS = 16
"""Work items per point of the path tracer: paths are split so long runs use every thread."""


@wp.kernel
def indirect_paths_kernel(
    start: int,
    scene: TraceScene,
    surfaces: Surfaces,
    lights: Lights,
    positions: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    paths_per_item: int,
    chunks: int,
    bounces: int,
    epsilon: float,
    seed: int,
    out: wp.array(dtype=wp.vec3),
):
    """Sum over paths of the indirect irradiance estimate at point item // chunks
    (``path_indirect_irradiance``: the Neumann series truncated after ``bounces`` terms)."""
    item = start + wp.tid()
    v = item // chunks
    n = normals[v]
    total = wp.vec3(0.0, 0.0, 0.0)
    if wp.length(n) >= 0.5:
        for path in range(paths_per_item):
            total += path_indirect_irradiance(scene, surfaces, lights, positions[v], n, bounces, epsilon,
                                              wp.rand_init(seed, item * paths_per_item + path))
    out[item] = total


def path_traced_indirect(tracer, scene, positions, normals, *, paths: int, bounces: int = 3, seed: int = 7):
    """(N, 3) indirect irradiance (W/m^2) at points with unit normals, by path tracing."""
    per_item = max(1, paths // PATH_CHUNKS)
    lighting = scene_lighting(scene, tracer.device)
    out = wp.zeros(len(positions) * PATH_CHUNKS, dtype=wp.vec3, device=tracer.device)
    tracer.launch(indirect_paths_kernel, len(positions) * PATH_CHUNKS, [
        tracer.scene, lighting.surfaces, lighting.lights, tracer.array(positions, wp.vec3),
        tracer.array(normals, wp.vec3), per_item, PATH_CHUNKS, bounces, tracer.epsilon, seed, out])
    return out.numpy().reshape(len(positions), PATH_CHUNKS, 3).sum(axis=1) / (per_item * PATH_CHUNKS)


@wp.kernel
def point_irradiance_kernel(
    start: int,
    scene: TraceScene,
    surfaces: Surfaces,
    lights: Lights,
    positions: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    strata: int,
    seed: int,
    epsilon: float,
    include_direct: int,
    see_emission: int,
    irradiance: wp.array(dtype=wp.vec3),
):
    """E at point i with normal n by strata^2 cosine-weighted rays, E = pi / N sum L, with the incident
    radiance the irradiance grid sees (``hit_radiance`` at hits, the dome on escape), plus the small
    lights sampled directly as in the grid; ``include_direct`` 0 keeps only the one-bounce light."""
    i = start + wp.tid()
    n = normals[i]
    if wp.length(n) < 0.5:
        irradiance[i] = wp.vec3(0.0, 0.0, 0.0)
        return
    p = surface_origin(scene, positions[i], n, wp.vec3(0.0, 0.0, 0.0), epsilon)
    state = wp.rand_init(seed, i)
    frame = tangent_frame(n)
    samples = strata * strata
    total = wp.vec3(0.0, 0.0, 0.0)
    for k in range(samples):
        u = stratified_pair(k, strata, state)
        d = frame * cosine_hemisphere(u[0], u[1])
        q = trace_closest(scene, p, d, FAR)
        if not q.result:
            if include_direct != 0:
                total = total + lights.dome_radiance
        else:
            total = total + hit_radiance(scene, surfaces, lights, p, d, q.face, q.t, see_emission, epsilon,
                                         wp.rand_init(wp.int32(state), samples + k))
    result = total * (wp.pi / float(samples))
    if include_direct != 0:  # the small lights, as the grid samples them; domes are seen by the escaped rays
        for l in range(lights.light_kind.shape[0]):
            for k in range(light_sample_count(lights, l, strata)):
                s = visible_light_sample(scene, lights, l, p, k, strata, state)
                result = result + lights.light_radiance[l] * (s.weight * wp.max(wp.dot(n, s.direction), 0.0))
    irradiance[i] = result


def point_irradiance(tracer, scene, positions: np.ndarray, normals: np.ndarray, *, rays: int, seed: int = 0,
                     include_direct: bool = True) -> np.ndarray:
    """(N, 3) float32 irradiance (W/m^2) at surface points with unit normals by brute-force ray casting:
    the reference the irradiance grid's reconstruction is measured against."""
    positions = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    normals = np.ascontiguousarray(np.nan_to_num(normals), np.float32).reshape(-1, 3)
    if len(positions) == 0:
        return np.zeros((0, 3), np.float32)
    see_emission = int(bool(include_direct) and emissive_lights(scene))
    strata = strata_for(rays)
    lighting = scene_lighting(scene, tracer.device)
    out = wp.zeros(len(positions), dtype=wp.vec3, device=tracer.device)
    tracer.launch(point_irradiance_kernel, len(positions), [
        tracer.scene, lighting.surfaces, lighting.lights, tracer.array(positions, wp.vec3),
        tracer.array(normals, wp.vec3), strata, int(seed), tracer.epsilon, int(bool(include_direct)), see_emission,
        out,
    ])
    return np.nan_to_num(out.numpy(), nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32)


@wp.kernel
def point_sky_view_kernel(
    start: int,
    scene: TraceScene,
    positions: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    up: wp.vec3,
    strata: int,
    epsilon: float,
    seed: int,
    view: wp.array(dtype=float),
):
    """Brute-force reference: share of cosine-weighted rays that escape to the sky (above the horizon).

    Estimates E_sky / (pi L) under a uniform sky of radiance L (dimensionless),
    the quantity Bosch, Besuievsky & Martin, Sec. 5, Eq. 1 gives as
    sum_j V_ij dw_j / pi, without patches: Malley's cosine-weighted directions
    (pdf cos(theta) / pi per sr), a ray counting when it escapes and points
    above the horizon (``up``).
    """
    i = start + wp.tid()
    n = normals[i]
    view[i] = 0.0
    if wp.length(n) < 0.5:
        return
    frame = tangent_frame(n)
    state = wp.rand_init(seed, i)
    hits = int(0)
    origin = surface_origin(scene, positions[i], n, wp.vec3(0.0, 0.0, 0.0), epsilon)
    for k in range(strata * strata):
        u = stratified_pair(k, strata, state)
        d = frame * cosine_hemisphere(u[0], u[1])
        if wp.dot(d, up) > 0.0:
            if not trace_any(scene, origin, d, FAR):
                hits += 1
    view[i] = float(hits) / float(strata * strata)


def compute_point_sky_view(tracer, positions: np.ndarray, normals: np.ndarray, up: np.ndarray, *,
                           samples: int = 4096, seed: int = 0) -> np.ndarray:
    """(N,) float32 sky irradiance / (pi L) at points under a uniform sky L, black surroundings.

    Dimensionless; the reference for sum_j V_ij dw_j / pi of Bosch, Besuievsky &
    Martin, Sec. 5, Eq. 1 with a uniform sky (launches ``point_sky_view_kernel``).

    The independent reference the patch factors are checked against: stratified cosine-weighted
    hemisphere rays (no patches), a ray counting when it is unoccluded and points above the horizon.
    """
    positions = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    normals = np.ascontiguousarray(normals, np.float32).reshape(-1, 3)
    strata = strata_for(samples)
    view = wp.zeros(len(positions), dtype=float, device=tracer.device)
    up = np.asarray(up, np.float32)
    tracer.launch(point_sky_view_kernel, len(positions), [
        tracer.scene, tracer.array(positions, wp.vec3), tracer.array(normals, wp.vec3),
        wp.vec3(float(up[0]), float(up[1]), float(up[2])), strata, tracer.epsilon, int(seed), view])
    tracer.rays_cast += len(positions) * strata * strata
    return view.numpy()
