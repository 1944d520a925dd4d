"""processors/radiosity/patch_kernels.py on its own: ``fragment_of_hit`` in a kernel of this file.

- for m = 1..7, random barycentrics land in the fragment that contains them: a plain float64 containment
  test against every fragment of ``fragment_template(m)`` (the numpy order the module promises to invert);
  every fragment is reached;
- several triangles of different m: the fragment ids start at each triangle's ``tri_fragment_start``;
- hits rounded just outside a triangle (barycentrics below 0, above 1, or summing past 1) get the fragment
  at the corner or edge they graze, never another triangle's.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from usdbake.processors.radiosity.patch_kernels import fragment_of_hit
from usdbake.processors.radiosity.patches import fragment_template

wp.set_module_options({"enable_backward": False})

EDGE_MARGIN = 1e-4
"""Points closer than this (in grid units u m, v m) to a fragment edge are left out of the containment
check: float32 barycentrics there may fall on either side (a qualitative cut, not an error bound)."""


@wp.kernel
def lookup_kernel(face: wp.array(dtype=int), uv: wp.array(dtype=wp.vec2), subdivision: wp.array(dtype=int),
                  start: wp.array(dtype=int), out: wp.array(dtype=int)):
    i = wp.tid()
    out[i] = fragment_of_hit(face[i], uv[i][0], uv[i][1], subdivision, start)


def lookup(face, uv, subdivision, start) -> np.ndarray:
    out = wp.zeros(len(face), dtype=int, device="cpu")
    wp.launch(lookup_kernel, dim=len(face), device="cpu", inputs=[
        wp.array(np.asarray(face, np.int32), dtype=int, device="cpu"),
        wp.array(np.asarray(uv, np.float32), dtype=wp.vec2, device="cpu"),
        wp.array(np.asarray(subdivision, np.int32), dtype=int, device="cpu"),
        wp.array(np.asarray(start, np.int32), dtype=int, device="cpu"), out])
    return out.numpy()


def containing_fragment(uv: np.ndarray, m: int) -> np.ndarray:
    """(N,) index of the fragment of fragment_template(m) that contains each (u, v), by signed areas."""
    corners, _ = fragment_template(m)  # (m^2, 3, 2)
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]

    def cross(p, q, r):  # z of (q - p) x (r - p), broadcast over points (N, 1, 2) and fragments (m^2, 2)
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])

    x = uv[:, None, :]
    area = cross(a, b, c)  # positive: counter-clockwise in (u, v)
    inside = (cross(a, b, x) * area >= 0) & (cross(b, c, x) * area >= 0) & (cross(c, a, x) * area >= 0)
    assert (inside.sum(axis=1) == 1).all()
    return np.argmax(inside, axis=1)


def random_barycentrics(count: int, m: int, seed: int) -> np.ndarray:
    """Uniform points of the triangle u, v >= 0, u + v <= 1, none within EDGE_MARGIN of a fragment edge."""
    rng = np.random.default_rng(seed)  # fixed by the caller
    uv = rng.random((4 * count, 2))
    uv = np.where(uv.sum(axis=1, keepdims=True) > 1, 1 - uv, uv)  # fold the upper half onto the triangle
    grid = uv * m
    distance = np.minimum.reduce([np.abs(grid[:, 0] - np.rint(grid[:, 0])), np.abs(grid[:, 1] - np.rint(grid[:, 1])),
                                  np.abs(grid.sum(axis=1) - np.rint(grid.sum(axis=1))) / np.sqrt(2)])
    return uv[distance > EDGE_MARGIN][:count]


@pytest.mark.parametrize("m", [1, 2, 3, 4, 7])
def test_a_hit_lands_in_the_fragment_that_contains_it(m):
    uv = random_barycentrics(4000, m, seed=m)
    found = lookup(np.zeros(len(uv)), uv, [m], [0])
    np.testing.assert_array_equal(found, containing_fragment(uv, m))
    assert set(found.tolist()) == set(range(m * m))  # every fragment is reached


def test_fragment_ids_start_at_each_triangles_first_fragment():
    subdivision = np.array([3, 1, 5, 2])
    start = np.concatenate([[0], np.cumsum(subdivision ** 2)[:-1]])
    faces, uvs, expected = [], [], []
    for face, m in enumerate(subdivision):
        uv = random_barycentrics(500, int(m), seed=10 + face)
        faces.append(np.full(len(uv), face))
        uvs.append(uv)
        expected.append(start[face] + containing_fragment(uv, int(m)))
    found = lookup(np.concatenate(faces), np.concatenate(uvs), subdivision, start)
    np.testing.assert_array_equal(found, np.concatenate(expected))
    assert set(found.tolist()) == set(range(int((subdivision ** 2).sum())))


@pytest.mark.parametrize("m", [1, 3, 6])
def test_hits_rounded_outside_the_triangle_keep_the_fragment_they_graze(m):
    """The ray core's barycentrics of an edge hit may stray by a rounding: the vertex and edge fragments."""
    tiny = 1e-6
    mid = (m // 2 + 0.5) / m  # the middle of a cell's edge on u + v = 1 (not a grid vertex)
    outside = np.array([
        [-tiny, -tiny],            # vertex v2 (u = v = 0): grid cell (0, 0)
        [1 + tiny, -tiny],         # vertex v0: the last lower cell of row 0
        [-tiny, 1 + tiny],         # vertex v1: the single cell of the top row
        [mid + tiny, 1 - mid + tiny],  # past the edge u + v = 1
        [0.5 / m, -tiny],          # just below the edge v = 0, in the first cell
        [-tiny, 0.5 / m],          # just left of the edge u = 0, in the first cell
    ])
    inside = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [mid, 1 - mid], [0.5 / m, 0.0], [0.0, 0.5 / m]])
    inside = inside + np.array([[1, 1], [-2, 1], [1, -2], [-1, -1], [0, 1], [1, 0]]) * 1e-3 / m  # pulled in
    found = lookup(np.zeros(len(outside)), outside, [m], [5])
    np.testing.assert_array_equal(found, 5 + containing_fragment(inside, m))
    assert ((found >= 5) & (found < 5 + m * m)).all()
    # far outside too: clamped into the triangle's own fragments
    wild = lookup(np.zeros(3), [[3.0, -2.0], [-1.0, 4.0], [0.9, 0.9]], [m], [5])
    assert ((wild >= 5) & (wild < 5 + m * m)).all()
