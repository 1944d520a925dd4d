"""processors/instancing/instance_points.py: the instances' own vertices as AO sample points.

Checked directly on small Scenes built without pxr (instanced_scenes.build_scene): which points are
taken and with what area weights; how ``at`` moves points, normals and tangents with new instance
transforms (against the prototype points put through the new matrix in float64, and the normals of
the moved triangles by cross products); the per-instance means of a linear field (the field at the
surface's centroid, exactly); and the primvar records (one value per authored row, masked rows 1,
native roots constant).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from instanced_scenes import build_scene, grid, translate
from usdbake.core.scene import Instances
from usdbake.processors.instancing.instance_points import InstancePoints

from tolerances import FLOAT32_ACCUMULATED, FLOAT32_STORAGE, FLOAT64_ROUNDING

# A 2 x 2-cell square facing +Y, side 1, centred on the prototype origin: 9 welded points whose
# vertex areas (a third of the area of each triangle at them) differ, so area and count weights differ.
PROTO_POINTS, PROTO_TRIS = grid(0.5, 2)
FLOOR_POINTS, FLOOR_TRIS = grid(3.0, 1, height=-1.0)


def axis_rotation(axis, angle) -> np.ndarray:
    """(3, 3) row-vector rotation (p' = p @ R) by ``angle`` about unit ``axis`` (Rodrigues, transposed)."""
    x, y, z = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    column = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    return column.T


def affine(linear, translation) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[3, :3] = linear, translation
    return m


BASES = [translate(1.0, 0.0, 0.0), translate(-2.0, 0.5, 1.0, scale=(2.0, 1.0, 1.0), rotate_y=0.7),
         translate(0.0, 2.0, -3.0, rotate_y=-1.2)]


def scene_of(bases=BASES, *, floor=True):
    receivers = [("/World/Floor", FLOOR_POINTS, FLOOR_TRIS)] if floor else []
    return build_scene(receivers, [("/Proto/Tile", PROTO_POINTS, PROTO_TRIS)], [(0, b) for b in bases])


def unit_y(scene):
    normals = np.zeros((scene.num_points, 3), np.float32)
    normals[:, 1] = 1.0
    return normals


def unit_x(scene):
    inward = np.zeros((scene.num_points, 3), np.float32)
    inward[:, 0] = 1.0
    return inward


def vertex_areas(points, tris) -> np.ndarray:
    """A third of the area of every triangle at a vertex, by a plain float64 loop."""
    areas = np.zeros(len(points))
    for a, b, c in tris:
        area = 0.5 * np.linalg.norm(np.cross(points[b] - points[a], points[c] - points[a]))
        for v in (a, b, c):
            areas[v] += area / 3
    return areas


# ---------------------------------------------------------------------------
# construction


def test_the_points_taken_are_the_instances_points_with_their_vertex_areas():
    scene = scene_of()
    fields = np.array([0, -1, 0], np.int32)
    points = InstancePoints(scene, unit_y(scene), unit_x(scene), fields)
    floor = len(FLOOR_POINTS)
    np.testing.assert_array_equal(points.point_ids, np.arange(floor, floor + 3 * len(PROTO_POINTS)))
    np.testing.assert_array_equal(points.instance, np.repeat([0, 1, 2], len(PROTO_POINTS)))
    np.testing.assert_array_equal(points.moving, np.repeat([True, False, True], len(PROTO_POINTS)))
    np.testing.assert_array_equal(points.own, np.repeat([0, -1, 2], len(PROTO_POINTS)))
    assert points.own.dtype == np.int32
    expected = np.concatenate([vertex_areas(scene.points[scene.prim_points(m)].astype(np.float64), PROTO_TRIS)
                               for m in (1, 2, 3)])
    np.testing.assert_allclose(points.weights, expected, rtol=FLOAT32_STORAGE)
    # the unscaled tile: its vertex areas add up to its area, 1
    np.testing.assert_allclose(points.weights[:len(PROTO_POINTS)].sum(), 1.0, rtol=FLOAT32_STORAGE)
    # the second instance is stretched by 2 along x: twice the area
    np.testing.assert_allclose(points.weights[len(PROTO_POINTS):2 * len(PROTO_POINTS)].sum(), 2.0,
                               rtol=FLOAT32_STORAGE)


def test_a_scene_without_instances_has_no_points():
    scene = build_scene([("/World/Floor", FLOOR_POINTS, FLOOR_TRIS)], [], [])
    points = InstancePoints(scene, unit_y(scene), unit_x(scene), np.zeros(0, np.int32))
    assert len(points.point_ids) == 0
    positions, normals, inward = points.at(np.zeros((0, 4, 4)))
    assert positions.shape == normals.shape == inward.shape == (0, 3)
    assert points.means(np.zeros(0, np.float32)).shape == (0,)
    assert points.records(np.zeros(0, np.float32), None) == []


# ---------------------------------------------------------------------------
# at: moving the points with their instance


def test_at_the_extraction_transforms_nothing_moves():
    scene = scene_of()
    normals, inward = unit_y(scene), unit_x(scene)
    points = InstancePoints(scene, normals, inward, np.zeros(3, np.int32))
    positions, moved_normals, moved_inward = points.at(scene.instances.instance_transforms)
    assert positions.dtype == moved_normals.dtype == moved_inward.dtype == np.float32
    np.testing.assert_allclose(positions, scene.points[points.point_ids], atol=FLOAT32_ACCUMULATED)
    np.testing.assert_allclose(moved_normals, normals[points.point_ids], atol=FLOAT32_ACCUMULATED)
    np.testing.assert_allclose(moved_inward, inward[points.point_ids], atol=FLOAT32_ACCUMULATED)


def test_new_transforms_move_points_normals_and_tangents_like_the_surface():
    scene = scene_of()
    # normals and tangents of the extraction-time surface: each instance's moved +Y and +X
    base = scene.instances.instance_transforms
    normals = np.zeros((scene.num_points, 3))
    inward = np.zeros((scene.num_points, 3))
    normals[:len(FLOOR_POINTS)] = (0, 1, 0)
    inward[:len(FLOOR_POINTS)] = (1, 0, 0)
    for j in range(3):
        span = scene.prim_points(1 + j)
        linear = base[j, :3, :3]
        tri = PROTO_POINTS[PROTO_TRIS[0]] @ linear
        n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
        normals[span] = n / np.linalg.norm(n)
        t = np.array([1.0, 0, 0]) @ linear
        inward[span] = t / np.linalg.norm(t)
    new = np.array([
        affine(axis_rotation([1, 0, 0], 0.9), [0.0, 3.0, 0.0]),                                 # rigid
        affine(np.diag([1.0, 3.0, 0.5]) @ axis_rotation([1, 1, 0], 1.1), [2.0, -1.0, 0.5]),  # non-uniform scale
        affine(0.25 * axis_rotation([0, 0, 1], -0.4), [-4.0, 1.0, 2.0]),                        # uniform scale
    ])
    points = InstancePoints(scene, normals, inward, np.zeros(3, np.int32))
    positions, moved_normals, moved_inward = points.at(new)
    for j in range(3):
        rows = points.instance == j
        expected = np.c_[PROTO_POINTS, np.ones(len(PROTO_POINTS))] @ new[j]
        np.testing.assert_allclose(positions[rows], expected[:, :3], atol=FLOAT32_ACCUMULATED)
        tri = expected[PROTO_TRIS[0], :3]  # the moved surface's normal, by a cross product
        n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
        np.testing.assert_allclose(moved_normals[rows], np.tile(n / np.linalg.norm(n), (rows.sum(), 1)),
                                   atol=FLOAT32_ACCUMULATED)
        t = np.array([1.0, 0, 0]) @ new[j, :3, :3]  # prototype +X through the new matrix
        np.testing.assert_allclose(moved_inward[rows], np.tile(t / np.linalg.norm(t), (rows.sum(), 1)),
                                   atol=FLOAT32_ACCUMULATED)
        np.testing.assert_allclose(np.linalg.norm(moved_normals[rows], axis=1), 1.0, atol=FLOAT32_STORAGE)
        assert np.abs((moved_normals[rows] * moved_inward[rows]).sum(axis=1)).max() < FLOAT32_ACCUMULATED


def test_instances_without_a_field_keep_their_extraction_time_points():
    scene = scene_of()
    normals, inward = unit_y(scene), unit_x(scene)
    points = InstancePoints(scene, normals, inward, np.array([-1, 0, -1], np.int32))
    shift = np.tile(translate(0.0, 5.0, 0.0), (3, 1, 1))
    positions, moved_normals, moved_inward = points.at(scene.instances.instance_transforms @ shift)
    still = points.instance != 1
    np.testing.assert_array_equal(positions[still], scene.points[points.point_ids][still])
    np.testing.assert_array_equal(moved_normals[still], normals[points.point_ids][still])
    np.testing.assert_array_equal(moved_inward[still], inward[points.point_ids][still])
    np.testing.assert_allclose(positions[~still], scene.points[points.point_ids][~still] + [0, 5, 0],
                               atol=FLOAT32_ACCUMULATED)


def test_singular_and_non_finite_transforms_give_finite_points():
    # a flattened extraction-time instance (scale 0 along y) must not make the inverse fail
    flattened = translate(0.0, 1.0, 0.0, scale=(1.0, 0.0, 1.0))
    scene = scene_of([translate(1.0, 0.0, 0.0), flattened])
    points = InstancePoints(scene, unit_y(scene), unit_x(scene), np.zeros(2, np.int32))
    assert np.isfinite(points.base_inverse).all()
    positions, normals, inward = points.at(scene.instances.instance_transforms)
    np.testing.assert_allclose(positions, scene.points[points.point_ids], atol=FLOAT32_ACCUMULATED)
    bad = np.array([np.full((4, 4), np.nan), np.zeros((4, 4))])
    for out in points.at(bad):
        assert np.isfinite(out).all()


# ---------------------------------------------------------------------------
# means


def test_the_mean_of_a_linear_field_is_its_value_at_the_centroid():
    # vertex areas (a third of each triangle) integrate a linear field exactly: the mean is f(centroid)
    scene = scene_of(floor=False)
    points = InstancePoints(scene, unit_y(scene), unit_x(scene), np.zeros(3, np.int32))
    world = scene.points[points.point_ids].astype(np.float64)
    coefficients = np.array([0.3, -0.2, 0.1])
    ao = (world @ coefficients + 0.5).astype(np.float32)
    means = points.means(ao)
    assert means.dtype == np.float32 and means.shape == (3,)
    centres = np.array([b[3, :3] for b in BASES])  # the tile is centred on its prototype origin
    np.testing.assert_allclose(means, centres @ coefficients + 0.5, atol=FLOAT32_ACCUMULATED)


def test_means_weigh_points_by_area_not_count():
    scene = scene_of(floor=False)
    points = InstancePoints(scene, unit_y(scene), unit_x(scene), np.zeros(3, np.int32))
    rng = np.random.default_rng(5)  # fixed seed: arbitrary AO values in [0, 1)
    ao = rng.random(len(points.point_ids)).astype(np.float32)
    for j, mean in enumerate(points.means(ao)):
        rows = points.instance == j
        areas = vertex_areas(scene.points[scene.prim_points(j)].astype(np.float64), PROTO_TRIS)
        expected = float((ao[rows] * areas).sum() / areas.sum())
        assert mean == pytest.approx(expected, rel=FLOAT32_STORAGE, abs=FLOAT32_STORAGE)


def test_an_instance_without_area_gets_one():
    flat = translate(0.0, 0.0, 0.0, scale=(1.0, 1.0, 0.0))  # the tile collapsed onto a line
    scene = scene_of([translate(1.0, 0.0, 0.0), flat])
    points = InstancePoints(scene, unit_y(scene), unit_x(scene), np.zeros(2, np.int32))
    means = points.means(np.full(len(points.point_ids), 0.25, np.float32))
    np.testing.assert_allclose(means, [0.25, 1.0], rtol=FLOAT64_ROUNDING)


# ---------------------------------------------------------------------------
# records


def authored_scene():
    """Instancers /A (4 authored rows, row 2 masked: instances 0, 1, 2 at rows 3, 0, 1), the native root /N
    (instance 3) and /B (instance 4, 1 row)."""
    scene = scene_of([translate(float(k), 0.0, 0.0) for k in range(5)], floor=False)
    table = dataclasses.replace(
        scene.instances, instancer_paths=("/A", "/N", "/B"),
        instance_instancer=np.array([0, 0, 0, 1, 2], np.int32),
        instance_index=np.array([3, 0, 1, 0, 0], np.int32),
        instancer_instance_count=np.array([4, 1, 1], np.int32),
        instancer_native=np.array([False, True, False]))
    return dataclasses.replace(scene, instances=table)


def test_records_put_each_mean_on_its_authored_row_and_masked_rows_get_one():
    scene = authored_scene()
    points = InstancePoints(scene, unit_y(scene), unit_x(scene), np.zeros(5, np.int32))
    means = np.array([0.1, 0.2, 0.3, 0.4, 0.5], np.float32)
    records = points.records(means, 12.0)
    assert [r.prim for r in records] == ["/A", "/N", "/B"]
    assert all(r.name == "bake:ao" and r.type_name == "float" and r.time == 12.0 for r in records)
    assert [r.interpolation for r in records] == ["vertex", "constant", "vertex"]
    np.testing.assert_array_equal(records[0].values, np.float32([0.2, 0.3, 1.0, 0.1]))
    np.testing.assert_array_equal(records[1].values, np.float32([0.4]))
    np.testing.assert_array_equal(records[2].values, np.float32([0.5]))
    assert all(r.values.dtype == np.float32 for r in records)
    assert points.records(means, None)[0].time is None


def test_records_without_authored_rows_follow_the_table_order():
    # build_scene leaves instance_index and instancer_instance_count empty, as a Scene not read from USD
    scene = scene_of()
    assert len(scene.instances.instance_index) == 0
    points = InstancePoints(scene, unit_y(scene), unit_x(scene), np.zeros(3, np.int32))
    np.testing.assert_array_equal(points.row, [0, 1, 2])
    (record,) = points.records(np.array([0.7, 0.8, 0.9], np.float32), None)
    assert record.prim == "/World/Scatter" and record.interpolation == "vertex"
    np.testing.assert_array_equal(record.values, np.float32([0.7, 0.8, 0.9]))


def test_rows_are_counted_per_instancer_without_authored_rows():
    scene = scene_of([translate(float(k), 0.0, 0.0) for k in range(4)], floor=False)
    table = Instances(**{**{f.name: getattr(scene.instances, f.name) for f in dataclasses.fields(Instances)},
                         "instancer_paths": ("/A", "/B"),
                         "instance_instancer": np.array([1, 0, 1, 1], np.int32)})
    scene = dataclasses.replace(scene, instances=table)
    points = InstancePoints(scene, unit_y(scene), unit_x(scene), np.zeros(4, np.int32))
    np.testing.assert_array_equal(points.row, [0, 0, 1, 2])
    np.testing.assert_array_equal(points.instancer_count, [1, 3])
    a, b = points.records(np.array([0.1, 0.2, 0.3, 0.4], np.float32), None)
    np.testing.assert_array_equal(a.values, np.float32([0.2]))
    np.testing.assert_array_equal(b.values, np.float32([0.1, 0.3, 0.4]))
