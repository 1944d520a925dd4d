"""The light model (kernels/lights.py): each light's direct irradiance against a closed form or a float64
quadrature of its own written here in numpy (no sampling, no Warp), shadows, the one-bounce radiance at a
hit and one indirect path. The host side (bundles, counts) is tested in test_light_bundles.py.

No ``from __future__ import annotations`` here: Warp reads the test kernels' annotations as objects.
"""

import math

import numpy as np
import pytest
import warp as wp
from lit_scenes import make_lights, make_scene, merge, quad
from open_irradiance import direct_irradiance_at
from tolerances import DIRECT_TOLERANCE, FLOAT32_ACCUMULATED, FLOAT32_LONG_CHAIN, FLOAT32_STORAGE, MC_SIGMAS
from usdbake.core.scene import LIGHT_DISK, LIGHT_DISTANT, LIGHT_DOME, LIGHT_RECT, LIGHT_SPHERE, Lights
from usdbake.kernels.light_bundles import light_bundle, surface_bundle
from usdbake.kernels.lights import Lights as LightBundle
from usdbake.kernels.lights import Surfaces, hit_radiance, path_indirect_irradiance
from usdbake.kernels.tracer import FAR, Tracer
from usdbake.kernels.traversal import TraceScene, trace_closest

STRATA = 64
"""4096 stratified samples per light: DIRECT_TOLERANCE holds at a quarter of that (1024) on smooth
integrands; the kinks tested here (a horizon, a shadow edge) cost a few strata along one line."""

MARKER = quad([40, 40, -40], [0.1, 0, 0], [0, 0.1, 0])
"""A tiny quad far from every receiver: the ray core needs a triangle, and this one blocks nothing."""


def open_scene(*light_rows, parts=(MARKER,), emission=None, double_sided=None, lights=None):
    points, tris = merge(parts)
    return make_scene(points, tris, emission=emission, double_sided=double_sided,
                      lights=lights if lights is not None else make_lights(*light_rows))


def irradiance(scene, point, normal, *, strata=STRATA, sky_strata=STRATA):
    normal = np.asarray(normal, np.float64)
    return direct_irradiance_at(scene, [point], [normal / np.linalg.norm(normal)], strata=strata,
                                sky_strata=sky_strata)[0]


def unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


# -- float64 references, written from the radiometry (no code of the library) -----------------------------


def area_integral(points, weights, radiance, emit_normal, p, n, *, two_sided=False):
    """E = L sum_q cos(n, q - p)+ cos'(emit_normal, p - q)+ / d^2 w_q over quadrature nodes q on an emitter."""
    v = points - p
    d2 = np.einsum("ij,ij->i", v, v)
    d = np.sqrt(d2)
    cos_r = np.maximum(v @ n / d, 0.0)
    cos_l = -(v @ emit_normal) / d
    cos_l = np.abs(cos_l) if two_sided else np.maximum(cos_l, 0.0)
    return radiance * float(np.sum(cos_r * cos_l / d2 * weights))


def in_plane_axes(axis):
    """Any orthonormal pair perpendicular to unit axis (a disk's integral does not depend on the roll)."""
    helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
    t = unit(np.cross(axis, helper))
    return t, np.cross(axis, t)


def disk_nodes(centre, axis, radius, nodes=256):
    """Gauss-Legendre in the radius times the midpoint rule in the angle (spectral for periodic integrands)."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    r, wr = 0.5 * radius * (x + 1), 0.5 * radius * w
    phi = (np.arange(2 * nodes) + 0.5) * math.pi / nodes
    t, s = in_plane_axes(axis)
    rr, pp = np.meshgrid(r, phi, indexing="ij")
    points = centre + rr.reshape(-1, 1) * (np.cos(pp).reshape(-1, 1) * t + np.sin(pp).reshape(-1, 1) * s)
    weights = (wr[:, None] * r[:, None] * np.full(2 * nodes, math.pi / nodes)).ravel()
    return points, weights


def rect_nodes(centre, x_axis, y_axis, width, height, nodes=256):
    x, w = np.polynomial.legendre.leggauss(nodes)
    a, b = np.meshgrid(0.5 * width * x, 0.5 * height * x, indexing="ij")
    points = centre + a.reshape(-1, 1) * x_axis + b.reshape(-1, 1) * y_axis
    return points, (np.outer(w, w) * width * height / 4).ravel()


def triangle_nodes(a, b, c, nodes=128):
    """Duffy's collapse of the unit square onto the triangle: q = a + u (b - a) + u v (c - b), dA = 2 A u du dv."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    u, wu = 0.5 * (x + 1), 0.5 * w
    uu, vv = np.meshgrid(u, u, indexing="ij")
    a, b, c = (np.asarray(corner, np.float64) for corner in (a, b, c))
    points = a + uu.reshape(-1, 1) * (b - a) + (uu * vv).reshape(-1, 1) * (c - b)
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a))
    return points, (2 * area * np.outer(wu * u, wu)).ravel()


def cap_irradiance(radiance, axis, half_angle, n, nodes=2048):
    """E = L integral over the cone of half-angle alpha around axis of max(n . w, 0) dw, midpoint rule in
    cos(theta) and the angle (the clamp's kink is resolved by the fine grid)."""
    cos_t = 1 - (np.arange(nodes) + 0.5) / nodes * (1 - math.cos(half_angle))
    phi = (np.arange(2 * nodes) + 0.5) * math.pi / nodes
    t, s = in_plane_axes(axis)
    sin_t = np.sqrt(1 - cos_t ** 2)
    along = np.outer(cos_t, np.ones_like(phi)) * (axis @ n)
    across = np.outer(sin_t, np.cos(phi)) * (t @ n) + np.outer(sin_t, np.sin(phi)) * (s @ n)
    cell = (1 - math.cos(half_angle)) / nodes * math.pi / nodes
    return radiance * float(np.maximum(along + across, 0.0).sum() * cell)


# -- each light ------------------------------------------------------------------------------------


def test_disk_light_off_axis_on_a_tilted_receiver_matches_quadrature():
    centre, axis, radius, radiance = np.array([0.7, -0.4, 2.0]), unit([-0.3, 0.2, -1.0]), 0.8, 3.0
    p, n = np.zeros(3), unit([0.2, 0.1, 1.0])
    scene = open_scene((LIGHT_DISK, [radiance] * 3, centre, axis, [radius, radius]))
    expected = area_integral(*disk_nodes(centre, axis, radius), radiance, axis, p, n)
    np.testing.assert_allclose(irradiance(scene, p, n), expected, rtol=DIRECT_TOLERANCE)


def test_disk_light_on_axis_matches_the_closed_form():
    """E = L pi R^2 / (h^2 + R^2) on the axis of a disk facing the point (Howell's catalogue, B-13)."""
    radius, height, radiance = 1.5, 2.0, 2.0
    scene = open_scene((LIGHT_DISK, [radiance] * 3, [0, 0, height], [0, 0, -1], [radius, radius]))
    expected = radiance * math.pi * radius ** 2 / (height ** 2 + radius ** 2)
    np.testing.assert_allclose(irradiance(scene, np.zeros(3), [0, 0, 1]), expected, rtol=DIRECT_TOLERANCE)


def test_rect_light_off_axis_matches_quadrature():
    """A light pointing straight down: Duff et al.'s tangent frame of -z puts the width along x, the height
    along -y (the rect is symmetric in y, so only the x/y assignment of width and height matters)."""
    centre, width, height, radiance = np.array([1.5, 0.2, 1.0]), 4.0, 0.3, 4.0
    p, n = np.zeros(3), unit([0.3, -0.2, 1.0])
    scene = open_scene((LIGHT_RECT, [radiance] * 3, centre, [0, 0, -1], [width, height]))
    nodes = rect_nodes(centre, np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), width, height)
    expected = area_integral(*nodes, radiance, np.array([0, 0, -1.0]), p, n)
    np.testing.assert_allclose(irradiance(scene, p, n), expected, rtol=DIRECT_TOLERANCE)
    swapped = area_integral(*rect_nodes(centre, np.array([0, 1.0, 0]), np.array([1.0, 0, 0]), width, height),
                            radiance, np.array([0, 0, -1.0]), p, n)
    assert abs(swapped - expected) > 4 * DIRECT_TOLERANCE * expected  # the test tells the two apart


def test_rect_light_on_axis_matches_howells_closed_form():
    """Parallel rectangle centred above the point: four times Howell's C-11 corner factor times pi L."""
    a, b, h, radiance = 1.0, 3.0, 2.0, 1.0
    scene = open_scene((LIGHT_RECT, [radiance] * 3, [0, 0, h], [0, 0, -1], [a, b]))
    x, y = a / 2 / h, b / 2 / h
    corner = (x / math.sqrt(1 + x * x) * math.atan(y / math.sqrt(1 + x * x))
              + y / math.sqrt(1 + y * y) * math.atan(x / math.sqrt(1 + y * y))) / (2 * math.pi)
    np.testing.assert_allclose(irradiance(scene, np.zeros(3), [0, 0, 1]), 4 * corner * math.pi * radiance,
                               rtol=DIRECT_TOLERANCE)


def test_sphere_light_above_the_horizon_matches_the_closed_form():
    """A sphere wholly above the tangent plane: E = pi L sin^2(alpha) cos(beta) (alpha its angular radius,
    beta the angle between the normal and its centre)."""
    centre, radius, radiance = np.array([1.0, 0.5, 2.5]), 0.6, 2.0
    n = unit([0.1, 0.2, 1.0])
    distance = np.linalg.norm(centre)
    scene = open_scene((LIGHT_SPHERE, [radiance] * 3, centre, [0, 0, -1], [radius, radius]))
    expected = math.pi * radiance * (radius / distance) ** 2 * (unit(centre) @ n)
    np.testing.assert_allclose(irradiance(scene, np.zeros(3), n), expected, rtol=DIRECT_TOLERANCE)


def test_sphere_light_cut_by_the_horizon_matches_quadrature():
    centre, radius, radiance = np.array([2.0, 0.0, 0.4]), 1.0, 1.0
    n = np.array([0, 0, 1.0])
    distance = np.linalg.norm(centre)
    scene = open_scene((LIGHT_SPHERE, [radiance] * 3, centre, [0, 0, -1], [radius, radius]))
    expected = cap_irradiance(radiance, unit(centre), math.asin(radius / distance), n)
    unclipped = math.pi * radiance * (radius / distance) ** 2 * (unit(centre) @ n)  # counts the hidden part < 0
    assert expected > (1 + 4 * DIRECT_TOLERANCE) * unclipped  # the horizon matters at this tolerance
    np.testing.assert_allclose(irradiance(scene, np.zeros(3), n), expected, rtol=DIRECT_TOLERANCE)


def test_inside_a_sphere_light_the_whole_hemisphere_shines():
    scene = open_scene((LIGHT_SPHERE, [2.0] * 3, [0.1, 0, 0], [0, 0, -1], [1.0, 1.0]))
    np.testing.assert_allclose(irradiance(scene, np.zeros(3), unit([1, 1, 1])), 2.0 * math.pi,
                               rtol=FLOAT32_STORAGE)


@pytest.mark.parametrize("tilt_degrees", [0.0, 40.0, 75.0])
def test_distant_cone_on_a_tilted_receiver_matches_the_closed_form(tilt_degrees):
    """A cone of half-angle alpha above the horizon: E = L integral cos = pi L sin^2(alpha) cos(beta)."""
    angle, radiance = 12.0, 1.5
    tilt = math.radians(tilt_degrees)
    scene = open_scene((LIGHT_DISTANT, [radiance] * 3, [0, 0, 0], [0, 0, -1], [angle, angle]))
    n = np.array([math.sin(tilt), 0, math.cos(tilt)])
    expected = math.pi * radiance * math.sin(math.radians(angle / 2)) ** 2 * math.cos(tilt)
    np.testing.assert_allclose(irradiance(scene, np.zeros(3), n), expected, rtol=DIRECT_TOLERANCE)


def test_zero_angle_distant_light_is_a_delta_light():
    """UsdLux: a distant light of angle 0 gives E = L cos(theta) on the lit side and nothing below."""
    direction = unit([0.3, -0.4, -1.0])
    scene = open_scene((LIGHT_DISTANT, [2.0, 1.0, 0.5], [0, 0, 0], direction, [0, 0]))
    np.testing.assert_allclose(irradiance(scene, np.zeros(3), [0, 0, 1]), np.array([2.0, 1.0, 0.5]) * -direction[2],
                               rtol=FLOAT32_STORAGE)
    assert irradiance(scene, np.zeros(3), [0, 0, -1]).max() == 0.0


# -- the dome and its texture ------------------------------------------------------------------------


def banded_texture(rows, columns=8):
    """A lat-long texture whose rows (latitude bands, +90 deg at row 0) hold 0, 1, 2, ...: one value per row."""
    values = np.arange(rows, dtype=np.float32)
    return np.repeat(values[:, None], columns, axis=1)[:, :, None].repeat(3, axis=2)


def test_textured_dome_matches_the_band_integral():
    """Row k of an H-row lat-long map covers latitudes [90 - 180 (k+1)/H, 90 - 180 k/H] deg. Facing the pole,
    band [lo, hi] gives pi (cos^2 lo - cos^2 hi) of cosine-weighted solid angle; the estimator pi L T(w) over
    cosine-weighted directions has variance pi^2 L^2 sum T^2 share - E^2."""
    rows, radiance = 6, 1.5
    lights = Lights(light_paths=("/World/Dome",), light_kind=np.array([LIGHT_DOME], np.int32),
                    light_radiance=np.full((1, 3), radiance, np.float32), light_position=np.zeros((1, 3), np.float32),
                    light_direction=np.array([[0, 0, -1]], np.float32), light_size=np.zeros((1, 2), np.float32),
                    dome_source=banded_texture(rows))
    scene = open_scene(lights=lights)
    edges = np.radians(90 - 180 * np.arange(rows + 1) / rows)
    upper = edges[:-1] > 0  # rows wholly above the horizon of a receiver facing +Y (the dome's pole)
    share = np.cos(np.maximum(edges[1:], 0)) ** 2 - np.cos(edges[:-1]) ** 2
    texel = np.arange(rows, dtype=np.float64)
    expected = math.pi * radiance * float((texel * share)[upper].sum())
    second = (math.pi * radiance) ** 2 * float((texel ** 2 * share)[upper].sum())
    tolerance = MC_SIGMAS * math.sqrt(max(second - expected ** 2, 0.0) / STRATA ** 2)
    np.testing.assert_allclose(irradiance(scene, np.zeros(3), [0, 1, 0]), expected, rtol=0, atol=tolerance)


@pytest.mark.parametrize("facing, lit", [([0, 0, 1], True), ([0, 0, -1], False), ([1, 0, 0], None)])
def test_dome_frame_turns_the_texture(facing, lit):
    """dome_to_local (row vectors) taking world +Z to the dome's +Y: a texture bright above the dome's equator
    lights a +Z receiver fully (pi L), a -Z receiver not at all, a sideways one by half."""
    texture = np.zeros((8, 4, 3), np.float32)
    texture[:4] = 1.0  # rows 0-3: latitudes above the equator
    to_local = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], np.float64)  # x -> x, y -> -z, z -> y
    lights = Lights(light_paths=("/World/Dome",), light_kind=np.array([LIGHT_DOME], np.int32),
                    light_radiance=np.full((1, 3), 2.0, np.float32), light_position=np.zeros((1, 3), np.float32),
                    light_direction=np.array([[0, 0, -1]], np.float32), light_size=np.zeros((1, 2), np.float32),
                    dome_source=texture, dome_to_local=to_local)
    got = irradiance(open_scene(lights=lights), np.zeros(3), facing)
    expected = 2.0 * math.pi * {True: 1.0, False: 0.0, None: 0.5}[lit]
    # Sideways, each cosine-weighted sample sees the bright half or not: pi L V, V Bernoulli(1/2), i.i.d.
    # standard deviation pi L / 2 per sample.
    tolerance = MC_SIGMAS * 2.0 * math.pi * 0.5 / STRATA if lit is None else FLOAT32_LONG_CHAIN * 2.0 * math.pi
    np.testing.assert_allclose(got, expected, rtol=0, atol=tolerance)


def test_dome_texture_columns_run_from_plus_pi_longitude():
    """OpenEXR lat-long layout: column 0 is longitude +pi, longitude atan2(x, z); the left half of the map is
    the +X half of the dome."""
    texture = np.zeros((4, 8, 3), np.float32)
    texture[:, :4] = 1.0
    lights = Lights(light_paths=("/World/Dome",), light_kind=np.array([LIGHT_DOME], np.int32),
                    light_radiance=np.ones((1, 3), np.float32), light_position=np.zeros((1, 3), np.float32),
                    light_direction=np.array([[0, 0, -1]], np.float32), light_size=np.zeros((1, 2), np.float32),
                    dome_source=texture)
    scene = open_scene(lights=lights)
    np.testing.assert_allclose(irradiance(scene, np.zeros(3), [1, 0, 0]), math.pi, rtol=FLOAT32_LONG_CHAIN)
    assert irradiance(scene, np.zeros(3), [-1, 0, 0]).max() == 0.0


# -- emissive triangles ------------------------------------------------------------------------------


def test_emissive_triangles_match_quadrature_within_monte_carlo_noise():
    """Two one-sided emitters of different power above the point, picked by power: the estimator
    X = L_t A_t g(q) / pmf_t (q uniform on t, g = cos cos' / d^2) has E[X^2] = sum_t L_t^2 A_t / pmf_t int g^2."""
    first = quad([-1.0, -0.5, 2.0], [0, 1.0, 0], [1.0, 0, 0])  # normal -z, facing the point
    second = quad([0.5, 0.0, 1.5], [0, 0.8, 0], [0.6, 0, 0])
    radiance = np.array([[2.0] * 3, [2.0] * 3, [5.0] * 3, [5.0] * 3], np.float32)
    points, tris = merge([first, second, MARKER])
    emission = np.concatenate([radiance, np.zeros((2, 3), np.float32)])
    scene = make_scene(points, tris, emission=emission)
    p, n = np.zeros(3), unit([0.1, 0.0, 1.0])
    totals, squares, powers = [], [], []
    for t in range(4):
        a, b, c = points[tris[t]].astype(np.float64)
        emit_normal = unit(np.cross(b - a, c - a))
        q, w = triangle_nodes(a, b, c)
        totals.append(area_integral(q, w, float(radiance[t, 0]), emit_normal, p, n))
        v = q - p
        d2 = np.einsum("ij,ij->i", v, v)
        g = np.maximum(v @ n, 0) * np.maximum(-(v @ emit_normal), 0) / d2 ** 2
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a))
        squares.append(float(radiance[t, 0]) ** 2 * area * float(np.sum(g ** 2 * w)))
        powers.append(float(radiance[t, 0]) * area)
    pmf = np.array(powers) / sum(powers)
    expected = sum(totals)
    variance = float(np.sum(np.array(squares) / pmf)) - expected ** 2
    tolerance = MC_SIGMAS * math.sqrt(variance / STRATA ** 2)
    np.testing.assert_allclose(irradiance(scene, p, n), expected, rtol=0, atol=tolerance)


def test_one_sided_emitter_is_dark_behind_and_a_double_sided_one_is_not():
    emitter = quad([-0.5, -0.5, 1.0], [1.0, 0, 0], [0, 1.0, 0])  # normal +z: faces away from the point below
    points, tris = merge([emitter, MARKER])
    emission = np.array([[3.0] * 3, [3.0] * 3, [0] * 3, [0] * 3], np.float32)
    one_sided = make_scene(points, tris, emission=emission)
    assert irradiance(one_sided, np.zeros(3), [0, 0, 1]).max() == 0.0
    two_sided = make_scene(points, tris, emission=emission, double_sided=[True, True, False, False])
    a, b, c, d = points[:4].astype(np.float64)
    expected = sum(area_integral(*triangle_nodes(*corners), 3.0, np.array([0, 0, 1.0]), np.zeros(3),
                                 np.array([0, 0, 1.0]), two_sided=True) for corners in ((a, b, c), (a, c, d)))
    np.testing.assert_allclose(irradiance(two_sided, np.zeros(3), [0, 0, 1]), expected, rtol=DIRECT_TOLERANCE)


# -- shadows -----------------------------------------------------------------------------------------


def test_a_half_plane_halfway_up_hides_half_a_disk_light():
    """A blocker over x < 0 at half the light's height stops exactly the rays to the disk's x < 0 half."""
    height, radius = 2.0, 1.0
    blocker = quad([-10, -10, height / 2], [0, 20, 0], [10, 0, 0])
    scene = open_scene((LIGHT_DISK, [1.0] * 3, [0, 0, height], [0, 0, -1], [radius, radius]),
                       parts=(blocker, MARKER))
    points, weights = disk_nodes(np.array([0, 0, height]), np.array([0, 0, -1.0]), radius)
    keep = points[:, 0] > 0
    expected = area_integral(points[keep], weights[keep], 1.0, np.array([0, 0, -1.0]), np.zeros(3),
                             np.array([0, 0, 1.0]))
    np.testing.assert_allclose(irradiance(scene, np.zeros(3), [0, 0, 1]), expected, rtol=DIRECT_TOLERANCE)


# -- radiance at a hit and one indirect path ---------------------------------------------------------


@wp.kernel
def hit_radiance_kernel(scene: TraceScene, surfaces: Surfaces, lights: LightBundle, origins: wp.array(dtype=wp.vec3),
                        directions: wp.array(dtype=wp.vec3), epsilon: float, out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    q = trace_closest(scene, origins[i], directions[i], FAR)
    value = wp.vec3(-1.0, -1.0, -1.0)
    if q.result:
        value = hit_radiance(scene, surfaces, lights, origins[i], directions[i], q.face, q.t, 1, epsilon,
                             wp.rand_init(3, i))
    out[i] = value


@wp.kernel
def indirect_kernel(scene: TraceScene, surfaces: Surfaces, lights: LightBundle, p: wp.vec3, n: wp.vec3,
                    bounces: int, epsilon: float, out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = path_indirect_irradiance(scene, surfaces, lights, p, n, bounces, epsilon, wp.rand_init(11, i))


def test_a_lambertian_hit_reflects_albedo_times_irradiance_over_pi_plus_its_emission():
    theta, radiance, albedo, glow = math.radians(35), 3.0, 0.6, 0.25
    floor = quad([-5, -5, 0], [10, 0, 0], [0, 10, 0])  # normal +z
    light = (LIGHT_DISTANT, [radiance] * 3, [0, 0, 0], [math.sin(theta), 0, -math.cos(theta)], [0, 0])
    points, tris = merge([floor])
    scene = make_scene(points, tris, albedo=albedo, emission=np.full((2, 3), glow, np.float32),
                       lights=make_lights(light))
    tracer = Tracer.from_scene(scene)
    origins = np.array([[0.3, 0.2, 1.0], [0.3, 0.2, -1.0]], np.float32)
    directions = np.array([[0, 0, -1], [0, 0, 1]], np.float32)  # front, then the single-sided back
    out = wp.zeros(2, dtype=wp.vec3, device=tracer.device)
    wp.launch(hit_radiance_kernel, dim=2, device=tracer.device,
              inputs=[tracer.scene, surface_bundle(scene, tracer.device), light_bundle(scene, tracer.device),
                      tracer.array(origins, wp.vec3), tracer.array(directions, wp.vec3), tracer.epsilon, out])
    front, back = out.numpy()
    np.testing.assert_allclose(front, albedo * radiance * math.cos(theta) / math.pi + glow, rtol=FLOAT32_STORAGE)
    np.testing.assert_allclose(back, 0.0, atol=0)


@pytest.mark.parametrize("bounces", [1, 3])
def test_one_indirect_bounce_off_a_lit_ceiling(bounces):
    """A free point facing a wide ceiling (half-width 1000 at height 1) lit from below by a zero-angle
    distant light of irradiance L: every path hits it (misses: cos^2 of the ceiling's edge, ~1e-6) and
    brings rho L; the second bounce, down from the ceiling, escapes, so more bounces add nothing."""
    albedo, radiance = 0.7, 2.0
    ceiling = quad([-1000, -1000, 1], [0, 2000, 0], [2000, 0, 0])  # normal -z
    points, tris = merge([ceiling])
    scene = make_scene(points, tris, albedo=albedo, lights=make_lights(
        (LIGHT_DISTANT, [radiance] * 3, [0, 0, 0], [0, 0, 1], [0, 0])))
    tracer = Tracer.from_scene(scene)
    paths = 256
    out = wp.zeros(paths, dtype=wp.vec3, device=tracer.device)
    wp.launch(indirect_kernel, dim=paths, device=tracer.device,
              inputs=[tracer.scene, surface_bundle(scene, tracer.device), light_bundle(scene, tracer.device),
                      wp.vec3(0.0, 0.0, 0.0), wp.vec3(0.0, 0.0, 1.0), bounces, tracer.epsilon, out])
    np.testing.assert_allclose(out.numpy().mean(axis=0), albedo * radiance, rtol=FLOAT32_ACCUMULATED)
