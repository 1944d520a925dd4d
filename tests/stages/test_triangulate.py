"""Polygon triangulation: fans for convex faces, ear clipping for concave ones.

Closed forms on hand-drawn polygons in every axis plane, then hypothesis
properties on random star-shaped and convex polygons in random 3D planes.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tolerances import ON_BOUNDARY, TRIANGULATION_AREA
from usdbake.stages.triangulate import convex_mask, ear_clip, fan, triangulate

# Polygons in the xy plane, counter-clockwise seen from +z.
SQUARE = [(0, 0), (2, 0), (2, 2), (0, 2)]
L_HEXAGON = [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)]       # area 3, reflex at (1, 1)
ARROW_PENTAGON = [(0, 0), (2, 0), (2, 2), (1, 1), (0, 2)]          # area 3, reflex at (1, 1)

# Rigid maps of the xy plane into 3D, covering each dominant normal axis and
# both signs (the ear clipper projects on the dominant axis).
PLANES = {
    "xy+z": np.eye(3),
    "xy-z": Rotation.from_euler("x", 180, degrees=True).as_matrix(),
    "xz-y": Rotation.from_euler("x", 90, degrees=True).as_matrix(),
    "xz+y": Rotation.from_euler("x", -90, degrees=True).as_matrix(),
    "yz+x": Rotation.from_euler("y", 90, degrees=True).as_matrix(),
    "yz-x": Rotation.from_euler("y", -90, degrees=True).as_matrix(),
    "tilted": Rotation.from_euler("xyz", [31, -47, 12], degrees=True).as_matrix(),
}


def shoelace(flat: np.ndarray) -> float:
    x, y = flat[:, 0], flat[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def embed(flat, rotation: np.ndarray, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(n, 2) plane points -> (n, 3) points: rotated xy plane, then shifted."""
    flat = np.asarray(flat, np.float64)
    return np.c_[flat, np.zeros(len(flat))] @ rotation.T + np.asarray(offset)


def signed_areas(points: np.ndarray, triangles: np.ndarray, normal: np.ndarray) -> np.ndarray:
    corners = points[triangles]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return 0.5 * cross @ normal


def inside(point: np.ndarray, polygon: np.ndarray) -> bool:
    """Even-odd ray cast in 2D (the oracle for 'triangle centroid lies in the polygon')."""
    x, y = point
    hit = False
    for (x0, y0), (x1, y1) in zip(polygon, np.roll(polygon, -1, axis=0)):
        if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
            hit = not hit
    return hit


def check_triangulation(flat: np.ndarray, rotation: np.ndarray, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Triangulate the polygon ``flat`` placed in 3D and check count, area, winding and coverage."""
    n = len(flat)
    points = embed(flat, rotation, offset)
    triangles, tri_face = triangulate(points, [n], np.arange(n))
    assert triangles.shape == (n - 2, 3)
    assert triangles.dtype == np.int32
    np.testing.assert_array_equal(tri_face, np.zeros(n - 2))
    # Every triangle uses polygon corners, each triangle three distinct ones.
    assert all(len(set(t)) == 3 for t in triangles.tolist())

    area = shoelace(flat)
    normal = rotation[:, 2] * np.sign(area)  # unit polygon normal in 3D
    areas = signed_areas(points, triangles, normal)
    np.testing.assert_allclose(areas.sum(), abs(area), rtol=TRIANGULATION_AREA)
    assert (areas >= -ON_BOUNDARY * abs(area)).all(), areas  # a zero-area ear is wound either way

    centroids = flat[triangles].mean(axis=1)
    assert all(inside(c, flat) for c in centroids)
    return triangles


# --- closed forms -----------------------------------------------------------------------------


@pytest.mark.parametrize("plane", PLANES)
def test_convex_quad_is_a_fan(plane):
    points = embed(SQUARE, PLANES[plane])
    triangles, tri_face = triangulate(points, [4], [0, 1, 2, 3])
    np.testing.assert_array_equal(triangles, [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(tri_face, [0, 0])


@pytest.mark.parametrize("plane", PLANES)
@pytest.mark.parametrize("reverse", [False, True], ids=["ccw", "cw"])
@pytest.mark.parametrize("polygon", [L_HEXAGON, ARROW_PENTAGON], ids=["L-hexagon", "arrow-pentagon"])
def test_concave_polygon_ear_clipping(polygon, reverse, plane):
    flat = np.array(polygon[::-1] if reverse else polygon, np.float64)
    points = embed(flat, PLANES[plane])
    assert not convex_mask(points[None])[0]
    np.testing.assert_allclose(abs(shoelace(flat)), 3.0)
    check_triangulation(flat, PLANES[plane])


def test_ear_clip_keeps_the_reflex_corner_out_of_the_notch():
    """The L's notch square (1,1)-(2,2) must not be covered: no triangle (2,1),(1,1),(1,2)."""
    points = embed(L_HEXAGON, PLANES["xz+y"])
    local = ear_clip(points)
    assert sorted(map(sorted, local.tolist())).count([2, 3, 4]) == 0


def test_faces_are_mapped_and_indices_go_through_face_vertex_indices():
    # Face 0: square on points 4..7 (reversed in indices), face 1: triangle, face 2: L on 8..13.
    square = embed(SQUARE, np.eye(3))
    tri = embed([(0, 0), (1, 0), (0, 1)], np.eye(3), (5, 0, 0))
    ell = embed(L_HEXAGON, np.eye(3), (10, 0, 0))
    points = np.r_[tri, np.zeros((1, 3)), square, ell]
    counts = [4, 3, 6]
    indices = [4, 5, 6, 7, 0, 1, 2, *range(8, 14)]
    triangles, tri_face = triangulate(points, counts, indices)
    np.testing.assert_array_equal(tri_face, [0, 0, 1, 2, 2, 2, 2])
    np.testing.assert_array_equal(triangles[:3], [[4, 5, 6], [4, 6, 7], [0, 1, 2]])
    assert set(triangles[3:].ravel()) == set(range(8, 14))
    np.testing.assert_allclose(signed_areas(points, triangles[3:], np.array([0, 0, 1.0])).sum(), 3.0)


# --- degenerate input -------------------------------------------------------------------------


def test_collinear_polygon_does_not_crash():
    points = np.array([(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0), (1.5, 0, 0)], np.float64)
    triangles, tri_face = triangulate(points, [5], np.arange(5))
    assert triangles.shape == (3, 3)
    np.testing.assert_allclose(signed_areas(points, triangles, np.array([0, 0, 1.0])), 0.0)
    assert ear_clip(points).shape == (3, 3)


def test_faces_with_fewer_than_three_vertices_are_skipped():
    points = embed([(0, 0), (1, 0), (1, 1), (0, 1)], np.eye(3))
    counts = [3, 2, 1, 0, 4]
    indices = [0, 1, 2, 0, 1, 3, 0, 1, 2, 3]
    triangles, tri_face = triangulate(points, counts, indices)
    np.testing.assert_array_equal(tri_face, [0, 4, 4])
    np.testing.assert_array_equal(triangles, [[0, 1, 2], [0, 1, 2], [0, 2, 3]])


def test_skip_faces_are_left_out():
    points = embed(L_HEXAGON, np.eye(3))
    counts = [6, 3, 4]
    indices = [*range(6), 0, 1, 2, 0, 1, 2, 3]
    triangles, tri_face = triangulate(points, counts, indices, skip_faces=np.array([True, False, True]))
    np.testing.assert_array_equal(tri_face, [1])
    np.testing.assert_array_equal(triangles, [[0, 1, 2]])
    triangles, tri_face = triangulate(points, counts, indices, skip_faces=np.array([True, True, True]))
    assert triangles.shape == (0, 3) and tri_face.shape == (0,)


def test_empty_mesh():
    triangles, tri_face = triangulate(np.zeros((0, 3)), [], [])
    assert triangles.shape == (0, 3) and triangles.dtype == np.int32
    assert tri_face.shape == (0,) and tri_face.dtype == np.int32


# --- properties -------------------------------------------------------------------------------

# Gaps between consecutive vertex angles are drawn in [0.5, 1] then normalized,
# so with n >= 4 no gap reaches pi and the polygon is simple and star-shaped
# around its centre.
angles_deg = st.floats(-180.0, 180.0, allow_nan=False)
rotations = st.tuples(angles_deg, angles_deg, angles_deg).map(
    lambda euler: Rotation.from_euler("xyz", euler, degrees=True).as_matrix())
offsets = st.tuples(*[st.floats(-100.0, 100.0, allow_nan=False)] * 3)


@st.composite
def star_polygons(draw, radius=st.floats(0.1, 1.0)):
    n = draw(st.integers(4, 14))
    gaps = np.array(draw(st.lists(st.floats(0.5, 1.0), min_size=n, max_size=n)))
    angles = np.cumsum(gaps) / gaps.sum() * 2 * np.pi
    radii = np.array(draw(st.lists(radius, min_size=n, max_size=n)))
    scale = draw(st.floats(0.01, 100.0))
    flat = scale * np.c_[radii * np.cos(angles), radii * np.sin(angles)]
    return flat[::-1] if draw(st.booleans()) else flat


# derandomize: the examples are a fixed function of the test, so CI runs are reproducible.
@settings(max_examples=150, deadline=None, derandomize=True)
@given(flat=star_polygons(), rotation=rotations, offset=offsets)
def test_star_polygons_triangulate_exactly(flat, rotation, offset):
    check_triangulation(flat, rotation, offset)


@settings(max_examples=100, deadline=None, derandomize=True)
@given(flat=star_polygons(radius=st.just(1.0)), stretch=st.floats(0.2, 5.0), rotation=rotations, offset=offsets)
def test_convex_polygons_take_the_fan_path(flat, stretch, rotation, offset):
    flat = flat * [stretch, 1.0]  # points on an ellipse: convex
    n = len(flat)
    points = embed(flat, rotation, offset)
    assert convex_mask(points[None])[0]
    triangles = check_triangulation(flat, rotation, offset)
    np.testing.assert_array_equal(triangles, fan(np.arange(n)[None]))
