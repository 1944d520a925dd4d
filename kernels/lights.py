"""The one light model: a Scene's lights on the device and direct irradiance from them.

Every processor that lights surfaces (radiosity, light_probes,
irradiance_grid) and the benchmarks' references call these functions, so a
light is read the same way everywhere. Conventions (UsdLux, radiance in
W/(m^2 sr), irradiance in W/m^2):

- distant: ``light_radiance`` is the radiance over the cone of full apex
  angle ``angle``, ``E = L Omega <cos V>``; for angle 0 it is the irradiance
  on a surface facing the light (a delta light, ``E = L cos V``);
- dome: radiance L times the dome texture's texel in that direction
  (``sky_texel``: the first DomeLight with a lat-long ``texture:file``, OpenEXR
  layout in the dome's frame, nearest texel; 1 without a texture, and for
  the other domes of a stage with a textured one), ``E = pi
  <L T V>`` with cosine-weighted directions; rays that escape the scene see
  ``sky_radiance``, the sum of the dome lights times the texel;
- sphere: directions uniform in the subtended cone, ``E = L Omega <cos V>``
  (a point inside the sphere gets ``E = pi L``);
- rect / disk: uniform points q on the emitter, whose plane is normal to the
  light's -Z (in-plane axes from a tangent frame, so a non-square rect
  light's roll about its axis is not honoured), ``E = L A <cos cos' / d^2 V>``;
- emissive triangles (``emissiveColor`` as radiance): area lights picked in
  proportion to their power, one-sided unless double-sided. By default they
  light the scene only when it has no UsdLux lights (a fixture modelled as a
  RectLight *and* an emissive quad would count twice); their emission is
  always *seen* by rays that hit them.

The 1/d^2 of a sample next to the shaded point is bounded by
``min_d2 = (MIN_DISTANCE_RELATIVE * diagonal)^2`` (``light_bundles``). Shadow rays start at
``p + n epsilon`` and step ``epsilon`` along the ray (``shadow_visible``), so a
point on the seam of two meshes (a floor corner under a wall) does not hit
the neighbouring surface at t = 0.

References: Pharr, Jakob & Humphreys, Physically Based Rendering (4th ed.),
ch. 12 (light sources) and 13.4 (direct lighting, sampling lights by power);
the UsdLux schema for each light's quantities.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .sampling import concentric_disk, cosine_hemisphere, stratified_pair, tangent_frame, triangle_point
from .tracer import FAR, surface_origin
from .traversal import TraceScene, trace_any, trace_closest

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

AREA_SHADOW_SHORTENING = 1e-4
"""Shadow rays towards a point on an area light stop this fraction short of it, so the emitter's own
surface (a quad modelled at the light) does not occlude its light."""


LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
"""Rec. 709 luminance weights of linear RGB: the power an emissive triangle is picked by, the tone maps'
exposure, light-probe placement. Cast with ``.astype(np.float32)`` for float32 products."""


@wp.struct
class Lights:
    """A Scene's UsdLux lights and emissive triangles on the device, one bundle for every kernel."""

    light_kind: wp.array(dtype=int)
    """(L,) one of core.scene.LIGHT_DISTANT .. LIGHT_DISK."""
    light_radiance: wp.array(dtype=wp.vec3)
    light_position: wp.array(dtype=wp.vec3)
    light_direction: wp.array(dtype=wp.vec3)
    """(L,) unit emission direction (the light's -Z)."""
    light_size: wp.array(dtype=wp.vec2)
    """(L,) radius (sphere, disk), width/height (rect) or apex angle in degrees (distant)."""
    light_textured: wp.array(dtype=int)
    """(L,) 1 for the dome whose texture ``sky_map`` is (every dome when the Scene does not say which)."""
    dome_radiance: wp.vec3
    """Sum of the dome lights' radiance."""
    textured_radiance: wp.vec3
    """The part of ``dome_radiance`` that ``sky_texel`` modulates (the textured dome's)."""
    sky_map: wp.array2d(dtype=wp.vec3)
    """(H, W) lat-long texture of the textured dome, or one texel of 1 (no texture)."""
    sky_to_local: wp.mat33
    """World direction -> the dome's frame (column-vector convention: local = sky_to_local * d)."""
    emitter_vertices: wp.array(dtype=wp.vec3)
    """(3E,) corners of the emissive triangles that act as lights."""
    emitter_normal: wp.array(dtype=wp.vec3)
    emitter_radiance: wp.array(dtype=wp.vec3)
    emitter_area: wp.array(dtype=float)
    emitter_two_sided: wp.array(dtype=int)
    emitter_cdf: wp.array(dtype=float)
    """(E,) running sum of the emitters' power (luminance * area * sides)."""
    min_d2: float


@wp.struct
class Surfaces:
    """What a ray hit shows: per-triangle normal, albedo, emitted radiance and sidedness."""

    tri_normals: wp.array(dtype=wp.vec3)
    tri_albedo: wp.array(dtype=wp.vec3)
    tri_emission: wp.array(dtype=wp.vec3)
    tri_double_sided: wp.array(dtype=int)


@wp.struct
class LightSample:
    """One sample of a light seen from a point: E = L * weight * cos * V estimates its irradiance."""

    direction: wp.vec3
    """Unit direction from the point towards the sample."""
    weight: float
    """Solid angle the sample stands for (sr): Omega for cones, A cos' / d^2 for area lights; 0: none."""
    distance: float
    """Length of the shadow ray that tests the sample."""


# ---------------------------------------------------------------------------
# Device functions


@wp.func
def cone_direction(axis: wp.vec3, cos_max: float, u1: float, u2: float) -> wp.vec3:
    """Uniform direction in the cone of half-angle acos(cos_max) around unit axis (PBRT 4e, 12.4)."""
    z = 1.0 - u1 * (1.0 - cos_max)
    r = wp.sqrt(wp.max(0.0, 1.0 - z * z))
    phi = 2.0 * wp.pi * u2
    return tangent_frame(axis) * wp.vec3(r * wp.cos(phi), r * wp.sin(phi), z)


@wp.func
def distant_solid_angle(angle_degrees: float) -> float:
    """Solid angle (sr) of a distant light's cone of full apex angle ``angle``, 2 pi (1 - cos(angle/2));
    1 for angle 0 (the intensity of a zero-angle distant light is read as the irradiance it gives)."""
    half = wp.min(wp.radians(angle_degrees) * 0.5, wp.pi)
    if half <= 0.0:
        return 1.0
    return 2.0 * wp.pi * (1.0 - wp.cos(half))


@wp.func
def sky_texel(lights: Lights, d: wp.vec3) -> wp.vec3:
    """The dome texture's value along unit world direction d, nearest texel. OpenEXR lat-long layout in
    the dome's frame (UsdLux DomeLight: +Y the pole): latitude asin(y), longitude atan2(x, z) (0 towards
    +z, pi/2 towards +x); column (pi - longitude) / 2 pi, row (pi/2 - latitude) / pi of the image."""
    height = lights.sky_map.shape[0]
    width = lights.sky_map.shape[1]
    local = lights.sky_to_local * d
    latitude = wp.asin(wp.clamp(local[1], -1.0, 1.0))
    longitude = wp.atan2(local[0], local[2])
    column = wp.clamp(int((wp.pi - longitude) / (2.0 * wp.pi) * float(width)), 0, width - 1)
    row = wp.clamp(int((0.5 * wp.pi - latitude) / wp.pi * float(height)), 0, height - 1)
    return lights.sky_map[row, column]


@wp.func
def sky_radiance(lights: Lights, d: wp.vec3) -> wp.vec3:
    """Radiance (W/(m^2 sr)) a ray leaving the scene along unit d sees: the textured dome's times the
    texel, plus the uniform domes'."""
    return wp.cw_mul(lights.textured_radiance, sky_texel(lights, d)) + lights.dome_radiance - lights.textured_radiance


@wp.func
def shadow_visible(scene: TraceScene, origin: wp.vec3, direction: wp.vec3, distance: float, epsilon: float) -> float:
    """V: 1 if nothing lies along the ray within ``distance``. The origin also steps ``epsilon`` along the
    ray: a point on the seam of two meshes would otherwise hit the neighbouring surface at t = 0."""
    if distance <= epsilon:
        return 1.0
    if trace_any(scene, origin + direction * epsilon, direction, distance - epsilon):
        return 0.0
    return 1.0


@wp.func
def is_delta_light(lights: Lights, l: int) -> bool:
    """A zero-angle distant light: one direction, one sample, no random numbers."""
    return lights.light_kind[l] == 0 and lights.light_size[l][0] <= 0.0


@wp.func
def area_light_sample(p: wp.vec3, q: wp.vec3, emit_normal: wp.vec3, two_sided: int, area: float,
                      min_d2: float) -> LightSample:
    """Point q on an emitter of area A facing emit_normal: weight A cos' / max(d^2, min_d2) (PBRT 4e, 12.2)."""
    s = LightSample()
    s.direction = wp.vec3(0.0, 0.0, 1.0)
    s.weight = 0.0
    s.distance = 0.0
    v = q - p
    d2 = wp.dot(v, v)
    if d2 > 0.0:
        d = wp.sqrt(d2)
        s.direction = v / d
        cos_l = -wp.dot(emit_normal, s.direction)
        if two_sided != 0:
            cos_l = wp.abs(cos_l)
        if cos_l > 0.0:
            s.weight = area * cos_l / wp.max(d2, min_d2)
            s.distance = d * (1.0 - AREA_SHADOW_SHORTENING)
    return s


@wp.func
def sample_light(lights: Lights, l: int, p: wp.vec3, u1: float, u2: float) -> LightSample:
    """One sample of non-dome light l seen from p (conventions in the module docstring); weight 0 for a
    dome light and for a point inside a sphere light."""
    kind = lights.light_kind[l]
    axis = lights.light_direction[l]
    size = lights.light_size[l]
    s = LightSample()
    s.direction = -axis
    s.weight = 0.0
    s.distance = FAR
    if kind == 0:  # distant: a direction in the cone `angle`, weight Omega (angle 0: -axis, weight 1)
        s.weight = distant_solid_angle(size[0])
        half = wp.radians(size[0]) * 0.5
        if half > 0.0:
            s.direction = cone_direction(-axis, wp.cos(wp.min(half, wp.pi)), u1, u2)
    elif kind == 2:  # sphere: a direction in the subtended cone, weight Omega
        r = size[0]
        to_c = lights.light_position[l] - p
        d = wp.length(to_c)
        if d > r and r > 0.0:
            cos_max = wp.sqrt(wp.max(0.0, 1.0 - r * r / (d * d)))
            s.direction = cone_direction(to_c / d, cos_max, u1, u2)
            s.weight = 2.0 * wp.pi * (1.0 - cos_max)
            b = wp.dot(s.direction, to_c)
            s.distance = b - wp.sqrt(wp.max(0.0, b * b - (d * d - r * r)))
    elif kind == 3 or kind == 4:  # rect / disk: a point on the emitter, weight A cos' / d^2
        frame = tangent_frame(axis)
        tx = wp.vec3(frame[0, 0], frame[1, 0], frame[2, 0])
        ty = wp.vec3(frame[0, 1], frame[1, 1], frame[2, 1])
        q = lights.light_position[l]
        area = size[0] * size[1]
        if kind == 3:
            q = q + tx * ((u1 - 0.5) * size[0]) + ty * ((u2 - 0.5) * size[1])
        else:
            area = wp.pi * size[0] * size[0]
            dsk = concentric_disk(u1, u2)
            q = q + tx * (dsk[0] * size[0]) + ty * (dsk[1] * size[0])
        s = area_light_sample(p, q, axis, 0, area, lights.min_d2)
    return s


@wp.func
def light_sample_count(lights: Lights, l: int, strata: int) -> int:
    """strata^2 stratified samples per light; 1 for a delta light; 0 for a dome (sampled by rays that escape)."""
    if lights.light_kind[l] == 1:
        return 0
    if is_delta_light(lights, l):
        return 1
    return strata * strata


@wp.func
def light_sample_at(lights: Lights, l: int, p: wp.vec3, k: int, strata: int, state: wp.uint32) -> LightSample:
    """Sample k of light l from p: stratified cell k of a strata x strata grid (a delta light uses none)."""
    u = wp.vec2(0.5, 0.5)
    if not is_delta_light(lights, l):
        u = stratified_pair(k, strata, state)
    return sample_light(lights, l, p, u[0], u[1])


@wp.func
def visible_light_sample(scene: TraceScene, lights: Lights, l: int, p: wp.vec3, k: int, strata: int,
                         state: wp.uint32) -> LightSample:
    """Sample k of light l seen from a point p in free space, its shadow ray cast: weight = Omega V / count,
    so sum_k L weight estimates the light's part of integral L dw (zero for a dome light, which escaped
    rays see, and for an occluded sample). Vector irradiance and SH projections sum L weight f(w)."""
    s = light_sample_at(lights, l, p, k, strata, state)
    if s.weight > 0.0:
        s.weight = s.weight * shadow_visible(scene, p, s.direction, s.distance, 0.0) / float(
            light_sample_count(lights, l, strata))
    return s


@wp.func
def pick_emitter(lights: Lights, u: float) -> int:
    """Index of the emissive triangle whose power-CDF interval holds u * total power (binary search)."""
    count = lights.emitter_area.shape[0]
    target = u * lights.emitter_cdf[count - 1]
    lo = int(0)
    hi = count - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if lights.emitter_cdf[mid] < target:
            lo = mid + 1
        else:
            hi = mid
    return lo


@wp.func
def emitter_pmf(lights: Lights, t: int) -> float:
    """Probability of picking emissive triangle t (its share of the total power)."""
    below = float(0.0)
    if t > 0:
        below = lights.emitter_cdf[t - 1]
    return (lights.emitter_cdf[t] - below) / lights.emitter_cdf[lights.emitter_area.shape[0] - 1]


@wp.func
def direct_irradiance(scene: TraceScene, lights: Lights, p: wp.vec3, n: wp.vec3, strata: int, sky_strata: int,
                      epsilon: float, state: wp.uint32) -> wp.vec3:
    """Direct irradiance E0 (W/m^2) at p with unit normal n: E0 = sum_l L_l <weight cos V> over strata^2
    stratified samples per light (sky_strata^2 cosine-weighted rays per dome light, E = pi L <V>) plus
    strata^2 emissive-triangle samples picked by power (weight / pmf). Unbiased; ``state`` must differ
    between calls that should be independent (the samples are drawn from generators seeded by it)."""
    e = wp.vec3(0.0, 0.0, 0.0)
    origin = surface_origin(scene, p, n, wp.vec3(0.0, 0.0, 0.0), epsilon)
    for l in range(lights.light_kind.shape[0]):
        acc = float(0.0)
        if lights.light_kind[l] == 1:  # dome
            frame = tangent_frame(n)
            sky = sky_strata * sky_strata
            textured = wp.vec3(0.0, 0.0, 0.0)
            for k in range(sky):
                u = stratified_pair(k, sky_strata, state)
                w = frame * cosine_hemisphere(u[0], u[1])
                texel = wp.vec3(1.0, 1.0, 1.0)
                if lights.light_textured[l] != 0:
                    texel = sky_texel(lights, w)
                textured += texel * (shadow_visible(scene, origin, w, FAR, epsilon) * (wp.pi / float(sky)))
            e += wp.cw_mul(lights.light_radiance[l], textured)
        elif lights.light_kind[l] == 2 and wp.length(lights.light_position[l] - p) <= lights.light_size[l][0]:
            acc = wp.pi  # inside a sphere light: radiance from every direction of the hemisphere
        else:
            count = light_sample_count(lights, l, strata)
            inv = 1.0 / float(count)
            for k in range(count):
                s = light_sample_at(lights, l, p, k, strata, state)
                c = wp.dot(n, s.direction)
                if s.weight > 0.0 and c > 0.0:
                    acc += s.weight * c * shadow_visible(scene, origin, s.direction, s.distance - 2.0 * epsilon,
                                                         epsilon) * inv
        e += lights.light_radiance[l] * acc
    if lights.emitter_area.shape[0] > 0:
        samples = strata * strata
        pick_state = wp.rand_init(wp.int32(state), -1)
        for k in range(samples):
            t = pick_emitter(lights, wp.randf(pick_state))
            pmf = emitter_pmf(lights, t)
            if pmf > 0.0:
                u = stratified_pair(k, strata, state)
                q = triangle_point(lights.emitter_vertices[3 * t], lights.emitter_vertices[3 * t + 1],
                                   lights.emitter_vertices[3 * t + 2], u[0], u[1])
                s = area_light_sample(p, q, lights.emitter_normal[t], lights.emitter_two_sided[t],
                                      lights.emitter_area[t], lights.min_d2)
                c = wp.dot(n, s.direction)
                if s.weight > 0.0 and c > 0.0:
                    v = shadow_visible(scene, origin, s.direction, s.distance - 2.0 * epsilon, epsilon)
                    e += lights.emitter_radiance[t] * (s.weight * c * v / (pmf * float(samples)))
    return e


@wp.func
def hit_radiance(scene: TraceScene, surfaces: Surfaces, lights: Lights, origin: wp.vec3, d: wp.vec3, tri: int,
                 t: float, see_emission: int, epsilon: float, state: wp.uint32) -> wp.vec3:
    """Radiance L(origin, -d) leaving the surface a ray hit, one bounce: L_e + rho E0 / pi for a
    Lambertian surface with E0 by ``direct_irradiance`` (one sample per light); zero on the back of a
    single-sided triangle (the rendering equation truncated after the first bounce). The ray
    origin + t d hit triangle ``tri``."""
    n = surfaces.tri_normals[tri]
    front = wp.dot(n, d) < 0.0
    value = wp.vec3(0.0, 0.0, 0.0)
    if (front or surfaces.tri_double_sided[tri] != 0) and wp.length(n) > 0.5:
        if not front:
            n = -n
        e = direct_irradiance(scene, lights, origin + d * t, n, 1, 1, epsilon, state)
        value = wp.cw_mul(surfaces.tri_albedo[tri], e) / wp.pi
        if see_emission != 0:
            value = value + surfaces.tri_emission[tri]
    return value


@wp.func
def path_indirect_irradiance(scene: TraceScene, surfaces: Surfaces, lights: Lights, p: wp.vec3, n: wp.vec3,
                             bounces: int, epsilon: float, state: wp.uint32) -> wp.vec3:
    """One path's estimate of the indirect irradiance at p with unit normal n: a cosine-weighted path
    x -> y1 -> y2 ... gives E_ind(x) ~ sum_h (rho(y1) ... rho(yh)) E0(yh), E0 by one next-event sample per
    light (the Neumann series of the radiosity equation truncated after ``bounces`` terms); a back face
    absorbs the path, as in the form factors. ``state`` seeds this path only (pass a fresh one per path)."""
    rng = wp.rand_init(wp.int32(state), 0x5bd1)
    total = wp.vec3(0.0, 0.0, 0.0)
    x = p
    normal = n
    throughput = wp.vec3(1.0, 1.0, 1.0)
    for h in range(bounces):
        w = tangent_frame(normal) * cosine_hemisphere(wp.randf(rng), wp.randf(rng))
        origin = surface_origin(scene, x, normal, wp.vec3(0.0, 0.0, 0.0), epsilon)
        q = trace_closest(scene, origin, w, FAR)
        if not q.result:
            break
        hn = surfaces.tri_normals[q.face]
        if wp.dot(w, hn) >= 0.0 or wp.length(hn) < 0.5:
            break
        x = origin + w * q.t
        normal = hn
        throughput = wp.cw_mul(throughput, surfaces.tri_albedo[q.face])
        total += wp.cw_mul(throughput, direct_irradiance(scene, lights, x, normal, 1, 1, epsilon,
                                                         wp.rand_init(wp.int32(state), h)))
    return total


@wp.func
def hit_radiance_bounces(scene: TraceScene, surfaces: Surfaces, lights: Lights, origin: wp.vec3, d: wp.vec3,
                         tri: int, t: float, see_emission: int, bounces: int, epsilon: float,
                         state: wp.uint32) -> wp.vec3:
    """``hit_radiance`` with interreflection: L = L_e + rho (E0 + E_ind) / pi at the hit, E_ind by one path
    of ``bounces - 1`` bounces (``path_indirect_irradiance``); ``bounces`` 1 is ``hit_radiance``."""
    value = hit_radiance(scene, surfaces, lights, origin, d, tri, t, see_emission, epsilon, state)
    n = surfaces.tri_normals[tri]
    front = wp.dot(n, d) < 0.0
    if bounces > 1 and (front or surfaces.tri_double_sided[tri] != 0) and wp.length(n) > 0.5:
        if not front:
            n = -n
        e = path_indirect_irradiance(scene, surfaces, lights, origin + d * t, n, bounces - 1, epsilon,
                                     wp.rand_init(wp.int32(state), 0x2c1b))
        value = value + wp.cw_mul(surfaces.tri_albedo[tri], e) / wp.pi
    return value
