"""Patches (processors/radiosity/patches.py): graded voxels around a detail box (coarser with distance, unchanged
inside); shared patches across instances (the patch count follows the voxel, not the instance count)."""

import numpy as np

from tolerances import FLOAT32_ACCUMULATED
from usdbake.processors.radiosity.patches import (GRADE_DISTANCE, _cluster_keys, build_patches, choose_voxel_size, count_patches,
                                     fragment_levels, patch_groups)


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
        np.testing.assert_allclose(p.patch_areas.sum(), areas.sum(), rtol=FLOAT32_ACCUMULATED)


# ---------------------------------------------------------------------------
# Shared patches: triangles that receive no output (instances) cluster across prims (issue 27)


def spheres_on_a_floor(per_side: int, half: float = 4.0, radius: float = 0.2):
    """A 2 half x 2 half floor (prim 0, facing +Z) under per_side^2 icospheres (prims 1..) spread evenly
    over it: points, triangles, normals, areas, prim of each triangle."""
    from instanced_scenes import icosphere

    sphere, sphere_tris = icosphere(1)  # 80 triangles
    floor_points, floor_tris = quad(-half, half, 0.0)
    ticks = (np.arange(per_side) + 0.5) / per_side * 2 * half - half
    centres = [(x, y, radius) for x in ticks for y in ticks]
    points = [floor_points] + [sphere * radius + c for c in centres]
    tris = [floor_tris] + [sphere_tris] * len(centres)
    start = np.cumsum([0] + [len(p) for p in points])
    points = np.vstack(points).astype(np.float32)
    triangles = np.vstack([t + start[k] for k, t in enumerate(tris)]).astype(np.int32)
    prim = np.concatenate([np.full(len(t), k) for k, t in enumerate(tris)])
    corner = points[triangles].astype(np.float64)
    cross = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    length = np.linalg.norm(cross, axis=1)
    return points, triangles, (cross / length[:, None]).astype(np.float32), (length / 2).astype(np.float32), prim


def patches_of(arrays, groups, voxel, albedo=None):
    points, tris, normals, areas, _ = arrays
    albedo = np.full((len(tris), 3), 0.5, np.float32) if albedo is None else albedo
    return build_patches(points, tris, normals, areas, albedo, np.zeros((len(tris), 3), np.float32),
                         voxel_size=voxel, tri_group=groups)


def test_patch_groups_keep_receivers_and_bin_the_rest_by_albedo():
    prim = np.array([0, 0, 1, 2, 3])
    albedo = np.array([[0.5] * 3, [0.5] * 3, [0.5] * 3, [0.52, 0.5, 0.5], [0.9, 0.1, 0.1]], np.float32)
    groups = patch_groups(prim, albedo, prim > 0)
    np.testing.assert_array_equal(groups[:2], [0, 0])  # receivers: their prim
    assert (groups[2:] > prim.max()).all()  # shared ones sort after every prim
    assert groups[2] == groups[3] != groups[4]  # the same 1/ALBEDO_LEVELS step, another colour
    np.testing.assert_array_equal(patch_groups(prim, albedo, np.zeros(5, bool)), prim)


def test_patch_count_follows_the_voxel_not_the_instance_count():
    """4x as many spheres over the same floor: per-prim patches grow with them, shared ones do not."""
    counts = {}
    for per_side in (4, 8):
        arrays = spheres_on_a_floor(per_side)
        prim = arrays[4]
        shared = patch_groups(prim, np.full((len(prim), 3), 0.5, np.float32), prim > 0)
        counts[per_side] = (patches_of(arrays, shared, 2.0).count, patches_of(arrays, prim, 2.0).count)
    assert counts[8][1] >= 6 * 64  # one patch at least per prim and normal axis
    assert counts[8][0] == counts[4][0] <= 16 * 7  # 16 voxels x (6 axes of the spheres + the floor's one)


def test_shared_patches_never_hold_a_receiver_or_two_colours():
    arrays = spheres_on_a_floor(8)
    points, tris, normals, areas, prim = arrays
    albedo = np.where((prim % 2 == 0)[:, None], [0.8, 0.8, 0.8], [0.7, 0.1, 0.1]).astype(np.float32)
    patches = patches_of(arrays, patch_groups(prim, albedo, prim > 0), 2.0, albedo)
    fragment_prim = prim[patches.fragment_tri]
    for patch in range(patches.count):
        members = patches.fragment_patch == patch
        owners = np.unique(fragment_prim[members])
        colours = np.unique(albedo[patches.fragment_tri[members]], axis=0)
        assert len(colours) == 1 and (owners[0] > 0 or len(owners) == 1)
    floor_alone = patches_of(spheres_on_a_floor(8), prim, 2.0)  # the receiver's patches are as before
    floor = fragment_prim == 0
    np.testing.assert_array_equal(np.unique(patches.fragment_patch[floor]).size,
                                  np.unique(floor_alone.fragment_patch[floor]).size)
    np.testing.assert_allclose(patches.patch_areas.sum(), areas.sum(), rtol=FLOAT32_ACCUMULATED)


def test_voxel_choice_reaches_the_target_whatever_the_instance_count():
    for per_side in (6, 12):  # 36 and 144 spheres; per-prim patches could not go below 6 x 144 = 864
        points, tris, normals, areas, prim = spheres_on_a_floor(per_side)
        groups = patch_groups(prim, np.full((len(prim), 3), 0.5, np.float32), prim > 0)
        voxel = choose_voxel_size(points, tris, normals, areas, 120, groups)
        count = count_patches(points, tris, normals, areas, voxel, groups)
        assert 0.7 * 120 <= count <= 1.4 * 120, (per_side, count)


def test_patch_numbering_is_the_lexicographic_order_of_the_key_columns():
    """_cluster_keys ranks the columns one at a time; the patches must come out in the order a row-wise
    np.unique gives (so samples without shared triangles keep their patch order, and their results)."""
    rng = np.random.default_rng(5)  # fixed seed: keys full of ties in every column
    centres = rng.integers(0, 4, (5000, 3)) + 0.5
    normals = np.eye(3)[rng.integers(0, 3, 5000)] * rng.choice([-1.0, 1.0], (5000, 1))
    groups = rng.integers(0, 7, 5000)
    levels = rng.integers(0, 3, 5000)
    got = _cluster_keys(centres, normals, np.zeros(3), 1.0, groups, levels)
    axis = np.abs(normals).argmax(axis=1)
    direction = axis * 2 + (normals[np.arange(5000), axis] < 0)

    def packed(size):
        cell = np.floor(centres / size).astype(np.int64)
        return (cell[:, 0] << 43) | (cell[:, 1] << 23) | (cell[:, 2] << 3) | direction

    _, expected = np.unique(np.column_stack([packed(np.exp2(levels)[:, None]), groups, levels]), axis=0,
                            return_inverse=True)
    np.testing.assert_array_equal(got, expected.reshape(-1))
    _, expected = np.unique(packed(1.0), return_inverse=True)
    np.testing.assert_array_equal(_cluster_keys(centres, normals, np.zeros(3), 1.0), expected.reshape(-1))


def test_fragments_computed_in_blocks_give_the_same_patches(monkeypatch):
    """FRAGMENT_BLOCK bounds the float64 temporaries; the patches do not depend on it, bit for bit."""
    import dataclasses

    from usdbake.processors.radiosity import patches as module

    points, tris, normals, areas, prim = spheres_on_a_floor(3)
    albedo = np.full((len(tris), 3), 0.5, np.float32)
    groups = patch_groups(prim, albedo, prim > 0)

    def build():  # voxel 0.3: the floor's triangles split 27 x 27, the spheres' not at all
        return build_patches(points, tris, normals, areas, albedo, np.zeros_like(albedo), voxel_size=0.3,
                             tri_group=groups), count_patches(points, tris, normals, areas, 0.3, groups)

    whole, whole_count = build()
    monkeypatch.setattr(module, "FRAGMENT_BLOCK", 7)
    blocks, blocks_count = build()
    assert whole_count == blocks_count == whole.count
    for field in dataclasses.fields(whole):
        np.testing.assert_array_equal(getattr(blocks, field.name), getattr(whole, field.name), err_msg=field.name)
