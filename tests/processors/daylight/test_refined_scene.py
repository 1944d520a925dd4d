"""processors.daylight.refined_scene on its own: ``refine_scene`` on refinements written by hand.

Three quad prims (two triangles each, faces 0 and 1, face-vertex slots of a quad). Triangles are
quartered at their edge midpoints (the new points listed in a scrambled order, the faces of two prims
interleaved); the checks are written from the definitions in the module docstring:

- the refined Scene: authored points at their own indices, new points in order of first use, each
  corner at its barycentric weights' combination of the source triangle's corners, areas summing to
  the authored ones, per-triangle attributes carried from the source, the prim tables updated, the
  unrefined prim untouched;
- the RefinedMesh records: one per refined prim, local triangle indices, authored face, face-vertex
  slots and weights of the source; a mirrored prim's record wound back (and its corner slots reversed);
- nothing refined: the scene comes back as it was, with no records.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from daylight_boxes import quad_scene
from tolerances import FLOAT32_ROUNDING, FLOAT32_STORAGE
from usdbake.processors.daylight.refined_scene import refine_scene

QUARTERS = np.array([  # barycentric weights of the four children of a triangle split at its edge midpoints
    [[1, 0, 0], [0.5, 0.5, 0], [0.5, 0, 0.5]],
    [[0.5, 0.5, 0], [0, 1, 0], [0, 0.5, 0.5]],
    [[0.5, 0, 0.5], [0, 0.5, 0.5], [0, 0, 1]],
    [[0.5, 0.5, 0], [0, 0.5, 0.5], [0.5, 0, 0.5]],
], np.float64)


def three_quads(mirrored_prim: int | None = None):
    """Prims /P0, /P1, /P2: unit quads at heights 0, 1, 2 (4 points, triangles (0 1 2) and (0 2 3) each), with
    distinct albedo, transmittance, authored faces and face-vertex slots, so that carrying them shows."""
    quads = [np.array([[0, 0, z], [1, 0, z], [1, 1, z], [0, 1, z]], np.float64) for z in (0.0, 1.0, 2.0)]
    scene = quad_scene([([quads[0]], 0.1, 0.0), ([quads[1]], 0.2, 0.0), ([quads[2]], 0.3, 0.4)])
    # one quad per prim: prim m's triangles are 2m (0 1 2) and 2m + 1 (0 2 3)
    prim_to_world = np.repeat(np.eye(4)[None], 3, axis=0)
    if mirrored_prim is not None:
        prim_to_world[mirrored_prim] = np.diag([-1.0, 1.0, 1.0, 1.0])
    return dataclasses.replace(
        scene, tri_face=np.array([5, 6], np.int32)[np.arange(6) % 2], tri_corner=np.tile([[0, 1, 2], [0, 2, 3]], (3, 1)),
        tri_double_sided=np.arange(6) % 3 == 0, tri_instance=np.arange(6, dtype=np.int32) - 10,
        prim_to_world=prim_to_world)


def quarter(scene, triangles, new_start):
    """Refined (faces, sources, weights, new point positions) for quartering the scene triangles given:
    corner ids index a refined point array whose first P entries are the scene's points and whose new
    points start at ``new_start`` (one per edge midpoint, in order of creation)."""
    faces, sources, weights, positions = [], [], [], []
    for t in triangles:
        v = scene.tri_vertices[t].astype(np.int64)
        corner = scene.points[v].astype(np.float64)
        mid = [new_start + len(positions) + k for k in range(3)]  # m01, m12, m20
        positions += [0.5 * (corner[0] + corner[1]), 0.5 * (corner[1] + corner[2]), 0.5 * (corner[2] + corner[0])]
        faces += [[v[0], mid[0], mid[2]], [mid[0], v[1], mid[1]], [mid[2], mid[1], v[2]], [mid[0], mid[1], mid[2]]]
        sources += [t] * 4
        weights.append(QUARTERS)
    return np.array(faces), np.array(sources), np.concatenate(weights), np.array(positions)


def refinement(scene, triangles):
    """Refined arrays for quartering ``triangles``, faces of prims interleaved in their given order and the new
    points stored in reverse (so the order of first use is not the stored one)."""
    count = scene.num_points
    faces, sources, weights, positions = quarter(scene, triangles, count)
    reverse = np.arange(len(positions))[::-1]  # new point k is stored at count + reverse[k]
    faces = np.where(faces >= count, count + reverse[np.maximum(faces - count, 0)], faces)
    points = np.concatenate([scene.points.astype(np.float64), positions[::-1]])
    point_source = np.concatenate([np.arange(count), np.full(len(positions), -1)])
    return points, point_source, faces, sources, weights


def test_refined_scene_corners_areas_and_carried_attributes():
    scene = three_quads()
    # triangle 0 of prim 0, triangle 1 of prim 2 and triangle 1 of prim 0: two prims' faces interleaved
    chosen = [0, 5, 1]
    points, point_source, faces, sources, weights = refinement(scene, chosen)
    refined, records = refine_scene(scene, points, point_source, faces, sources, weights)

    # prim 0: both triangles quartered (8 faces), prim 1 untouched (one authored quad), prim 2: the 4 faces given
    assert refined.prim_face_count.tolist() == [8, 1, 4]
    assert refined.num_triangles == 14
    assert refined.tri_prim.tolist() == [0] * 8 + [1] * 2 + [2] * 4
    # prim 0: 4 authored and 6 new points (each quartered triangle made its own midpoints: nothing is welded)
    assert refined.prim_point_start.tolist() == [0, 4 + 6, 10 + 4, 14 + 4 + 3]
    np.testing.assert_array_equal(refined.point_prim, np.repeat([0, 1, 2], [10, 4, 7]))

    # every refined corner is its weights' combination of the source triangle's corners
    corners = refined.points[refined.tri_vertices].astype(np.float64)
    ours = np.flatnonzero(refined.tri_prim != 1)
    source_of = sources[np.argsort(scene.tri_prim[sources], kind="stable")]  # refined faces grouped by prim
    assert len(source_of) == len(ours)
    source_corners = scene.points[scene.tri_vertices[source_of]].astype(np.float64)
    prim_weights = weights[np.argsort(scene.tri_prim[sources], kind="stable")]
    np.testing.assert_allclose(corners[ours], np.einsum("fik,fkc->fic", prim_weights, source_corners),
                               atol=FLOAT32_STORAGE)
    # the authored points keep their indices within their prims
    for prim in range(3):
        span = scene.prim_points(prim)
        start = refined.prim_point_start[prim]
        np.testing.assert_array_equal(refined.points[start:start + 4], scene.points[span])

    # areas recomputed and summing to those of the triangles they came from; attributes from the source triangle
    for prim, came_from in ((0, [0, 1]), (1, [2, 3]), (2, [5])):
        np.testing.assert_allclose(refined.tri_areas[refined.tri_prim == prim].sum(),
                                   scene.tri_areas[came_from].sum(), rtol=FLOAT32_STORAGE)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    np.testing.assert_allclose(refined.tri_areas, 0.5 * np.linalg.norm(cross, axis=1), rtol=FLOAT32_ROUNDING * 4)
    np.testing.assert_allclose(cross / np.linalg.norm(cross, axis=1, keepdims=True), refined.tri_normals,
                               atol=FLOAT32_STORAGE)  # same winding as the source
    carried = np.concatenate([source_of[:8], [2, 3], source_of[8:]])  # prim 1 keeps its two triangles
    for name in ("tri_normals", "tri_albedo", "tri_emission", "tri_transmittance", "tri_instance", "tri_double_sided"):
        np.testing.assert_array_equal(getattr(refined, name), getattr(scene, name)[carried], err_msg=name)
    # the refined faces' tri_face numbers faces of the refined mesh; the unrefined prim keeps its own
    assert refined.tri_face[:8].tolist() == list(range(8)) and refined.tri_face[8:10].tolist() == [5, 6]
    np.testing.assert_array_equal(refined.tri_corner[:8], 3 * np.arange(8)[:, None] + [0, 1, 2])
    np.testing.assert_array_equal(refined.tri_corner[8:10], [[0, 1, 2], [0, 2, 3]])


def test_new_points_come_in_order_of_first_use():
    scene = three_quads()
    points, point_source, faces, sources, weights = refinement(scene, [0])
    refined, _ = refine_scene(scene, points, point_source, faces, sources, weights)
    local = refined.tri_vertices[:4].ravel()
    new = local[local >= 4]
    first_use = new[np.sort(np.unique(new, return_index=True)[1])]
    assert first_use.tolist() == [4, 5, 6]  # numbered as they first appear in the faces
    # and they are the midpoints, (0 + 1) / 2 first: the first face is (v0, m01, m20)
    corner = scene.points[scene.tri_vertices[0]].astype(np.float64)
    np.testing.assert_allclose(refined.points[4:7], [0.5 * (corner[0] + corner[1]), 0.5 * (corner[0] + corner[2]),
                                                     0.5 * (corner[1] + corner[2])], atol=FLOAT32_ROUNDING)


def test_records_describe_each_refined_prim():
    scene = three_quads()
    points, point_source, faces, sources, weights = refinement(scene, [0, 5, 1])
    refined, records = refine_scene(scene, points, point_source, faces, sources, weights)
    assert [r.prim for r in records] == ["/P0", "/P2"]
    order = np.argsort(scene.tri_prim[sources], kind="stable")
    for record, prim, rows in ((records[0], 0, order[:8]), (records[1], 2, order[8:])):
        assert record.point_count == 4
        faces_here = refined.tri_prim == prim
        np.testing.assert_array_equal(record.triangles, refined.tri_vertices[faces_here] - refined.prim_point_start[prim])
        assert record.triangles.dtype == np.int32
        np.testing.assert_array_equal(record.face, scene.tri_face[sources[rows]])
        np.testing.assert_array_equal(record.source_corners, scene.tri_corner[sources[rows]])
        np.testing.assert_array_equal(record.corner_weights, weights[rows])
    # a refined prim is made of the faces given for it: prim 2's other triangle (not given) is gone
    assert len(records[1].triangles) == 4 and refined.prim_face_count[2] == 4


def test_a_mirrored_prim_is_wound_back_in_its_record():
    """A prim whose local-to-world matrix mirrors: the scene's winding was flipped on extraction, so the record
    (authored rightHanded in the prim's own space) lists each triangle's corners and weights reversed, and the
    refined Scene's corner slots point at them in scene winding."""
    scene = three_quads(mirrored_prim=0)
    points, point_source, faces, sources, weights = refinement(scene, [0])
    refined, records = refine_scene(scene, points, point_source, faces, sources, weights)
    plain, plain_records = refine_scene(three_quads(), points, point_source, faces, sources, weights)
    np.testing.assert_array_equal(refined.tri_vertices, plain.tri_vertices)  # the Scene keeps scene winding
    np.testing.assert_array_equal(records[0].triangles, plain_records[0].triangles[:, ::-1])
    np.testing.assert_array_equal(records[0].corner_weights, plain_records[0].corner_weights[:, ::-1])
    np.testing.assert_array_equal(refined.tri_corner[:4], 3 * np.arange(4)[:, None] + [2, 1, 0])
    # slot k of the refined Scene's corner is the record's corner it names: the same point
    flat = records[0].triangles.ravel()
    np.testing.assert_array_equal(flat[refined.tri_corner[:4]], refined.tri_vertices[:4])


def test_nothing_refined_gives_the_scene_back():
    scene = three_quads()
    refined, records = refine_scene(scene, scene.points, np.arange(scene.num_points), np.zeros((0, 3), np.int64),
                                    np.zeros(0, np.int64), np.zeros((0, 3, 3)))
    assert records == []
    order = np.argsort(scene.tri_prim, kind="stable")  # the identity here: a prim's triangles are contiguous
    np.testing.assert_array_equal(refined.points, scene.points)
    np.testing.assert_array_equal(refined.tri_vertices, scene.tri_vertices[order])
    for name in ("tri_normals", "tri_albedo", "tri_prim", "tri_face", "tri_corner", "tri_transmittance"):
        np.testing.assert_array_equal(getattr(refined, name), getattr(scene, name)[order], err_msg=name)
    np.testing.assert_allclose(refined.tri_areas, scene.tri_areas[order], rtol=FLOAT32_ROUNDING * 4)
    np.testing.assert_array_equal(refined.prim_point_start, scene.prim_point_start)
    np.testing.assert_array_equal(refined.prim_face_count, scene.prim_face_count)


@pytest.mark.parametrize("prim", [0, 1, 2])
def test_refining_one_prim_leaves_the_others_alone(prim):
    scene = three_quads()
    points, point_source, faces, sources, weights = refinement(scene, [2 * prim, 2 * prim + 1])
    refined, records = refine_scene(scene, points, point_source, faces, sources, weights)
    assert [r.prim for r in records] == [f"/P{prim}"]
    for other in {0, 1, 2} - {prim}:
        mine = scene.tri_vertices[scene.tri_prim == other] - scene.prim_point_start[other]
        theirs = refined.tri_vertices[refined.tri_prim == other] - refined.prim_point_start[other]
        np.testing.assert_array_equal(theirs, mine)
        span = slice(refined.prim_point_start[other], refined.prim_point_start[other + 1])
        np.testing.assert_array_equal(refined.points[span], scene.points[scene.prim_points(other)])


def test_a_refined_scene_under_a_textured_dome_is_cached(tmp_path):
    """radiosity asks for sky_visibility's refinement; the RefinedScene product carries the scene's lights,
    whose textured dome was a file reader the result cache could not store (a bake under a usdbake sky layer
    failed). It now stores the texels, and a second bake reads every step back from the cache."""
    from pxr import UsdLux

    import usdbake
    from stage_builders import add_mesh, new_stage
    from usdbake.core.records import Texture
    from usdbake.stages.hook import last_report
    from usdbake.stages.sidecars import write_texture

    texture = write_texture(Texture("sky.exr", np.full((8, 16, 3), 2.0, np.float32)), str(tmp_path))
    stage = new_stage(up_axis="Z")
    add_mesh(stage, "/World/Floor", [(0, 0, 0), (4, 0, 0), (4, 4, 0), (0, 4, 0)], [4], [0, 1, 2, 3])
    add_mesh(stage, "/World/Wall", [(2, 0, 0), (2, 4, 0), (2, 4, 2), (2, 0, 2)], [4], [0, 1, 2, 3])
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateTextureFileAttr(texture)
    params = {"form_factors": {"target_patches": 16, "rays": 16},
              "radiosity": {"sky_samples": 16, "gather_rays": 16, "patch_points": 1}}
    for run in range(2):
        layer = usdbake.bake(stage, processors=["radiosity"], params=params, cache_dir=str(tmp_path / "cache"),
                             texture_dir=str(tmp_path))
        actions = {step["processor"]: step["action"] for step in last_report(layer)}
        assert actions["sky_visibility"] == ("run" if run == 0 else "cached"), actions
