"""processors.light_probes.conforming on its own: the box surface, Sutherland-Hodgman clipping against a box
(areas and containment against plain float64 geometry), the tetrahedra's shared faces and neighbour table on
hand-built meshes, and fTetWild's mesh of a box with a wall embedded (volume, orientation, the wall on faces)."""

from __future__ import annotations

import numpy as np
import pytest

from tolerances import FLOAT64_AMPLIFIED
from usdbake.processors.light_probes.conforming import (box_surface, clip_polygon, clip_to_box, shared_faces,
                                                        tetrahedralize_box)


def triangle_areas(triangles: np.ndarray) -> np.ndarray:
    t = np.asarray(triangles, np.float64)
    return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)


def test_box_surface_is_closed_outward_and_holds_the_box():
    lo, hi = np.array([-1.0, 0.0, 2.0]), np.array([3.0, 1.0, 5.0])
    corners, triangles = box_surface(lo, hi)
    assert corners.shape == (8, 3) and triangles.shape == (12, 3)
    t = corners[triangles]
    area = triangle_areas(t).sum()
    size = hi - lo
    assert area == pytest.approx(2 * (size[0] * size[1] + size[1] * size[2] + size[0] * size[2]))
    # divergence theorem: sum of centroid . n A over a closed outward surface is 3 x volume
    normals = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]) / 2
    volume = np.einsum("ij,ij->", t.mean(axis=1), normals) / 3
    assert volume == pytest.approx(np.prod(size), rel=FLOAT64_AMPLIFIED)
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    assert np.all(uses == 2)  # every edge shared by two triangles: closed


def test_clip_polygon_keeps_one_side_of_the_plane():
    square = [np.array(p, np.float64) for p in ((0, 0, 0), (2, 0, 0), (2, 2, 0), (0, 2, 0))]
    below = clip_polygon(square, 0, 0.5, keep_below=True)
    above = clip_polygon(square, 0, 0.5, keep_below=False)
    assert np.array(below)[:, 0].max() == pytest.approx(0.5) and np.array(above)[:, 0].min() == pytest.approx(0.5)
    def shoelace(points):
        p = np.array(points)[:, :2]
        return 0.5 * abs(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(p[:, 1], np.roll(p[:, 0], -1)))
    assert shoelace(below) == pytest.approx(1.0) and shoelace(above) == pytest.approx(3.0)
    assert clip_polygon(square, 0, -1.0, keep_below=True) == []  # wholly on the other side


def test_clip_to_box_keeps_inside_clips_crossing_and_drops_outside():
    lo, hi = np.zeros(3), np.ones(3)
    inside = [[0.1, 0.1, 0.5], [0.9, 0.1, 0.5], [0.1, 0.9, 0.5]]
    outside = [[2, 2, 2], [3, 2, 2], [2, 3, 2]]
    crossing = [[-1, 0.5, 0.5], [2, 0.5, 0.5], [0.5, 0.5, 0.9]]  # a vertical triangle through the box
    clipped = clip_to_box(np.array([inside, outside, crossing], np.float64), lo, hi)
    assert np.all((clipped >= lo - 1e-12) & (clipped <= hi + 1e-12))
    assert np.allclose(clipped[0], inside)
    # the crossing triangle's part inside x in [0, 1]: in its plane (y = 0.5), the region of the triangle
    # (-1, .5), (2, .5), (.5, .9) in (x, z) with 0 <= x <= 1; plain polygon area by dense sampling of x
    x = np.linspace(0.0, 1.0, 200001)
    top = np.where(x <= 0.5, 0.5 + 0.4 * (x + 1) / 1.5, 0.5 + 0.4 * (2 - x) / 1.5)
    expected = np.trapezoid(top - 0.5, x)
    assert triangle_areas(clipped[1:]).sum() == pytest.approx(expected, rel=1e-6)
    assert clip_to_box(np.array([outside], np.float64), lo, hi).shape == (0, 3, 3)


def test_shared_faces_of_two_tetrahedra_and_a_lone_one():
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4], [5, 6, 7, 8]])
    pairs, neighbors = shared_faces(tets)
    assert pairs.tolist() == [[0, 1, 0, 3]]  # face (1, 2, 3): opposite corner 0 of tet 0 and corner 3 of tet 1
    assert neighbors.tolist() == [[1, -1, -1, -1], [-1, -1, -1, 0], [-1, -1, -1, -1]]


def test_shared_faces_of_a_cube_cut_into_five():
    """The 5-tetrahedron cube: the central one shares a face with each corner tetrahedron, which share none."""
    tets = np.array([[0, 1, 2, 4], [3, 1, 2, 7], [5, 1, 4, 7], [6, 2, 4, 7], [1, 2, 4, 7]])
    pairs, neighbors = shared_faces(tets)
    assert len(pairs) == 4 and set(map(tuple, np.sort(pairs[:, :2], axis=1))) == {(0, 4), (1, 4), (2, 4), (3, 4)}
    assert sorted(neighbors[4].tolist()) == [0, 1, 2, 3]
    for t in range(4):
        assert sorted(neighbors[t].tolist()) == [-1, -1, -1, 4]
        corner = int(np.flatnonzero(neighbors[t] == 4)[0])
        assert tets[t][corner] not in tets[4]  # the neighbour lies across the face opposite that corner


def test_fTetWild_meshes_the_box_with_a_wall_on_its_faces():
    lo, hi = np.zeros(3), np.array([2.0, 1.0, 1.0])
    wall = np.array([[[1, -1, -1], [1, 2, -1], [1, 2, 2]], [[1, -1, -1], [1, 2, 2], [1, -1, 2]]], np.float64)
    vertices, tets, seconds = tetrahedralize_box(wall, lo, hi, edge_length=0.5)
    assert seconds >= 0 and len(tets) > 0
    a, b, c, d = (vertices[tets[:, k]] for k in range(4))
    signed = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6
    assert np.all(signed > 0)  # positively oriented
    assert signed.sum() == pytest.approx(2.0, rel=1e-3)  # they fill the box
    centroids = vertices[tets].mean(axis=1)
    assert np.all((centroids > lo - 1e-6) & (centroids < hi + 1e-6))
    # the wall x = 1 lies on tetrahedron faces: no tetrahedron has corners strictly on both sides of it
    side = np.sign(np.round(vertices[tets][..., 0] - 1.0, 9))
    assert not np.any((side > 0).any(axis=1) & (side < 0).any(axis=1))
