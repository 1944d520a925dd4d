"""Light captured at points in free space: L2 SH of the incident radiance, and the inside test.

Sukys (Chalmers 2014), sections 2.3-2.4: a probe stores the irradiance SH of the
radiance it sees, E_lm = A_l L_lm (Ramamoorthi & Hanrahan 2001, eq. 7-8) with
L_lm = integral L(w) Y_lm(w) dw estimated by stratified uniform sphere rays.
Incident radiance is one bounce of the shared light model (kernels/lights.py:
emission + rho E0 / pi at hits, the dome on escape); small lights are sampled
directly and projected as the cones or areas they subtend. The inside test
(``classify_points``) votes with 26 fixed rays: a point that sees mostly the
backs of single-sided triangles is inside geometry.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ...core.scene import LIGHT_DOME, Scene
from ...kernels.light_bundles import SceneLighting, scene_lighting
from ...kernels.lights import (Lights, Surfaces, hit_radiance_bounces, light_sample_count, sky_radiance,
                               visible_light_sample)
from ...kernels.sampling import strata_for, stratified_pair
from ...kernels.sh import COSINE_LOBE, fibonacci_sphere_np, project_kernel, sh_basis, uniform_sphere
from ...kernels.tracer import FAR
from ...kernels.traversal import TraceScene, trace_any, trace_closest

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

SKY_RAYS_PER_RAY = 4
"""Sky visibility rays per capture ray while placing (``compute_probe_sh``'s ``sky_rays``): an any-hit ray
costs a small share of a capture ray (a closest hit plus a shadow ray per light and bounce at the hit), and
the sky seen through a window is what a few capture rays miss (the light_probes param ``sky_rays`` sets
the final capture's)."""

LIGHT_SAMPLES = 16
"""Stratified samples per small (non-dome) light and probe: a sphere, rect or disk light is too small
for the uniform capture rays to find, so it is sampled directly (soft shadows at 4 x 4)."""


def _directions_26() -> np.ndarray:
    d = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if (x, y, z) != (0, 0, 0)],
                 np.float64)
    return (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)


PROBE_DIRECTIONS = _directions_26()
"""(26, 3) the inside-test rays and Sukys' 26 sampling directions of an SH (axes + pair sums)."""

REVOTE_MARGIN = 2
"""A 26-ray vote within this many votes of a tie is cast again with REVOTE_DIRECTIONS rays: beside a wall, a
point inside a slab whose outer edge is the wall (the atrium's gallery floors) sees the wall's front through
a third of the 26 rays and ties, though most directions meet the backs of the slab's faces."""

REVOTE_DIRECTIONS = fibonacci_sphere_np(256).astype(np.float32)
"""(256, 3) the rays of a second vote (Fibonacci sphere, nearly uniform)."""


@wp.func
def probe_ray_direction(i: int, probe: int, strata: int, state: wp.uint32) -> wp.vec3:
    """Ray i's direction: stratum k = i - probe * strata^2 of a stratified uniform sphere, jittered by state."""
    u = stratified_pair(i - probe * strata * strata, strata, state)
    return uniform_sphere(u[0], u[1])


@wp.kernel
def capture_kernel(
    start: int,
    scene: TraceScene,
    surfaces: Surfaces,
    lights: Lights,
    probe_positions: wp.array(dtype=wp.vec3),
    strata: int,
    seed: int,
    first: int,
    bounces: int,
    see_sky: int,
    epsilon: float,
    directions: wp.array(dtype=wp.vec3),
    radiance: wp.array(dtype=wp.vec3),
):
    """Ray i = probe * strata^2 + k: incident radiance L(w) at the probe from stratified direction k
    (escaped rays see the dome, or nothing when ``see_sky`` is 0 and ``sky_kernel`` estimates the dome;
    hits return emission + ``bounces`` bounces of light, ``hit_radiance_bounces``); the Monte Carlo input
    of the SH projection, Sukys section 2.3 / Ramamoorthi & Hanrahan eq. 7.
    ``first``: global index of probe 0 (a chunk's start), which with i seeds the ray."""
    i = start + wp.tid()
    samples = strata * strata
    probe = i // samples
    state = wp.rand_init(seed, first * samples + i)
    d = probe_ray_direction(i, probe, strata, state)
    directions[i] = d
    origin = probe_positions[probe]
    q = trace_closest(scene, origin, d, FAR)
    value = wp.vec3(0.0, 0.0, 0.0)
    if see_sky != 0:
        value = sky_radiance(lights, d)
    if q.result:
        value = hit_radiance_bounces(scene, surfaces, lights, origin, d, q.face, q.t, 1, bounces, epsilon,
                                     wp.rand_init(wp.int32(state), samples))
    radiance[i] = value


@wp.kernel
def sky_kernel(
    start: int,
    scene: TraceScene,
    lights: Lights,
    probe_positions: wp.array(dtype=wp.vec3),
    strata: int,
    seed: int,
    first: int,
    directions: wp.array(dtype=wp.vec3),
    radiance: wp.array(dtype=wp.vec3),
):
    """Ray i = probe * strata^2 + k: the dome's part of L(w), sky_radiance(w) V(w), from stratified uniform
    direction k (an any-hit visibility ray; the capture rays then count only what they hit). The two
    integrals of L = L_sky V + L_hit (1 - V) are estimated apart, each unbiased, so the sky seen through a
    window gets many cheap rays while the hits keep their bounces (Sukys 2.3; the split is the direct /
    indirect separation of PBRT 4e, 13.4)."""
    i = start + wp.tid()
    samples = strata * strata
    probe = i // samples
    d = probe_ray_direction(i, probe, strata, wp.rand_init(seed, first * samples + i))
    directions[i] = d
    value = wp.vec3(0.0, 0.0, 0.0)
    if not trace_any(scene, probe_positions[probe], d, FAR):
        value = sky_radiance(lights, d)
    radiance[i] = value


@wp.kernel
def probe_lights_kernel(
    start: int,
    scene: TraceScene,
    lights: Lights,
    probe_positions: wp.array(dtype=wp.vec3),
    strata: int,
    seed: int,
    first: int,
    out: wp.array2d(dtype=float),
):
    """Radiance SH of the non-dome lights seen from probe i: L_k += L weight V Y_k(w) / count over
    ``light_sample_at`` samples (a small light is too concentrated for the uniform capture rays)."""
    i = start + wp.tid()
    p = probe_positions[i]
    state = wp.rand_init(seed, first + i)
    for l in range(lights.light_kind.shape[0]):
        for k in range(light_sample_count(lights, l, strata)):
            s = visible_light_sample(scene, lights, l, p, k, strata, state)
            if s.weight > 0.0:
                c = lights.light_radiance[l] * s.weight
                y = sh_basis(s.direction)
                for j in range(9):
                    out[i, 3 * j + 0] = out[i, 3 * j + 0] + y[j] * c[0]
                    out[i, 3 * j + 1] = out[i, 3 * j + 1] + y[j] * c[1]
                    out[i, 3 * j + 2] = out[i, 3 * j + 2] + y[j] * c[2]


@wp.kernel
def inside_kernel(
    start: int,
    scene: TraceScene,
    positions: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    surfaces: Surfaces,
    back_minus_front: wp.array(dtype=int),
    nearest: wp.array(dtype=float),
):
    """Back-face votes minus front-face votes of the 26 fixed rays from point i, and the nearest hit
    distance (Sukys 3.1.3 keeps probes offset above surfaces; this vote finds those inside geometry)."""
    i = start + wp.tid()
    p = positions[i]
    votes = int(0)
    near = FAR
    for k in range(directions.shape[0]):
        d = directions[k]
        q = trace_closest(scene, p, d, FAR)
        if q.result:
            near = wp.min(near, q.t)
            if surfaces.tri_double_sided[q.face] == 0:
                if wp.dot(surfaces.tri_normals[q.face], d) > 0.0:
                    votes += 1
                else:
                    votes -= 1
    back_minus_front[i] = votes
    nearest[i] = near


def compute_probe_sh(tracer, scene: Scene, positions: np.ndarray, *, rays: int, seed: int = 0,
                     lighting: SceneLighting | None = None, first: int = 0, bounces: int = 1,
                     direct_lights: bool = True, sky_rays: int | None = None) -> np.ndarray:
    """Irradiance SH (P, 9, 3) float32 (W/m^2) at probe positions (P, 3) in the scene frame.

    Radiance by ray casting with ``bounces`` bounces of light at the hits (module docstring),
    projected on L2 SH, plus (``direct_lights``) the non-geometric lights as visible point sources,
    convolved with the clamped cosine. Without ``direct_lights`` the probe holds what an engine's
    real-time lights leave out: the dome and light that bounced (Sukys 3.1.2, light decoupling).
    ``sky_rays``: visibility rays per probe (rounded to a square) that estimate the dome's part apart
    (``sky_kernel``), so a probe that sees the sky through a window is not decided by the few capture
    rays that leave through it; None: the capture rays see the dome themselves.
    ``first``: the global index of positions[0], which seeds its rays (a chunk of a larger set, core.chunks).
    """
    positions = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    count = len(positions)
    if count == 0:
        return np.zeros((0, 9, 3), np.float32)
    lighting = lighting or scene_lighting(scene, tracer.device)
    strata = strata_for(rays)
    samples = strata * strata
    probes_wp = tracer.array(positions, wp.vec3)
    directions = wp.zeros(count * samples, dtype=wp.vec3, device=tracer.device)
    radiance = wp.zeros(count * samples, dtype=wp.vec3, device=tracer.device)
    separate_sky = sky_rays is not None and has_dome(scene)
    tracer.launch(capture_kernel, count * samples, [
        tracer.scene, lighting.surfaces, lighting.lights, probes_wp, strata, int(seed), int(first), int(bounces),
        0 if separate_sky else 1, tracer.epsilon, directions, radiance,
    ])
    coefficients = wp.zeros((count, 27), dtype=float, device=tracer.device)
    tracer.launch(project_kernel, count, [directions, radiance, samples, coefficients])
    tracer.rays_cast += count * samples * bounces * (1 + lighting.shadow_rays)
    sky = np.zeros((count, 27))
    if separate_sky:
        sky = sky_radiance_sh(tracer, lighting, probes_wp, count, rays=int(sky_rays), seed=int(seed) + 2,
                              first=int(first))
    if direct_lights:
        light_strata = strata_for(LIGHT_SAMPLES)
        tracer.launch(probe_lights_kernel, count, [tracer.scene, lighting.lights, probes_wp, light_strata,
                                                   int(seed) + 1, int(first), coefficients])
        tracer.rays_cast += count * len(scene.lights) * LIGHT_SAMPLES
    radiance_sh = np.nan_to_num((coefficients.numpy().astype(np.float64) + sky).reshape(count, 9, 3),
                                nan=0.0, posinf=0.0, neginf=0.0)
    return (radiance_sh * COSINE_LOBE[None, :, None]).astype(np.float32)


def has_dome(scene: Scene) -> bool:
    """The scene has a dome light (escaped rays see something)."""
    return bool(len(scene.lights) and (np.asarray(scene.lights.light_kind) == LIGHT_DOME).any())


def sky_radiance_sh(tracer, lighting: SceneLighting, probes_wp: wp.array, count: int, *, rays: int, seed: int,
                    first: int) -> np.ndarray:
    """(count, 27) float64 radiance SH of the dome seen from the probes (``sky_kernel``: ``rays`` stratified
    visibility rays per probe, rounded to a square), in ``project_kernel``'s layout."""
    strata = strata_for(rays)
    samples = strata * strata
    directions = wp.zeros(count * samples, dtype=wp.vec3, device=tracer.device)
    radiance = wp.zeros(count * samples, dtype=wp.vec3, device=tracer.device)
    tracer.launch(sky_kernel, count * samples, [tracer.scene, lighting.lights, probes_wp, strata, seed, first,
                                                directions, radiance])
    coefficients = wp.zeros((count, 27), dtype=float, device=tracer.device)
    tracer.launch(project_kernel, count, [directions, radiance, samples, coefficients])
    tracer.rays_cast += count * samples
    return coefficients.numpy().astype(np.float64)


def _vote(tracer, lighting: SceneLighting, positions: np.ndarray, directions: np.ndarray):
    n = len(positions)
    votes = wp.zeros(n, dtype=int, device=tracer.device)
    nearest = wp.zeros(n, dtype=float, device=tracer.device)
    if n:
        tracer.launch(inside_kernel, n, [tracer.scene, tracer.array(positions, wp.vec3),
                                         tracer.array(directions, wp.vec3), lighting.surfaces, votes, nearest])
        tracer.rays_cast += n * len(directions)
    return votes.numpy(), nearest.numpy()


def classify_points(tracer, lighting: SceneLighting, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(inside (N,) bool, nearest hit distance (N,) float32) by the 26-ray back-face vote; votes within
    REVOTE_MARGIN of a tie are cast again with the REVOTE_DIRECTIONS (the nearest hit stays the 26 rays')."""
    positions = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    votes, nearest = _vote(tracer, lighting, positions, PROBE_DIRECTIONS)
    close = np.flatnonzero(np.abs(votes) <= REVOTE_MARGIN)
    if len(close):
        votes[close] = _vote(tracer, lighting, positions[close], REVOTE_DIRECTIONS)[0]
    return votes > 0, nearest


def probe_sh_chunk(tracer, first: int, positions: np.ndarray, *, scene: Scene, rays: int, seed: int,
                   bounces: int = 1, direct_lights: bool = True, sky_rays: int | None = None) -> np.ndarray:
    """``compute_probe_sh`` of probes first .. first + len(positions) - 1: one chunk (core.chunks)."""
    return compute_probe_sh(tracer, scene, positions, rays=rays, seed=seed, first=first, bounces=bounces,
                            direct_lights=direct_lights, sky_rays=sky_rays)


@wp.kernel
def direct_lights_kernel(
    start: int,
    scene: TraceScene,
    lights: Lights,
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    strata: int,
    seed: int,
    irradiance: wp.array(dtype=wp.vec3),
):
    """Direct irradiance at point i with normal n from the non-dome lights, as a real-time light adds it
    beside decoupled probes: E = sum_l L_l sum_k weight_k max(0, n . w_k) over ``visible_light_sample``
    (weight = Omega V / count; the exact clamped cosine, not its L2 projection)."""
    i = start + wp.tid()
    p = points[i]
    n = normals[i]
    state = wp.rand_init(seed, i)
    e = wp.vec3(0.0, 0.0, 0.0)
    for l in range(lights.light_kind.shape[0]):
        for k in range(light_sample_count(lights, l, strata)):
            s = visible_light_sample(scene, lights, l, p, k, strata, state)
            c = wp.dot(n, s.direction)
            if s.weight > 0.0 and c > 0.0:
                e += lights.light_radiance[l] * (s.weight * c)
    irradiance[i] = e


def direct_light_irradiance(tracer, scene: Scene, points: np.ndarray, normals: np.ndarray, *,
                            samples: int = LIGHT_SAMPLES, seed: int = 0,
                            lighting: SceneLighting | None = None) -> np.ndarray:
    """(N, 3) float32 irradiance (W/m^2) at points (N, 3, scene frame) with unit normals from the
    lights that are not geometry (distant, sphere, rect, disk), with shadow rays: what a cloud baked with
    ``direct_lights`` off leaves to the lookup (``direct_lights_kernel``)."""
    points = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
    n = len(points)
    out = wp.zeros(n, dtype=wp.vec3, device=tracer.device)
    if n and len(scene.lights):
        lighting = lighting or scene_lighting(scene, tracer.device)
        strata = strata_for(samples)
        tracer.launch(direct_lights_kernel, n, [tracer.scene, lighting.lights, tracer.array(points, wp.vec3),
                                                tracer.array(np.asarray(normals, np.float32).reshape(-1, 3), wp.vec3),
                                                strata, int(seed), out])
        tracer.rays_cast += n * len(scene.lights) * strata * strata
    return out.numpy()
