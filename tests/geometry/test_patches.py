"""Graded patch voxels around a detail box (geometry/patches.py): coarser with distance, unchanged inside."""

import numpy as np

from usdbake.geometry.patches import GRADE_DISTANCE, build_patches, fragment_levels


def quad(lo, hi, z):
    """Two triangles of the square [lo, hi]^2 at height z facing +Z."""
    points = np.array([[lo, lo, z], [hi, lo, z], [hi, hi, z], [lo, hi, z]], np.float32)
    return points, np.array([[0, 1, 2], [0, 2, 3]], np.int32)


def scene_arrays():
    """A 2 m square (the detail) 1 m above a 200 m ground plane: points, triangles, normals, areas, albedo."""
    (pa, ta), (pb, tb) = quad(-1.0, 1.0, 1.0), quad(-100.0, 100.0, 0.0)
    points, tris = np.vstack([pa, pb]), np.vstack([ta, tb + len(pa)])
    normals = np.tile([0.0, 0.0, 1.0], (len(tris), 1)).astype(np.float32)
    areas = np.array([2.0, 2.0, 2e4, 2e4], np.float32)
    return points, tris, normals, areas, np.full((4, 3), 0.5, np.float32), np.zeros((4, 3), np.float32)


def test_levels_grow_with_the_distance_from_the_detail():
    box = (np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 1.0]))
    voxel = 0.25
    near = GRADE_DISTANCE * voxel
    centres = np.array([[0.0, 0.0, 0.5], [1.0 + 0.9 * near, 0, 0], [1.0 + 1.9 * near, 0, 0], [1.0 + 3.9 * near, 0, 0]])
    np.testing.assert_array_equal(fragment_levels(centres, voxel, box), [0, 0, 1, 2])
    np.testing.assert_array_equal(fragment_levels(centres, voxel, None), [0, 0, 0, 0])


def test_grading_spends_fewer_patches_on_the_ground_and_keeps_the_detail():
    points, tris, normals, areas, albedo, emission = scene_arrays()
    groups = np.array([0, 0, 1, 1])
    box = (np.array([-1.0, -1.0, 1.0]), np.array([1.0, 1.0, 1.0]))
    flat = build_patches(points, tris, normals, areas, albedo, emission, voxel_size=0.25, tri_group=groups)
    graded = build_patches(points, tris, normals, areas, albedo, emission, voxel_size=0.25, tri_group=groups,
                           detail_box=box)
    assert graded.count < 0.5 * flat.count
    detail = lambda p: p.patch_centroids[p.patch_centroids[:, 2] > 0.5]  # noqa: E731
    np.testing.assert_allclose(np.sort(detail(graded), axis=0), np.sort(detail(flat), axis=0))
    for p in (flat, graded):  # every fragment in exactly one patch: the areas add up either way
        np.testing.assert_allclose(p.patch_areas.sum(), areas.sum(), rtol=1e-5)
