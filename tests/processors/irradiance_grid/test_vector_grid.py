"""processors/irradiance_grid/vector_grid.py on its own: layout, trilinear weights and reconstruction.

- ``grid_layout``: for any box, cubic cells, n = max(2, ceil(extent / h + 0.5) + 1) vertices an axis centred
  on the box, outer vertices h/4 to 3h/4 outside it (hypothesis); with a vertex budget, the largest grid
  within it (a slightly smaller cell exceeds it); ``positions`` x fastest;
- ``grid_bounds``: the union of the probe volumes, else the scene's bounds;
- ``trilinear``: a partition of unity that reproduces affine functions, clamps points outside to the grid,
  and handles an axis of one vertex;
- ``reconstruct_irradiance`` against a plain float64 loop written from the ``irradiance_grid`` docstring
  (paper 3.2: trilinear vectors of the hemispheres the normal's signs pick, I_n = sum I_a n_a^2,
  E = max(0, I_n . n)), with the normal offset, the behind-the-plane cutoff and the normalized variant.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from patch_scenes import make_scene, quad
from tolerances import FLOAT32_ACCUMULATED, FLOAT32_ROUNDING, FLOAT32_STORAGE, FLOAT64_ROUNDING, ON_BOUNDARY
from usdbake.processors.irradiance_grid.vector_grid import (MAX_GRID_VERTICES, RECEIVER_MARGIN, GridLayout, grid_bounds,
                                                            grid_layout, reconstruct_irradiance, trilinear)

extent = st.floats(0.0, 50.0, allow_nan=False)
corner = st.floats(-100.0, 100.0, allow_nan=False)


@given(lo=st.tuples(corner, corner, corner), size=st.tuples(extent, extent, extent),
       cell=st.floats(0.5, 10.0))  # at most ~100^3 vertices: under MAX_GRID_VERTICES
def test_a_fixed_cell_size_follows_the_layout_rule(lo, size, cell):
    lo = np.asarray(lo)
    hi = lo + np.asarray(size)
    layout = grid_layout(lo, hi, cell_size=cell)
    np.testing.assert_array_equal(layout.cell_size, np.full(3, cell))
    expected = [max(2, math.ceil(s / cell + 0.5) + 1) for s in size]
    assert list(layout.resolution) == expected and layout.count == int(np.prod(expected))
    first = layout.grid_origin
    last = first + (np.asarray(layout.resolution) - 1) * cell
    np.testing.assert_allclose(0.5 * (first + last), 0.5 * (lo + hi), atol=ON_BOUNDARY * max(1.0, np.abs(lo).max()))
    slack = ON_BOUNDARY * max(1.0, np.abs(hi).max(), np.abs(lo).max())
    tight = np.asarray(size) > 0  # a flat axis gets 2 vertices h/2 either side
    assert (lo - first >= cell / 4 - slack).all() and (last - hi >= cell / 4 - slack).all()
    assert ((lo - first)[tight] <= 3 * cell / 4 + slack).all()


@pytest.mark.parametrize("budget", [8, 100, 1000, 20000])
def test_a_vertex_budget_gives_the_largest_grid_within_it(budget):
    lo, hi = np.array([-1.0, 0.0, 2.0]), np.array([3.0, 1.5, 2.5])
    layout = grid_layout(lo, hi, vertices=budget)
    assert layout.count <= budget
    h = float(layout.cell_size[0])
    np.testing.assert_array_equal(layout.cell_size, np.full(3, h))
    finer = grid_layout(lo, hi, cell_size=h * (1 - 1e-6))  # the next smaller cell breaks the budget
    assert finer.count > budget or budget == 8  # 2 x 2 x 2 is the coarsest grid there is
    assert grid_layout(lo, hi, cell_size=h).resolution == layout.resolution


def test_too_many_vertices_are_refused():
    with pytest.raises(ValueError, match="choose a larger cell_size"):
        grid_layout(np.zeros(3), np.full(3, 1.0), cell_size=1.0 / (round(MAX_GRID_VERTICES ** (1 / 3)) + 1))


def test_positions_run_x_fastest():
    layout = GridLayout(np.array([1.0, -2.0, 0.5]), np.full(3, 0.25), (3, 4, 2))
    positions = layout.positions()
    assert positions.shape == (24, 3) and positions.dtype == np.float32
    for k in range(2):
        for j in range(4):
            for i in range(3):
                np.testing.assert_allclose(positions[i + 3 * (j + 4 * k)], [1 + 0.25 * i, -2 + 0.25 * j, 0.5 + 0.25 * k],
                                           atol=FLOAT32_STORAGE)


def test_grid_bounds_are_the_probe_volumes_else_the_receivers_without_backdrops():
    """No backdrop: the scene's bounds. A 10 m quad under a 1 m one is a backdrop: the grid spans the small
    quad grown by RECEIVER_MARGIN of its diagonal, clipped to the scene. Probe volumes win over both."""
    scene = make_scene([quad([-5, -5, 0], [10, 0, 0], [0, 10, 0]), quad([-4, -4, 3], [8, 0, 0], [0, 8, 0])])
    lo, hi = grid_bounds(scene)
    np.testing.assert_array_equal(lo, [-5, -5, 0])
    np.testing.assert_array_equal(hi, [5, 5, 3])
    scene = make_scene([quad([-5, -5, 0], [10, 0, 0], [0, 10, 0]), quad([0, 0, 3], [1, 0, 0], [0, 1, 0])])
    lo, hi = grid_bounds(scene)
    margin = RECEIVER_MARGIN * np.sqrt(2.0)
    np.testing.assert_allclose(lo, [-margin, -margin, 3 - margin], atol=FLOAT32_ROUNDING)
    np.testing.assert_allclose(hi, [1 + margin, 1 + margin, 3], atol=FLOAT32_ROUNDING)
    volumes = np.array([[[0, 0, 0], [1, 2, 1]], [[-1, 0.5, 0.2], [0.5, 1, 4]]], np.float64)
    lo, hi = grid_bounds(dataclasses.replace(scene, probe_volumes=volumes))
    np.testing.assert_array_equal(lo, [-1, 0, 0])
    np.testing.assert_array_equal(hi, [1, 2, 4])


def plain_grid(resolution=(3, 4, 5)):
    return GridLayout(np.array([0.5, -1.0, 2.0]), np.full(3, 0.75), resolution)


def vertex_positions(layout) -> np.ndarray:
    nx, ny, nz = layout.resolution
    k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    return layout.grid_origin + np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1) * layout.cell_size


def test_trilinear_weights_reproduce_affine_functions_and_clamp_outside():
    layout = plain_grid()
    rng = np.random.default_rng(4)  # any points in and around the grid
    span = (np.asarray(layout.resolution) - 1) * layout.cell_size
    inside = layout.grid_origin + rng.random((300, 3)) * span
    index, weight = trilinear(layout, inside)
    assert index.shape == weight.shape == (300, 8)
    assert ((index >= 0) & (index < layout.count)).all() and (weight >= -FLOAT64_ROUNDING).all()
    np.testing.assert_allclose(weight.sum(axis=1), 1.0, atol=FLOAT64_ROUNDING)
    vertices = vertex_positions(layout)
    affine = lambda p: 0.3 + p @ [1.5, -2.0, 0.25]  # noqa: E731
    # values and coordinates of order 10: FLOAT64_ROUNDING scaled by 10
    np.testing.assert_allclose((weight * affine(vertices)[index]).sum(axis=1), affine(inside), atol=FLOAT64_ROUNDING * 10)
    np.testing.assert_allclose((weight[:, :, None] * vertices[index]).sum(axis=1), inside, atol=FLOAT64_ROUNDING * 10)
    # points outside read the nearest point of the grid's box
    outside = layout.grid_origin + (rng.random((100, 3)) * 3 - 1) * span
    clamped = np.clip(outside, layout.grid_origin, layout.grid_origin + span)
    index_out, weight_out = trilinear(layout, outside)
    np.testing.assert_allclose((weight_out[:, :, None] * vertices[index_out]).sum(axis=1), clamped,
                               atol=FLOAT64_ROUNDING * 10)
    # a vertex itself: one weight of 1 on it (the far corner included)
    index_v, weight_v = trilinear(layout, vertices)
    picked = index_v[np.arange(len(vertices)), np.argmax(weight_v, axis=1)]
    np.testing.assert_array_equal(picked, np.arange(layout.count))
    np.testing.assert_allclose(weight_v.max(axis=1), 1.0, atol=FLOAT64_ROUNDING)


def test_trilinear_on_an_axis_of_one_vertex():
    layout = GridLayout(np.zeros(3), np.ones(3), (1, 3, 2))  # a plane of vertices at x = 0
    points = np.array([[0.0, 0.5, 0.25], [2.0, 1.5, 1.0], [-1.0, 2.0, 0.0]])
    index, weight = trilinear(layout, points)
    np.testing.assert_allclose(weight.sum(axis=1), 1.0, atol=FLOAT64_ROUNDING)
    assert ((index >= 0) & (index < layout.count)).all()
    vertices = vertex_positions(layout)
    np.testing.assert_allclose((weight[:, :, None] * vertices[index]).sum(axis=1)[:, 1:], points[:, 1:],
                               atol=FLOAT64_ROUNDING)


def reconstruct_plain(layout, vectors, p, n, *, offset=0.5, behind=False, normalized=False):
    """E(p, n) (3,) of one point, looping over corners and axes in float64 (the docstring's formulas)."""
    length = np.linalg.norm(n)
    if not length > 0.5:
        return np.zeros(3)
    n = n / length
    q = p + n * offset * layout.cell_size.min()
    res = np.asarray(layout.resolution)
    g = np.clip((q - layout.grid_origin) / layout.cell_size, 0, res - 1)
    base = np.minimum(np.floor(g).astype(int), res - 2)
    t = g - base
    corners = []
    for dz in (0, 1):
        for dy in (0, 1):
            for dx in (0, 1):
                c = base + [dx, dy, dz]
                w = (t[0] if dx else 1 - t[0]) * (t[1] if dy else 1 - t[1]) * (t[2] if dz else 1 - t[2])
                position = layout.grid_origin + c * layout.cell_size
                corners.append((c[0] + res[0] * (c[1] + res[1] * c[2]), w, position))
    if behind:
        front = [(i, w, x) for i, w, x in corners if (x - p) @ n >= 0]
        total = sum(w for _, w, _ in front)
        if total > 0:
            corners = [(i, w / total, x) for i, w, x in front]
    e = np.zeros(3)
    for axis in range(3):
        hemisphere = 2 * axis + (1 if n[axis] < 0 else 0)
        matrix = sum(w * vectors[i, hemisphere].astype(np.float64) for i, w, _ in corners)  # (channel, xyz)
        e += n[axis] ** 2 * (matrix @ n)
    if normalized:
        e /= (np.abs(n) ** 3).sum()
    return np.maximum(e, 0.0)


@pytest.mark.parametrize("behind, normalized, offset", [(False, False, 0.5), (True, False, 0.5), (False, True, 0.0),
                                                        (True, True, 1.3)])
def test_reconstruction_matches_a_plain_loop(behind, normalized, offset):
    layout = plain_grid((3, 3, 4))
    rng = np.random.default_rng(6)  # arbitrary vectors (some pointing away: E clamps at 0), points and normals
    vectors = (rng.normal(size=(layout.count, 6, 3, 3)) + 0.5).astype(np.float32)
    span = (np.asarray(layout.resolution) - 1) * layout.cell_size
    points = layout.grid_origin + (rng.random((120, 3)) * 1.2 - 0.1) * span
    normals = rng.normal(size=(120, 3)) * rng.choice([0.7, 3.0], (120, 1))  # not unit: normalized inside
    normals[:6] = [[1, 0, 0], [0, -1, 0], [0, 0, 1], [0, 0, 0], [0.1, 0.1, 0.1], [-1, -1, 0]]  # a zero, a short
    got = reconstruct_irradiance(layout, vectors, points, normals, normal_offset=offset,
                                 reconstruction="normalized" if normalized else "paper", behind_cutoff=behind)
    assert got.shape == (120, 3) and got.dtype == np.float32
    expected = np.array([reconstruct_plain(layout, vectors, p, n, offset=offset, behind=behind, normalized=normalized)
                         for p, n in zip(points, normals)])
    scale = np.abs(vectors).max() * 3  # |I_n . n| <= 3 max |entry| for a unit n
    np.testing.assert_allclose(got, expected, rtol=0, atol=FLOAT32_ACCUMULATED * scale)
    assert not got[3:5].any()  # zero and too-short normals read nothing
    assert (got > 0).any() and (expected == 0).any()  # both branches of the clamp are seen


def test_unknown_reconstruction_is_refused():
    layout = plain_grid()
    with pytest.raises(ValueError, match="normalized"):
        reconstruct_irradiance(layout, np.zeros((layout.count, 6, 3, 3)), np.zeros((1, 3)), [[0, 0, 1.0]],
                               reconstruction="exact")
