"""geometry.mesh: vertex normals and inward tangents, receivers, face means and backdrops, each against
values worked out by hand for small meshes."""

import numpy as np
from fake_processors import make_scene
from tolerances import FLOAT32_STORAGE, FLOAT64_ROUNDING
from usdbake.geometry.mesh import (NO_RECEIVERS, backdrop_prims, detail_diagonal, face_means, missing_receivers,
                                   prim_boxes, receiver_detail_box, receiver_prims, vertex_inward, vertex_normals)


def quads_scene(boxes, *, writable=None, skip=None):
    """A Scene of one quad (two triangles) per prim in the z = 0 plane, spanning (x0, y0)-(x1, y1)."""
    points, tris, tri_prim = [], [], []
    for prim, (x0, y0, x1, y1) in enumerate(boxes):
        base = len(points)
        points += [(x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0)]
        tris += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
        tri_prim += [prim, prim]
    count, prims = len(tris), len(boxes)
    areas = np.repeat([(x1 - x0) * (y1 - y0) / 2 for x0, y0, x1, y1 in boxes], 2)
    return make_scene(
        np.array(points, np.float32), tri_vertices=np.array(tris, np.int32),
        tri_normals=np.tile(np.float32([0, 0, 1]), (count, 1)), tri_areas=areas.astype(np.float32),
        tri_albedo=np.full((count, 3), 0.5, np.float32), tri_emission=np.zeros((count, 3), np.float32),
        tri_prim=np.array(tri_prim, np.int32), tri_face=np.zeros(count, np.int32),
        tri_instance=np.full(count, -1, np.int32), tri_double_sided=np.zeros(count, bool),
        point_prim=np.repeat(np.arange(prims, dtype=np.int32), 4),
        prim_paths=tuple(f"/World/P{k}" for k in range(prims)),
        prim_point_start=np.arange(0, 4 * prims + 1, 4, dtype=np.int64),
        prim_face_count=np.ones(prims, np.int32),
        prim_writable=np.ones(prims, bool) if writable is None else np.array(writable),
        prim_skip=np.zeros(prims, bool) if skip is None else np.array(skip),
        prim_surface=("",) * prims)


def test_vertex_normals_weight_faces_by_area():
    # Two triangles at a shared edge: +z with area 2, +x with area 1 -> (1, 0, 2) / sqrt(5) on the edge.
    points = np.zeros((5, 3), np.float32)
    tri_vertices = np.array([[0, 1, 2], [0, 1, 3]], np.int32)
    normals = vertex_normals(points, tri_vertices, np.float32([[0, 0, 1], [1, 0, 0]]), np.float32([2.0, 1.0]))
    edge = np.array([1, 0, 2]) / np.sqrt(5)
    np.testing.assert_allclose(normals[[0, 1]], [edge, edge], atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(normals[2], [0, 0, 1], atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(normals[3], [1, 0, 0], atol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(normals[4], 0.0)  # touched by no triangle
    assert normals.dtype == np.float32


def test_vertex_inward_points_into_the_vertex_own_face():
    # One right triangle: the corner at the origin points to the centroid (1/3, 1/3, 0).
    points = np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]])
    normals = np.tile(np.float32([0, 0, 1]), (4, 1))
    inward = vertex_inward(points, np.array([[0, 1, 2]]), normals)
    np.testing.assert_allclose(inward[0], np.array([1, 1, 0]) / np.sqrt(2), atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(inward[1], np.array([-2, 1, 0]) / np.sqrt(5), atol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(inward[3], 0.0)  # isolated point


def test_vertex_inward_is_zero_inside_a_balanced_ring_and_tangent_off_plane():
    # A centre vertex with a symmetric fan of four triangles: its ring centroid is the vertex itself.
    points = np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]])
    tris = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]])
    normals = np.tile(np.float32([0, 0, 1]), (5, 1))
    inward = vertex_inward(points, tris, normals)
    np.testing.assert_array_equal(inward[0], 0.0)
    # Rim vertices point towards the centre, in the tangent plane (no z component).
    np.testing.assert_allclose(inward[1], [-1, 0, 0], atol=FLOAT32_STORAGE)
    assert np.all(inward[:, 2] == 0.0)


def test_receiver_prims_leave_out_read_only_skipped_and_empty_prims():
    scene = quads_scene([(0, 0, 1, 1)] * 4, writable=[True, False, True, True], skip=[False, False, True, False])
    assert receiver_prims(scene).tolist() == [0, 3]
    assert missing_receivers(scene) == ""
    none = quads_scene([(0, 0, 1, 1)], writable=[False])
    assert receiver_prims(none).size == 0 and missing_receivers(none) == NO_RECEIVERS


def test_face_means_weight_by_area_and_fill_empty_faces_with_one():
    values = np.array([1.0, 0.0, 0.25, 0.75])
    weights = np.array([3.0, 1.0, 1.0, 1.0])
    means = face_means(values, weights, np.array([0, 0, 2, 2]), 4)
    np.testing.assert_allclose(means, [0.75, 1.0, 0.5, 1.0], atol=FLOAT64_ROUNDING)
    assert means.dtype == np.float32


def test_prim_boxes_hold_each_prim_points_bounds():
    scene = quads_scene([(0, 0, 1, 2), (-3, 1, -1, 4)])
    boxes = prim_boxes(scene, np.array([1, 0]))
    np.testing.assert_array_equal(boxes, [[[-3, 1, 0], [-1, 4, 0]], [[0, 0, 0], [1, 2, 0]]])


def test_a_ground_far_wider_than_the_rest_is_a_backdrop():
    # A 200 x 200 ground around two 1 x 1 boxes 3 apart: the rest spans 4 x 1, 200 > 4 * 4 on x and y.
    scene = quads_scene([(-100, -100, 100, 100), (0, 0, 1, 1), (3, 0, 4, 1)])
    backdrops, others = backdrop_prims(scene)
    assert backdrops.tolist() == [0] and others.tolist() == [1, 2]
    lo, hi = receiver_detail_box(scene)
    np.testing.assert_array_equal(lo, [0, 0, 0])
    np.testing.assert_array_equal(hi, [4, 1, 0])
    assert abs(detail_diagonal(scene) - np.sqrt(17.0)) < FLOAT64_ROUNDING


def test_no_backdrop_when_no_receiver_dominates_on_two_axes():
    # 100 x 1 is wider than the rest (1 x 1) on x only: not a backdrop.
    scene = quads_scene([(-50, 0, 50, 1), (0, 0, 1, 1)])
    assert backdrop_prims(scene)[0].size == 0
    assert receiver_detail_box(scene) is None
    assert detail_diagonal(scene) == scene.diagonal
