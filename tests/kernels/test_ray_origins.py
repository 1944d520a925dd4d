"""The one ray-origin rule (kernels.tracer.surface_origin) at unwelded creases and T-junctions.

A flat-shaded box stands on a floor next to a wall: its faces share positions but
not vertices with each other, and its bottom corners rest on the floor's interior.
AO at points on those creases is checked against a float64 brute-force ray cast
that starts at the point itself: a ray is blocked by a face it meets at t > 0, or
by a face the point lies on when the ray goes to that face's back side and,
moved along the face, would stay on it (a ray that leaves a face across its
edge, as at the rim of a box, is not blocked by it).
"""

from __future__ import annotations

import numpy as np
import pytest
from lit_scenes import make_scene, merge, quad
from tolerances import FLOAT32_STORAGE, FLOAT64_ROUNDING, MC_SIGMAS
from usdbake.kernels.tracer import Tracer
from usdbake.processors.occlusion.ambient_occlusion import compute_vertex_ao

SAMPLES = 4096
"""Rays per point: 64 x 64 strata, for both the processor and the reference."""


def crease_scene():
    """Unwelded 2 x 2 x 2 box (6 separate quads) on a 100 m floor, 0.5 from a wall facing it."""
    lo, hi = np.array([-1, -1, 0], np.float32), np.array([1, 1, 2], np.float32)
    ex, ey, ez = np.diag(hi - lo).astype(np.float32)
    box = [quad(lo, ey, ex), quad(lo + ez, ex, ey), quad(lo, ex, ez), quad(lo + ey, ez, ex),
           quad(lo, ez, ey), quad(lo + ex, ey, ez)]
    floor = quad([-50, -50, 0], [100, 0, 0], [0, 100, 0])
    wall = quad([1.5, -50, 0], [0, 0, 20], [0, 100, 0])  # x = 1.5, normal -x (towards the box)
    return merge([floor, wall, *box])


def brute_force_ao(points, tris, p, n, samples, seed) -> float:
    """Cosine-weighted visible share at p (normal n), float64, rays from p itself."""
    rng = np.random.default_rng(seed)  # fixed seed
    u = rng.random((samples, 2))
    r, phi = np.sqrt(u[:, 0]), 2 * np.pi * u[:, 1]
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u[:, 0])], axis=1)
    t = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    t /= np.linalg.norm(t)
    d = local @ np.stack([t, np.cross(n, t), n])
    a, b, c = (points[tris[:, k]].astype(np.float64) for k in range(3))
    e1, e2 = b - a, c - a
    face_n = np.cross(e1, e2)
    face_n /= np.linalg.norm(face_n, axis=1, keepdims=True)
    blocked = np.zeros(samples, bool)
    for f in range(len(tris)):
        pv = np.cross(d, e2[f])
        det = pv @ e1[f]
        s = p - a[f]
        qv = np.cross(s, e1[f])
        with np.errstate(divide="ignore", invalid="ignore"):
            bu = (pv @ s) / det
            bv = (d @ qv) / det
            tt = (qv @ e2[f]) / det
        hit_ahead = (bu >= 0) & (bv >= 0) & (bu + bv <= 1) & (tt > 1e-12) & (np.abs(det) > 1e-15)
        blocked |= hit_ahead
        if abs((p - a[f]) @ face_n[f]) < FLOAT64_ROUNDING:  # p lies in the face's plane
            along = d - np.outer(d @ face_n[f], face_n[f])
            stays = points_in_triangle(p + 1e-6 * along, a[f], b[f], c[f], face_n[f])
            blocked |= stays & (d @ face_n[f] < 0)
    return float(1.0 - blocked.mean())


def points_in_triangle(q, a, b, c, normal) -> np.ndarray:
    """(N,) bool: the points q (N, 3), in the triangle's plane, lie in triangle abc (edges included)."""
    return np.all([np.cross(q1 - q0, q - q0) @ normal >= -1e-15 for q0, q1 in ((a, b), (b, c), (c, a))], axis=0)


CASES = {  # point, normal, the unit tangent into the point's own face (what vertex_inward gives a vertex)
    "side face, bottom edge on the floor": ([0.0, -1.0, 0.0], [0, -1, 0], [0, 0, 1]),
    "side face, corner on the floor": ([-1.0, -1.0, 0.0], [0, -1, 0], [0.70710678, 0, 0.70710678]),
    "side face facing the wall, bottom edge": ([1.0, 0.0, 0.0], [1, 0, 0], [0, 0, 1]),
    "top face, edge over the side face": ([1.0, 0.0, 2.0], [0, 0, 1], [-1, 0, 0]),
    "floor, at the box's edge": ([0.0, -1.0, 0.0], [0, 0, 1], [0, 0, 0]),
    "floor, in the box-wall corner": ([1.5, 0.0, 0.0], [0, 0, 1], [-1, 0, 0]),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_ao_at_creases_matches_a_float64_brute_force(case):
    """Before the rule (origin p + epsilon n only) four of these cases missed by 0.1 to 0.27."""
    points, tris = crease_scene()
    tracer = Tracer.from_scene(make_scene(points, tris))
    p, n, inward = (np.array(v, np.float64) for v in CASES[case])
    got = compute_vertex_ao(tracer, p[None].astype(np.float32), n[None].astype(np.float32), samples=SAMPLES,
                            seed=3, inward=inward[None].astype(np.float32))[0]
    expected = brute_force_ao(points, tris, p, n, 16 * SAMPLES, seed=4)
    sigma = np.sqrt(max(expected * (1 - expected), 1.0 / SAMPLES) / SAMPLES)  # i.i.d. bound (stratified is tighter)
    assert abs(got - expected) <= MC_SIGMAS * sigma, f"{case}: {got:.4f} vs brute force {expected:.4f}"


def test_vertex_inward_points_into_the_own_face_at_an_unwelded_crease():
    from usdbake.geometry.mesh import vertex_inward, vertex_normals

    points, tris = crease_scene()
    scene = make_scene(points, tris)
    normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
    inward = vertex_inward(scene.points, scene.tri_vertices, normals)
    # the -y side face of the box is quad(lo, ex, ez): its corner (-1, -1, 0) lies on the floor
    corner = np.flatnonzero(np.all(points == [-1, -1, 0], axis=1) & (normals[:, 1] < -0.5))
    assert len(corner) == 1
    np.testing.assert_allclose(inward[corner[0]], [np.sqrt(0.5), 0, np.sqrt(0.5)], atol=FLOAT32_STORAGE)
    np.testing.assert_allclose((inward * normals).sum(axis=1), 0, atol=FLOAT32_STORAGE)


def test_no_light_leaks_out_of_a_closed_room_through_its_corners():
    """A closed room of six separate inward-facing walls: every ray from a point on its surface hits a
    wall, so AO is 0 at the corners and edges too (an origin on a neighbouring wall's plane let rays
    through the zero-width joint: up to 0.29 on the atrium sample before the rule)."""
    from lit_scenes import cube

    points, tris = cube([0, 0, 0], [4, 3, 2.5], inward=True)
    scene = make_scene(points, tris)
    tracer = Tracer.from_scene(scene)
    from usdbake.geometry.mesh import vertex_inward, vertex_normals

    normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
    inward = vertex_inward(scene.points, scene.tri_vertices, normals)
    ao = compute_vertex_ao(tracer, scene.points, normals, samples=1024, seed=5, inward=inward)
    np.testing.assert_array_equal(ao, 0.0)
