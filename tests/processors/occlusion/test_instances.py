"""processors/occlusion/instances.py on hand-built Scenes: which prims are instanced receivers, and the
area-weighted per-instance means (native roots and PointInstancer rows) against a plain float64 loop.

The scenes are right triangles with integer legs, so their float32 areas are exact and the only
rounding is the float64 sum (native means) or the float32 column (PointInstancer means).
"""

from __future__ import annotations

import numpy as np
import pytest

from usdbake.core.scene import Instances, Scene
from usdbake.processors.occlusion.instances import InstanceMeans, instanced_receivers, per_instance_means

from tolerances import FLOAT32_STORAGE, FLOAT64_ROUNDING


def right_triangle(x0: float, a: float, b: float) -> np.ndarray:
    """(3, 3) corners of a right triangle with legs a (along x) and b (along z) at (x0, 0, 0): area a b / 2."""
    return np.array([[x0, 0.0, 0.0], [x0 + a, 0.0, 0.0], [x0, 0.0, b]])


def make_scene(prims, *, instances: Instances | None = None) -> Scene:
    """A Scene from prims given as dicts: path, tris (list of (3, 3) corner arrays, each its own 3 points),
    and optionally writable (True), skip (False), roots (()), instance (-1)."""
    points, tri_vertices, tri_prim, tri_instance, point_prim, start = [], [], [], [], [], [0]
    for m, prim in enumerate(prims):
        for corners in prim["tris"]:
            base = len(points)
            points.extend(np.asarray(corners, np.float64))
            tri_vertices.append([base, base + 1, base + 2])
            tri_prim.append(m)
            tri_instance.append(prim.get("instance", -1))
            point_prim.extend([m] * 3)
        start.append(len(points))
    points = np.asarray(points, np.float64).reshape(-1, 3)
    tri_vertices = np.asarray(tri_vertices, np.int32).reshape(-1, 3)
    corners = points[tri_vertices]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]).reshape(-1, 3)
    length = np.linalg.norm(cross, axis=1)
    normals = np.where(length[:, None] > 0, cross / np.maximum(length, 1e-300)[:, None], 0.0)
    count, m = len(tri_vertices), len(prims)
    return Scene(
        points=points.astype(np.float32), tri_vertices=tri_vertices, tri_normals=normals.astype(np.float32),
        tri_areas=(length / 2).astype(np.float32), tri_albedo=np.full((count, 3), 0.5, np.float32),
        tri_emission=np.zeros((count, 3), np.float32), tri_prim=np.asarray(tri_prim, np.int32),
        tri_face=np.arange(count, dtype=np.int32), tri_instance=np.asarray(tri_instance, np.int32),
        tri_double_sided=np.zeros(count, bool), point_prim=np.asarray(point_prim, np.int32),
        prim_paths=tuple(p["path"] for p in prims), prim_point_start=np.asarray(start, np.int64),
        prim_face_count=np.array([len(p["tris"]) for p in prims], np.int32),
        prim_writable=np.array([p.get("writable", True) for p in prims], bool),
        prim_skip=np.array([p.get("skip", False) for p in prims], bool),
        prim_surface=("",) * m, prim_instance_roots=tuple(tuple(p.get("roots", ())) for p in prims),
        instances=instances if instances is not None else Instances(),
    )


def reference_mean(scene: Scene, values, prims_selected, fill: float) -> float:
    """Plain float64 loop: sum over triangles of (corner mean x area) / sum of areas, or fill."""
    total = weight = 0.0
    for t in range(scene.num_triangles):
        if int(scene.tri_prim[t]) not in prims_selected:
            continue
        a, b, c = (scene.points[i].astype(np.float64) for i in scene.tri_vertices[t])
        area = 0.5 * float(np.linalg.norm(np.cross(b - a, c - a)))
        corner_mean = sum(float(values[i]) for i in scene.tri_vertices[t]) / 3.0
        total += corner_mean * area
        weight += area
    return total / weight if weight > 0 else fill


# ---------------------------------------------------------------------------
# instanced_receivers


def test_instanced_receivers_are_read_only_unskipped_prims_with_triangles():
    tri = [right_triangle(0, 1, 1)]
    scene = make_scene([
        {"path": "/Writable", "tris": tri},                                  # ordinary receiver: not an instance
        {"path": "/Proxy", "tris": tri, "writable": False},                  # instance proxy: yes
        {"path": "/Skipped", "tris": tri, "writable": False, "skip": True},  # bake:skip: no
        {"path": "/Empty", "tris": [], "writable": False},                   # no triangles: no
        {"path": "/Proto", "tris": tri + tri, "writable": False},            # prototype: yes
    ])
    result = instanced_receivers(scene)
    np.testing.assert_array_equal(result, [1, 4])
    assert np.issubdtype(result.dtype, np.integer)


def test_no_instances_no_receivers():
    scene = make_scene([{"path": "/A", "tris": [right_triangle(0, 1, 1)]}])
    assert len(instanced_receivers(scene)) == 0
    assert len(instanced_receivers(make_scene([]))) == 0


def test_a_read_only_prim_without_triangles_at_the_end_is_not_counted():
    # bincount's minlength must cover trailing prims that own no triangle
    scene = make_scene([{"path": "/A", "tris": [right_triangle(0, 1, 1)], "writable": False},
                        {"path": "/B", "tris": [], "writable": False}])
    np.testing.assert_array_equal(instanced_receivers(scene), [0])


# ---------------------------------------------------------------------------
# per_instance_means: native instances


def native_scene():
    """Two native instances: /I0 has two meshes (one nested under an inner instance /I0/Inner), /I1 one;
    a writable floor and a skipped proxy are not selected."""
    return make_scene([
        {"path": "/Floor", "tris": [right_triangle(10, 4, 4)]},
        {"path": "/I0/Base", "tris": [right_triangle(0, 1, 2), right_triangle(1, 3, 2)], "writable": False,
         "roots": ("/I0",)},
        {"path": "/I0/Inner/Head", "tris": [right_triangle(5, 2, 2)], "writable": False,
         "roots": ("/I0", "/I0/Inner")},
        {"path": "/I1/Base", "tris": [right_triangle(20, 1, 1), right_triangle(22, 2, 1)], "writable": False,
         "roots": ("/I1",)},
    ])


def test_native_means_are_area_weighted_over_every_mesh_under_the_outermost_root():
    scene = native_scene()
    rng = np.random.default_rng(7)  # fixed seed: arbitrary per-point values in [0, 1)
    values = rng.random(scene.num_points)
    prims = instanced_receivers(scene)
    means = per_instance_means(scene, values, prims, fill=-1.0)
    assert isinstance(means, InstanceMeans)
    assert set(means.native) == {"/I0", "/I1"}  # the inner instance is folded into its outermost root
    assert means.instancers == {}
    np.testing.assert_allclose(means.native["/I0"], reference_mean(scene, values, {1, 2}, -1.0),
                               rtol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(means.native["/I1"], reference_mean(scene, values, {3}, -1.0),
                               rtol=FLOAT64_ROUNDING)
    assert all(isinstance(v, float) for v in means.native.values())


def test_native_mean_of_a_hand_computed_case():
    # /I: areas 1 (legs 1, 2) and 3 (legs 3, 2); corner values 0,0,0 and 1,1,1 -> (0 x 1 + 1 x 3) / 4
    scene = make_scene([{"path": "/I/M", "tris": [right_triangle(0, 1, 2), right_triangle(1, 3, 2)],
                         "writable": False, "roots": ("/I",)}])
    values = np.array([0, 0, 0, 1, 1, 1], np.float32)
    means = per_instance_means(scene, values, np.array([0]), fill=0.5)
    assert means.native == {"/I": pytest.approx(0.75, rel=FLOAT64_ROUNDING)}


def test_a_triangle_value_is_the_mean_of_its_corners():
    scene = make_scene([{"path": "/I/M", "tris": [right_triangle(0, 1, 1)], "writable": False, "roots": ("/I",)}])
    means = per_instance_means(scene, np.array([0.0, 0.3, 0.9]), np.array([0]), fill=0.0)
    assert means.native["/I"] == pytest.approx(0.4, rel=FLOAT64_ROUNDING)


def test_degenerate_triangles_weigh_nothing_and_an_all_degenerate_instance_gets_fill():
    collinear = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    scene = make_scene([
        {"path": "/I/M", "tris": [right_triangle(0, 2, 1), collinear], "writable": False, "roots": ("/I",)},
        {"path": "/J/M", "tris": [collinear], "writable": False, "roots": ("/J",)},
    ])
    values = np.array([0.2, 0.2, 0.2, 1e6, 1e6, 1e6, 5.0, 5.0, 5.0])
    means = per_instance_means(scene, values, np.array([0, 1]), fill=0.125)
    assert means.native["/I"] == pytest.approx(0.2, rel=FLOAT64_ROUNDING)  # the huge value has no area
    assert means.native["/J"] == 0.125


def test_only_the_selected_prims_count():
    scene = native_scene()
    values = np.arange(scene.num_points, dtype=np.float64)
    means = per_instance_means(scene, values, np.array([2]), fill=0.0)  # only /I0/Inner/Head
    assert set(means.native) == {"/I0"}
    np.testing.assert_allclose(means.native["/I0"], reference_mean(scene, values, {2}, 0.0), rtol=FLOAT64_ROUNDING)
    empty = per_instance_means(scene, values, np.zeros(0, np.int64), fill=0.0)
    assert empty.native == {} and empty.instancers == {}


def test_non_finite_values_stay_in_their_own_instance():
    scene = native_scene()
    values = np.full(scene.num_points, 0.5)
    values[scene.prim_points(3)] = np.nan  # all of /I1
    means = per_instance_means(scene, values, instanced_receivers(scene), fill=0.0)
    assert np.isnan(means.native["/I1"])
    assert means.native["/I0"] == pytest.approx(0.5, rel=FLOAT64_ROUNDING)


# ---------------------------------------------------------------------------
# per_instance_means: PointInstancer rows


def instancer_scene(*, authored: bool = True):
    """Two PointInstancers and one native instance in the instance table.

    /A: 5 authored rows, rows 1 and 3 masked; instances 0, 1, 2 at rows 0, 2, 4.
    /B: 2 authored rows; instance 3 (row 1) is baked, instance 4 (row 0) only has degenerate triangles.
    /N: a native instance (one instance, 5), keyed by its root, not in ``instancers``.
    /C: one instance (6) whose prim is not selected: /C is left out.
    """
    collinear = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    prims = [{"path": "/Ground", "tris": [right_triangle(-10, 5, 5)]}]
    legs = [(1, 2), (2, 2), (3, 1), (1, 1)]
    for j, (a, b) in enumerate(legs):
        prims.append({"path": f"/Proto{j}", "tris": [right_triangle(3 * j, a, b), right_triangle(3 * j, b, a)],
                      "writable": False, "instance": j})
    prims.append({"path": "/B/Proto", "tris": [collinear], "writable": False, "instance": 4})
    prims.append({"path": "/N/M", "tris": [right_triangle(30, 1, 1)], "writable": False, "instance": 5,
                  "roots": ("/N",)})
    prims.append({"path": "/C/Proto", "tris": [right_triangle(40, 1, 1)], "writable": False, "instance": 6})
    table = Instances(
        instancer_paths=("/A", "/B", "/N", "/C"), prototype_paths=("/P",),
        instance_instancer=np.array([0, 0, 0, 1, 1, 2, 3], np.int32),
        instance_prototype=np.zeros(7, np.int32),
        instance_transforms=np.tile(np.eye(4), (7, 1, 1)),
        instance_index=np.array([0, 2, 4, 1, 0, 0, 0], np.int32) if authored else np.zeros(0, np.int32),
        instancer_instance_count=np.array([5, 2, 1, 1], np.int32) if authored else np.zeros(0, np.int32),
        instancer_native=np.array([False, False, True, False]),
    )
    return make_scene(prims, instances=table)


def test_point_instancer_rows_get_their_instance_mean_and_masked_rows_fill():
    scene = instancer_scene()
    rng = np.random.default_rng(11)  # fixed seed: arbitrary per-point values in [0, 1)
    values = rng.random(scene.num_points)
    selected = np.arange(1, 7)  # every instanced prim but /C/Proto
    means = per_instance_means(scene, values, selected, fill=-2.0)
    assert set(means.instancers) == {"/A", "/B"}  # /N is native, /C has nothing baked
    assert set(means.native) == {"/N"}
    np.testing.assert_allclose(means.native["/N"], reference_mean(scene, values, {6}, -2.0), rtol=FLOAT64_ROUNDING)

    a = means.instancers["/A"]
    assert a.dtype == np.float32 and a.shape == (5,)
    expected_a = [reference_mean(scene, values, {1}, -2.0), -2.0, reference_mean(scene, values, {2}, -2.0),
                  -2.0, reference_mean(scene, values, {3}, -2.0)]
    np.testing.assert_allclose(a, expected_a, rtol=FLOAT32_STORAGE)

    b = means.instancers["/B"]
    assert b.dtype == np.float32 and b.shape == (2,)
    # row 0: instance 4, baked but with no area -> fill; row 1: instance 3
    np.testing.assert_allclose(b, [-2.0, reference_mean(scene, values, {4}, -2.0)], rtol=FLOAT32_STORAGE)


def test_a_scene_not_read_from_usd_gets_one_slot_per_instance_in_table_order():
    scene = instancer_scene(authored=False)
    values = np.linspace(0.0, 1.0, scene.num_points)
    means = per_instance_means(scene, values, np.arange(1, 8), fill=9.0)
    assert set(means.instancers) == {"/A", "/B", "/C"}
    np.testing.assert_allclose(means.instancers["/A"], [reference_mean(scene, values, {m}, 9.0) for m in (1, 2, 3)],
                               rtol=FLOAT32_STORAGE)
    np.testing.assert_allclose(means.instancers["/B"], [reference_mean(scene, values, {4}, 9.0), 9.0],
                               rtol=FLOAT32_STORAGE)
    np.testing.assert_allclose(means.instancers["/C"], [reference_mean(scene, values, {7}, 9.0)],
                               rtol=FLOAT32_STORAGE)


def test_constant_values_give_that_constant_everywhere():
    scene = instancer_scene()
    means = per_instance_means(scene, np.full(scene.num_points, 0.625), np.arange(1, 8), fill=0.0)
    np.testing.assert_array_equal(means.instancers["/A"], np.float32([0.625, 0, 0.625, 0, 0.625]))
    np.testing.assert_array_equal(means.instancers["/C"], np.float32([0.625]))
    assert means.native == {"/N": 0.625}


def test_inputs_are_left_untouched_and_results_are_new_arrays():
    scene = instancer_scene()
    values = np.linspace(0.0, 1.0, scene.num_points)
    before = values.copy()
    first = per_instance_means(scene, values, np.arange(1, 8), fill=0.0)
    np.testing.assert_array_equal(values, before)
    second = per_instance_means(scene, values, np.arange(1, 8), fill=0.0)
    assert first.instancers["/A"] is not second.instancers["/A"]
    with pytest.raises(AttributeError):  # frozen
        first.native = {}


def test_too_few_point_values_is_an_error():
    scene = native_scene()
    with pytest.raises(IndexError):
        per_instance_means(scene, np.zeros(scene.num_points - 1), instanced_receivers(scene), fill=0.0)
