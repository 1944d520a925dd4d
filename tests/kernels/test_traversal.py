"""kernels.traversal's device functions called from a kernel of this file, not through Tracer's batched
queries: the fields of ``RayHit`` (t in the units of a non-unit direction, face, the barycentric
convention u v0 + v v1 + (1 - u - v) v2, sign > 0 on the winding side) against a float64 brute-force
ray/triangle intersection in numpy; ``trace_any`` against the same; the half-open range 0 <= t < max_t;
``surface_origin`` inside a face and at a wall's foot.

Random soups, watertightness, instancing and degenerate scenes are tested through Tracer in
tests/kernels/test_ray_core.py; this file pins the conventions of the functions every processor kernel calls.
"""

from __future__ import annotations

import numpy as np
import warp as wp
from tolerances import FLOAT32_ACCUMULATED, FLOAT32_ROUNDING
from usdbake.kernels.tracer import Tracer
from usdbake.kernels.traversal import TraceScene, surface_origin, trace_any, trace_closest

wp.set_module_options({"enable_backward": False})


@wp.kernel
def closest_kernel(scene: TraceScene, origins: wp.array(dtype=wp.vec3), directions: wp.array(dtype=wp.vec3),
                   max_t: wp.array(dtype=float), hit_t: wp.array(dtype=float), face: wp.array(dtype=int),
                   uv: wp.array(dtype=wp.vec2), sign: wp.array(dtype=float), hit: wp.array(dtype=int),
                   blocked: wp.array(dtype=int)):
    """Test-only: every RayHit field of ``trace_closest`` and ``trace_any`` per ray, direction as given."""
    i = wp.tid()
    q = trace_closest(scene, origins[i], directions[i], max_t[i])
    hit[i] = wp.where(q.result, 1, 0)
    hit_t[i] = q.t
    face[i] = q.face
    uv[i] = wp.vec2(q.u, q.v)
    sign[i] = q.sign
    blocked[i] = wp.where(trace_any(scene, origins[i], directions[i], max_t[i]), 1, 0)


@wp.kernel
def origin_kernel(scene: TraceScene, points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                  inward: wp.array(dtype=wp.vec3), epsilon: float, out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = surface_origin(scene, points[i], normals[i], inward[i], epsilon)


def trace(tracer, origins, directions, max_t):
    n = len(origins)
    outputs = [wp.zeros(n, dtype=float), wp.zeros(n, dtype=int), wp.zeros(n, dtype=wp.vec2),
               wp.zeros(n, dtype=float), wp.zeros(n, dtype=int), wp.zeros(n, dtype=int)]
    wp.launch(closest_kernel, n, [tracer.scene, tracer.array(np.float32(origins), wp.vec3),
                                  tracer.array(np.float32(directions), wp.vec3),
                                  tracer.array(np.float32(np.broadcast_to(max_t, n)), float), *outputs],
              device=tracer.device)
    t, face, uv, sign, hit, blocked = (a.numpy() for a in outputs)
    return dict(t=t, face=face, uv=uv, sign=sign, hit=hit.astype(bool), blocked=blocked.astype(bool))


def brute_force(corners, origins, directions):
    """Plain float64 ray/triangle intersection (Moller-Trumbore), every ray against every triangle.

    Returns t (R, T) along the given (non-normalized) direction, inf where there is no hit with t >= 0, and
    the smallest distance (R, T) of the plane point to the triangle's edges in barycentric units (how
    clearly inside or outside it is)."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    e1, e2 = b - a, c - a
    p = np.cross(directions[:, None], e2[None])
    det = np.einsum("tk,rtk->rt", e1, p)
    s = origins[:, None] - a[None]
    q = np.cross(s, e1[None])
    with np.errstate(divide="ignore", invalid="ignore"):
        w1 = np.einsum("rtk,rtk->rt", s, p) / det
        w2 = np.einsum("rk,rtk->rt", directions, q) / det
        t = np.einsum("tk,rtk->rt", e2, q) / det
    margin = np.minimum(np.minimum(w1, w2), 1 - w1 - w2)
    inside = (det != 0) & (margin >= 0) & (t >= 0)
    return np.where(inside, t, np.inf), np.where(det != 0, np.abs(margin), 0.0)


def soup(rng, count):
    centers = rng.uniform(-1, 1, (count, 1, 3))
    corners = centers + rng.normal(scale=0.3, size=(count, 3, 3))
    return corners.reshape(-1, 3).astype(np.float32), np.arange(3 * count, dtype=np.int32).reshape(-1, 3)


def test_closest_hit_fields_match_a_float64_brute_force():
    rng = np.random.default_rng(21)  # fixed seed
    points, tris = soup(rng, 40)
    tracer = Tracer(points, tris)
    corners = points.astype(np.float64)[tris]
    origins = rng.uniform(-2, 2, (600, 3)).astype(np.float32)
    targets = corners[rng.integers(0, len(tris), 600)].mean(axis=1)  # half the rays aimed at a centroid
    directions = np.where(np.arange(600)[:, None] % 2 == 0, targets - origins, rng.normal(size=(600, 3)))
    directions = (directions * rng.uniform(0.3, 3.0, (600, 1))).astype(np.float32)  # not unit: t is in its units
    got = trace(tracer, origins, directions, 1e30)
    t_ref, margin = brute_force(corners, origins.astype(np.float64), directions.astype(np.float64))
    nearest = t_ref.argmin(axis=1)
    rows = np.arange(600)
    t_near = t_ref[rows, nearest]
    # Rays that pass within float32 reach of an edge of some triangle ahead may go either way: left out.
    # So are rays meeting two faces within 1e-3 of each other (which one is closer is float32's call).
    clear = ~(margin < 1e-3).any(axis=1)
    second = np.sort(t_ref, axis=1)[:, 1]
    with np.errstate(invalid="ignore"):  # inf - inf where a ray meets nothing
        clear &= ~(second - t_near < 1e-3)
    assert clear.sum() > 400 and (np.isfinite(t_near) & clear).sum() > 150  # not vacuous
    expect_hit = np.isfinite(t_near)
    np.testing.assert_array_equal(got["hit"][clear], expect_hit[clear])
    np.testing.assert_array_equal(got["blocked"][clear], expect_hit[clear])
    hit = clear & expect_hit
    np.testing.assert_array_equal(got["face"][hit], nearest[hit])
    np.testing.assert_allclose(got["t"][hit], t_near[hit], rtol=FLOAT32_ACCUMULATED, atol=FLOAT32_ACCUMULATED)
    # The hit point is u v0 + v v1 + (1 - u - v) v2 of the face, and lies on the ray at t.
    u, v = got["uv"][hit, 0].astype(np.float64), got["uv"][hit, 1].astype(np.float64)
    c = corners[got["face"][hit]]
    point = u[:, None] * c[:, 0] + v[:, None] * c[:, 1] + (1 - u - v)[:, None] * c[:, 2]
    on_ray = origins[hit] + got["t"][hit, None].astype(np.float64) * directions[hit]
    np.testing.assert_allclose(point, on_ray, atol=FLOAT32_ACCUMULATED * 10)  # coordinates up to ~5 units
    # sign > 0 where the ray meets the winding (front) side: direction against the normal (v1 - v0) x (v2 - v0).
    normal = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    front = np.einsum("nk,nk->n", normal, directions[hit]) < 0
    np.testing.assert_array_equal(got["sign"][hit], np.where(front, 1.0, -1.0))
    # A miss reports face -1 and sign 0.
    miss = ~got["hit"]
    assert miss.any() and (got["face"][miss] == -1).all() and (got["sign"][miss] == 0).all()


def square(z=0.0, flip=False):
    points = np.array([[0, 0, z], [1, 0, z], [1, 1, z], [0, 1, z]], np.float32)
    tris = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    return points, (tris[:, ::-1].copy() if flip else tris)


def test_t_is_measured_in_units_of_the_direction_and_max_t_is_exclusive():
    points, tris = square()
    tracer = Tracer(points, tris)
    origin = np.float32([[0.25, 0.75, 1.0]])
    for length in (0.5, 1.0, 4.0):  # powers of two: t = 1 / length exactly in float32
        got = trace(tracer, origin, np.float32([[0, 0, -length]]), 1e30)
        assert got["hit"][0] and got["t"][0] == np.float32(1.0 / length)
        assert got["face"][0] == 1 and got["sign"][0] == 1.0  # the upper-left triangle, from its front
    # The plane is at t = 1 exactly: max_t = 1 misses it (t < max_t), the next float32 up reaches it.
    down = np.float32([[0, 0, -1]])
    assert not trace(tracer, origin, down, 1.0)["hit"][0]
    assert not trace(tracer, origin, down, 1.0)["blocked"][0]
    above = np.nextafter(np.float32(1.0), np.float32(2.0))
    assert trace(tracer, origin, down, above)["hit"][0] and trace(tracer, origin, down, above)["blocked"][0]
    # Behind the origin (t < 0) is never hit; from below the ray meets the back side.
    assert not trace(tracer, origin, np.float32([[0, 0, 1]]), 1e30)["hit"][0]
    below = trace(tracer, np.float32([[0.25, 0.75, -1.0]]), np.float32([[0, 0, 1]]), 1e30)
    assert below["hit"][0] and below["sign"][0] == -1.0 and below["t"][0] == 1.0
    # A zero direction or max_t = 0 finds nothing.
    assert not trace(tracer, origin, np.float32([[0, 0, 0]]), 1e30)["hit"][0]
    assert not trace(tracer, origin, down, 0.0)["blocked"][0]


def test_barycentrics_at_the_corners_follow_the_convention():
    points, tris = square()
    tracer = Tracer(points, tris[:1])  # triangle (0, 0), (1, 0), (1, 1)
    # Rays down at points just inside each corner: u is the weight of v0, v of v1.
    targets = np.array([[0.02, 0.01], [0.98, 0.01], [0.99, 0.97]])
    expected_uv = np.array([[0.98, 0.01], [0.02, 0.97], [0.01, 0.02]])
    origins = np.column_stack([targets, np.ones(3)]).astype(np.float32)
    got = trace(tracer, origins, np.float32([[0, 0, -1]] * 3), 1e30)
    assert got["hit"].all()
    np.testing.assert_allclose(got["uv"], expected_uv, atol=FLOAT32_ACCUMULATED)


def test_surface_origin_clears_the_own_face_and_a_touching_wall():
    # A floor x in [0, 0.5] (z = 0, normal +z) and a wall on its edge x = 0.5, its front facing the floor (-x).
    floor = np.array([[0, 0, 0], [0.5, 0, 0], [0.5, 1, 0], [0, 1, 0]], np.float32)
    wall = np.array([[0.5, 0, 0], [0.5, 0, 1], [0.5, 1, 1], [0.5, 1, 0]], np.float32)
    quad = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    corners = np.concatenate([floor, wall]).astype(np.float64)[np.concatenate([quad, quad + 4])]
    normals_ref = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    np.testing.assert_array_equal(np.sign(normals_ref), [[0, 0, 1]] * 2 + [[-1, 0, 0]] * 2)  # as described
    tracer = Tracer(np.concatenate([floor, wall]), np.concatenate([quad, quad + 4]))
    eps = tracer.epsilon
    points = np.float32([[0.25, 0.3, 0.0], [0.5, 0.3, 0.0]])  # inside the floor; on the wall's foot line
    normals = np.float32([[0, 0, 1], [0, 0, 1]])
    inward = np.float32([[0, 0, 0], [-1, 0, 0]])  # the second point's own face lies towards -x
    out = wp.zeros(2, dtype=wp.vec3)
    wp.launch(origin_kernel, 2, [tracer.scene, tracer.array(points, wp.vec3), tracer.array(normals, wp.vec3),
                                 tracer.array(inward, wp.vec3), eps, out])
    origins = out.numpy().astype(np.float64)
    # Inside a face: p + epsilon n (coordinates of order 1 in float32).
    np.testing.assert_allclose(origins[0], [0.25, 0.3, eps], atol=FLOAT32_ROUNDING)
    # At the foot: above the floor and in front of the wall, each by at least epsilon, and close by.
    assert origins[1, 2] >= eps - FLOAT32_ROUNDING and origins[1, 0] <= 0.5 - eps + FLOAT32_ROUNDING
    assert np.linalg.norm(origins[1] - points[1]) < 10 * eps
    # Rays from there into the open quarter space (up, towards -x) hit neither face.
    rng = np.random.default_rng(2)  # fixed seed
    d = rng.normal(size=(200, 3))
    d[:, 2] = np.abs(d[:, 2])
    d[:, 0] = -np.abs(d[:, 0])
    got = trace(tracer, np.repeat(origins[1:2], 200, 0).astype(np.float32), d.astype(np.float32), 1e30)
    assert not got["hit"].any()
