"""Direct lighting at a surface point from the Scene's lights, as Warp functions.

The same light model as ``light_probes`` (whose docstring states it in full,
and from which these functions were lifted so other processors can share them
without importing a processor): one shadow-ray sample per UsdLux light
(distant: radiance over the cone ``angle``, E = L Omega cos V, angle 0 = the
intensity is the irradiance; dome: E = pi L V with a cosine-weighted ray;
sphere: a direction in the subtended cone; rect/disk: a point on the emitter,
E = L A cos cos' / d^2 V) and, only when the stage has no UsdLux lights, one
emissive triangle picked by power.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..core.scene import LIGHT_DOME, Scene
from .sampling import concentric_disk, cosine_hemisphere, tangent_frame, triangle_point

wp.set_module_options({"enable_backward": False})

MIN_DISTANCE_RELATIVE = 1e-3
"""d^2 in area-light terms is clamped to (this * diagonal)^2, so a hit right next to a small
light does not produce a firefly of unbounded irradiance."""


@wp.func
def cone_direction(axis: wp.vec3, cos_max: float, u1: float, u2: float) -> wp.vec3:
    """Uniform direction in the cone of half-angle acos(cos_max) around unit axis."""
    z = 1.0 - u1 * (1.0 - cos_max)
    r = wp.sqrt(wp.max(0.0, 1.0 - z * z))
    phi = 2.0 * wp.pi * u2
    return tangent_frame(axis) * wp.vec3(r * wp.cos(phi), r * wp.sin(phi), z)


@wp.func
def distant_solid_angle(angle_degrees: float) -> float:
    """Solid angle (sr) of a distant light's cone of full apex angle ``angle``; 1 for angle 0 (the
    intensity of a zero-angle distant light is read as the irradiance it gives, a delta light)."""
    half = wp.min(wp.radians(angle_degrees) * 0.5, wp.pi)
    if half <= 0.0:
        return 1.0
    return 2.0 * wp.pi * (1.0 - wp.cos(half))


@wp.func
def visible(mesh: wp.uint64, origin: wp.vec3, direction: wp.vec3, max_t: float) -> float:
    if max_t <= 0.0:
        return 1.0
    if wp.mesh_query_ray_anyhit(mesh, origin, direction, max_t):
        return 0.0
    return 1.0


@wp.func
def area_sample(mesh: wp.uint64, p: wp.vec3, n: wp.vec3, origin: wp.vec3, q: wp.vec3, q_normal: wp.vec3,
                two_sided: int, area: float, epsilon: float, min_d2: float) -> float:
    """A cos cos' / d^2 V for a point q on an emitter facing q_normal (irradiance per unit radiance)."""
    to_q = q - p
    d2 = wp.dot(to_q, to_q)
    d = wp.sqrt(d2)
    if d <= 0.0:
        return 0.0
    w = to_q / d
    cos_x = wp.dot(n, w)
    cos_l = -wp.dot(q_normal, w)
    if two_sided != 0:
        cos_l = wp.abs(cos_l)
    if cos_x <= 0.0 or cos_l <= 0.0:
        return 0.0
    return area * cos_x * cos_l / wp.max(d2, min_d2) * visible(mesh, origin, w, d - 2.0 * epsilon)


@wp.func
def direct_at(
    mesh: wp.uint64, p: wp.vec3, n: wp.vec3,
    light_kind: wp.array(dtype=int), light_radiance: wp.array(dtype=wp.vec3),
    light_position: wp.array(dtype=wp.vec3), light_direction: wp.array(dtype=wp.vec3),
    light_size: wp.array(dtype=wp.vec2),
    emitter_vertices: wp.array(dtype=wp.vec3), emitter_normal: wp.array(dtype=wp.vec3),
    emitter_radiance: wp.array(dtype=wp.vec3), emitter_area: wp.array(dtype=float),
    emitter_two_sided: wp.array(dtype=int), emitter_cdf: wp.array(dtype=float),
    epsilon: float, min_d2: float, state: wp.uint32,
) -> wp.vec3:
    """Direct irradiance (W/m^2) at p, normal n: one shadow-ray sample per light (unbiased)."""
    e = wp.vec3(0.0, 0.0, 0.0)
    origin = p + n * epsilon
    for l in range(light_kind.shape[0]):
        kind = light_kind[l]
        axis = light_direction[l]
        size = light_size[l]
        u1 = wp.randf(state)
        u2 = wp.randf(state)
        acc = float(0.0)
        if kind == 0:  # distant: radiance L over the cone `angle`, E = L Omega cos V (angle 0: E = L cos V)
            w = -axis
            omega = distant_solid_angle(size[0])
            half = wp.radians(size[0]) * 0.5
            if half > 0.0:
                w = cone_direction(-axis, wp.cos(wp.min(half, wp.pi)), u1, u2)
            c = wp.dot(n, w)
            if c > 0.0:
                acc = omega * c * visible(mesh, origin, w, 3.0e38)
        elif kind == 1:  # dome: uniform radiance, E = pi L V with cosine-weighted w
            w = tangent_frame(n) * cosine_hemisphere(u1, u2)
            acc = wp.pi * visible(mesh, origin, w, 3.0e38)
        elif kind == 2:  # sphere: uniform direction in the subtended cone, E = L Omega cos V
            r = size[0]
            to_c = light_position[l] - p
            d = wp.length(to_c)
            if d <= r:
                acc = wp.pi
            elif r > 0.0:
                cos_max = wp.sqrt(wp.max(0.0, 1.0 - r * r / (d * d)))
                w = cone_direction(to_c / d, cos_max, u1, u2)
                c = wp.dot(n, w)
                if c > 0.0:
                    b = wp.dot(w, to_c)
                    t = b - wp.sqrt(wp.max(0.0, b * b - (d * d - r * r)))
                    acc = 2.0 * wp.pi * (1.0 - cos_max) * c * visible(mesh, origin, w, t - 2.0 * epsilon)
        else:  # rect (3) / disk (4), emitting along the light's -Z (axis)
            frame = tangent_frame(axis)
            tx = wp.vec3(frame[0, 0], frame[1, 0], frame[2, 0])
            ty = wp.vec3(frame[0, 1], frame[1, 1], frame[2, 1])
            q = light_position[l]
            area = size[0] * size[1]
            if kind == 3:
                q = q + tx * ((u1 - 0.5) * size[0]) + ty * ((u2 - 0.5) * size[1])
            else:
                area = wp.pi * size[0] * size[0]
                dsk = concentric_disk(u1, u2)
                q = q + tx * (dsk[0] * size[0]) + ty * (dsk[1] * size[0])
            acc = area_sample(mesh, p, n, origin, q, axis, 0, area, epsilon, min_d2)
        e += light_radiance[l] * acc
    count = emitter_area.shape[0]
    if count > 0:  # one emissive triangle picked by power, weighted by 1 / pmf
        u = wp.randf(state) * emitter_cdf[count - 1]
        lo = int(0)
        hi = count - 1
        while lo < hi:
            mid = (lo + hi) // 2
            if emitter_cdf[mid] < u:
                lo = mid + 1
            else:
                hi = mid
        below = float(0.0)
        if lo > 0:
            below = emitter_cdf[lo - 1]
        pmf = (emitter_cdf[lo] - below) / emitter_cdf[count - 1]
        if pmf > 0.0:
            q = triangle_point(emitter_vertices[3 * lo], emitter_vertices[3 * lo + 1], emitter_vertices[3 * lo + 2],
                               wp.randf(state), wp.randf(state))
            g = area_sample(mesh, p, n, origin, q, emitter_normal[lo], emitter_two_sided[lo], emitter_area[lo],
                            epsilon, min_d2)
            e += emitter_radiance[lo] * (g / pmf)
    return e


def use_emissive(scene: Scene) -> bool:
    """Emissive triangles light hit points only when the stage has no UsdLux lights (a fixture
    modelled as a light and as an emissive quad would count twice); they are always *seen*."""
    return len(scene.lights) == 0


def has_light(scene: Scene) -> bool:
    emissive = bool((scene.tri_emission.max(axis=1, initial=0.0) > 0).any()) if scene.num_triangles else False
    lit = bool((np.asarray(scene.lights.light_radiance).max(axis=1, initial=0.0) > 0).any()) \
        if len(scene.lights) else False
    return emissive or lit


class Lighting:
    """Device arrays of the scene's materials and lights for the capture kernels."""

    def __init__(self, tracer, scene: Scene):
        lights = scene.lights

        def arr(values, dtype, shape):
            return tracer.array(np.asarray(values, np.int32 if dtype is int else np.float32).reshape(shape), dtype)

        self.min_d2 = float((MIN_DISTANCE_RELATIVE * max(scene.diagonal, 1e-30)) ** 2)
        dome = np.asarray(lights.light_kind) == LIGHT_DOME
        self.dome = wp.vec3(*np.asarray(lights.light_radiance, np.float64)[dome].sum(axis=0).tolist()) \
            if dome.any() else wp.vec3(0.0, 0.0, 0.0)
        self.lights = [arr(lights.light_kind, int, (-1,)), arr(lights.light_radiance, wp.vec3, (-1, 3)),
                       arr(lights.light_position, wp.vec3, (-1, 3)), arr(lights.light_direction, wp.vec3, (-1, 3)),
                       arr(lights.light_size, wp.vec2, (-1, 2))]
        emissive = (scene.tri_emission.max(axis=1, initial=0.0) > 0) & (scene.tri_areas > 0) if use_emissive(scene) \
            else np.zeros(scene.num_triangles, bool)
        tris = np.flatnonzero(emissive)
        emission = scene.tri_emission[tris].astype(np.float64)
        power = (emission @ np.array([0.2126, 0.7152, 0.0722])) * scene.tri_areas[tris] \
            * np.where(scene.tri_double_sided[tris], 2.0, 1.0)
        self.emitters = [
            arr(scene.points[scene.tri_vertices[tris]].reshape(-1, 3), wp.vec3, (-1, 3)),
            arr(scene.tri_normals[tris], wp.vec3, (-1, 3)), arr(scene.tri_emission[tris], wp.vec3, (-1, 3)),
            arr(scene.tri_areas[tris], float, (-1,)), arr(scene.tri_double_sided[tris], int, (-1,)),
            arr(np.cumsum(np.maximum(power, 0.0)), float, (-1,)),
        ]
        self.geometry = [
            arr(scene.points, wp.vec3, (-1, 3)), tracer.array(np.asarray(scene.tri_vertices, np.int32).reshape(-1, 3),
                                                                wp.vec3i),
            arr(scene.tri_normals, wp.vec3, (-1, 3)), arr(scene.tri_albedo, wp.vec3, (-1, 3)),
            arr(scene.tri_emission, wp.vec3, (-1, 3)), arr(scene.tri_double_sided, int, (-1,)),
        ]
        self.tri_normals = self.geometry[2]
        self.tri_double_sided = self.geometry[5]
        self.shadow_rays = len(lights) + (1 if len(tris) else 0)
