"""processors.daylight.sun_visibility: shadow rays toward the solar disk from faces under and beside a
blocker, against the unshadowed share of each face worked out by hand; sun bins against plain numpy."""

import math

import numpy as np
import pytest
from tolerances import FLOAT64_ROUNDING, MC_SIGMAS
from usdbake.kernels.sky import reinhart_patches
from usdbake.kernels.tracer import Tracer
from usdbake.kernels.daylight_relight import sun_levels
from usdbake.processors.daylight.sun_visibility import compute_sun_visibility, sun_bin_hits, sun_bins

BLOCKER_HEIGHT = 1.0
"""A square roof over x, y in [-5, 0] at z = 1: the faces below it see no sun from overhead."""


@pytest.fixture(scope="module")
def tracer():
    h = BLOCKER_HEIGHT
    points = np.float32([[-5, -5, h], [0, -5, h], [0, 0, h], [-5, 0, h]])
    return Tracer(points, np.int32([[0, 1, 2], [0, 2, 3]]), threads=1)


def faces(*triangles, normal=(0, 0, 1)):
    """(F * 3, 3) corners of triangles at z = 0 and (F, 3) normals."""
    corners = np.float32([[x, y, 0.0] for triangle in triangles for x, y in triangle])
    return corners, np.tile(np.float32(normal), (len(triangles), 1))


SHADED = [(-4, -4), (-2, -4), (-4, -2)]
LIT = [(2, 2), (4, 2), (2, 4)]


def test_faces_under_the_roof_see_no_sun_and_faces_beside_it_all_of_it(tracer):
    corners, normals = faces(SHADED, LIT)
    visible = compute_sun_visibility(tracer, corners, normals, np.array([0, 0, 3.0]), samples=16, seed=1)
    assert visible.tolist() == [0.0, 1.0]
    assert visible.dtype == np.float32


def test_a_face_turned_from_the_sun_sees_none_of_it(tracer):
    corners, normals = faces(LIT, normal=(0, 0, -1))
    assert compute_sun_visibility(tracer, corners, normals, np.array([0, 0, 1.0]), samples=16).tolist() == [0.0]


def test_a_low_sun_moves_the_shadow_by_the_roof_height_over_its_slope(tracer):
    # Sun 45 degrees up toward -x: the roof's shadow on z = 0 is shifted by +1 in x: it covers x in [-4, 1].
    sun = np.array([-1.0, 0.0, 1.0])
    under_shifted = [(0.2, -4), (0.8, -4), (0.2, -3)]
    beyond = [(1.2, -4), (1.8, -4), (1.2, -3)]
    corners, normals = faces(under_shifted, beyond)
    assert compute_sun_visibility(tracer, corners, normals, sun, samples=16, seed=2).tolist() == [0.0, 1.0]


def test_a_face_across_the_shadow_edge_sees_its_unshadowed_share(tracer):
    # The right triangle (-1, -3), (1, -3), (-1, -1) under an overhead sun: the part with x > 0 is lit,
    # a triangle of legs 1 and 1 (area 1/2) of the face's 2.
    samples = 4096
    corners, normals = faces([(-1, -3), (1, -3), (-1, -1)])
    visible = compute_sun_visibility(tracer, corners, normals, np.array([0, 0, 1.0]), samples=samples, seed=3)
    share = 0.25
    sigma = math.sqrt(share * (1 - share) / samples)
    assert abs(float(visible[0]) - share) < MC_SIGMAS * sigma


def test_sun_bins_group_positions_by_their_nearest_patch():
    layout = reinhart_patches(1).patch_directions
    near = layout[7] + np.array([0.001, -0.001, 0.0])
    suns = np.array([layout[7], near / np.linalg.norm(near), layout[20], [0.0, 0.6, -0.8]])
    up = suns[:, 2] > 0
    bins, directions = sun_bins(suns, up, 1)
    assert bins[3] == -1
    assert bins[0] == bins[1] != bins[2]
    expected = suns[0] + suns[1]
    np.testing.assert_allclose(directions[bins[0]], expected / np.linalg.norm(expected), atol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(directions[bins[2]], layout[20], atol=FLOAT64_ROUNDING)
    none, empty = sun_bins(suns, np.zeros(4, bool), 1)
    assert (none == -1).all() and empty.shape == (0, 3)


def test_sun_bin_hits_count_the_rays_that_reach_each_bin_sun(tracer):
    """Stored in steps of 1 / sun_levels(samples): 9 rays, 252 levels, 28 per ray."""
    corners, normals = faces(SHADED, LIT)
    directions = np.array([[0.0, 0.0, 1.0], [-0.8, 0.0, -0.6]])  # overhead; below every face's horizon
    hits = sun_bin_hits(tracer, corners, normals, directions, samples=9)
    assert hits.dtype == np.uint8 and sun_levels(9) == 252
    assert hits.tolist() == [[0, 252], [0, 0]]
    with pytest.raises(ValueError, match="1..255"):
        sun_bin_hits(tracer, corners, normals, directions, samples=256)
