"""The scene after mesh refinement: receiver prims re-authored as triangles inside their authored faces.

A refining processor (sky_visibility) splits receiver triangles. ``refine_scene`` turns its refined
triangles into

- one RefinedMesh record per prim, which ``usdbake.stages.refined_mesh`` expands into USD with every
  authored attribute carried onto the new faces, and
- a Scene in which those prims have the refined topology, exactly as extraction would read the
  baked output: per-vertex processors in the same run write results that fit it.

Point order per refined prim: the authored points at their own indices, then the new points in
the order of their first use. Pure numpy.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ...core.records import RefinedMesh
from ...core.scene import Scene

_FORWARD = np.array([0, 1, 2])
_REVERSED = np.array([2, 1, 0])


def refine_scene(scene: Scene, points: np.ndarray, point_source: np.ndarray, triangles: np.ndarray,
                 source: np.ndarray, weights: np.ndarray, *, with_sources: bool = False) -> tuple:
    """The refined Scene and one RefinedMesh record per prim that has refined faces; ``with_sources``: also
    the Scene triangle each refined Scene triangle lies in ((T',) int64) and its corners' barycentric
    coordinates there ((T', 3, 3) float64), to carry what was laid out on the refined Scene back to the input's.

    Parameters
    ----------
    points : (P', 3) float refined vertices in the scene frame
    point_source : (P',) int Scene point each vertex is, -1 for a new one
    triangles : (F, 3) int indices into ``points``, scene winding; a prim's faces keep their order
    source : (F,) int Scene triangle each face lies in
    weights : (F, 3, 3) float barycentric coordinates of each face corner in its source triangle
    """
    source = np.asarray(source, np.int64)
    triangles = np.asarray(triangles, np.int64)
    point_source = np.asarray(point_source, np.int64)
    face_prim = scene.tri_prim[source]
    refined_order = np.argsort(face_prim, kind="stable")
    refined_prims, refined_start = np.unique(face_prim[refined_order], return_index=True)
    refined_bounds = dict(zip(refined_prims.tolist(), np.append(refined_start, len(source))[1:].tolist()))
    refined_first = dict(zip(refined_prims.tolist(), refined_start.tolist()))
    scene_order = np.argsort(scene.tri_prim, kind="stable")
    scene_start = np.searchsorted(scene.tri_prim[scene_order], np.arange(len(scene.prim_paths) + 1))

    parts = {name: [] for name in ("points", "tris", "normals", "albedo", "emission", "face", "corner",
                                    "instance", "double_sided", "source", "weights")}
    point_start, face_count, corner_count, records = [0], [], [], []
    for prim in range(len(scene.prim_paths)):
        span = scene.prim_points(prim)
        authored = scene.points[span]
        if prim in refined_bounds:
            faces = refined_order[refined_first[prim]:refined_bounds[prim]]
            mirrored = bool(np.linalg.det(scene.prim_to_world[prim][:3, :3]) < 0)  # scene winding was flipped
            record, new_points, local = _refined_prim(scene, prim, points, point_source, triangles[faces],
                                                      source[faces], weights[faces], mirrored)
            records.append(record)
            prim_points = np.concatenate([authored, new_points.astype(np.float32)])
            tri_source = source[faces]
            order = _REVERSED if mirrored else _FORWARD  # the record's corner order, in scene winding
            corner = 3 * np.arange(len(faces))[:, None] + order[None, :]
            face = np.arange(len(faces))
            parts["weights"].append(weights[faces])
        else:
            tri_source = scene_order[scene_start[prim]:scene_start[prim + 1]]
            prim_points = authored
            local = scene.tri_vertices[tri_source].astype(np.int64) - span.start
            corner, face = scene.tri_corner[tri_source], scene.tri_face[tri_source]
            parts["weights"].append(np.broadcast_to(np.eye(3), (len(tri_source), 3, 3)))
        parts["points"].append(prim_points)
        parts["tris"].append(local + point_start[-1])
        parts["corner"].append(corner)
        parts["face"].append(face)
        parts["source"].append(tri_source)
        point_start.append(point_start[-1] + len(prim_points))
        face_count.append(len(faces) if prim in refined_bounds else int(scene.prim_face_count[prim]))
        corner_count.append(3 * len(faces) if prim in refined_bounds else int(scene.prim_corner_count[prim]))

    all_source = np.concatenate(parts["source"]) if parts["source"] else np.zeros(0, np.int64)
    new_points = np.concatenate(parts["points"]) if parts["points"] else np.zeros((0, 3), np.float32)
    tri_vertices = np.concatenate(parts["tris"]).astype(np.int32) if parts["tris"] else np.zeros((0, 3), np.int32)
    corners = new_points[tri_vertices].astype(np.float64)
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    tri_prim = scene.tri_prim[all_source]
    refined = dataclasses.replace(
        scene, points=new_points, tri_vertices=tri_vertices,
        tri_normals=scene.tri_normals[all_source], tri_areas=areas.astype(np.float32),
        tri_albedo=scene.tri_albedo[all_source], tri_emission=scene.tri_emission[all_source],
        tri_transmittance=scene.tri_transmittance[all_source], tri_prim=tri_prim, tri_face=np.concatenate(parts["face"]).astype(np.int32),
        tri_instance=scene.tri_instance[all_source], tri_double_sided=scene.tri_double_sided[all_source],
        tri_corner=np.concatenate(parts["corner"]).astype(np.int32).reshape(-1, 3),
        tri_st=_refined_uvs(scene.tri_st, all_source, parts["weights"]),
        tri_lightmap_uv=_refined_uvs(scene.tri_lightmap_uv, all_source, parts["weights"]),
        point_prim=np.repeat(np.arange(len(scene.prim_paths), dtype=np.int32), np.diff(point_start)),
        prim_point_start=np.array(point_start, np.int64), prim_face_count=np.array(face_count, np.int32),
        prim_corner_count=np.array(corner_count, np.int64),
        lights=_stored_lights(scene.lights),
    )
    if with_sources:
        corner_weights = np.concatenate(parts["weights"]) if parts["weights"] else np.zeros((0, 3, 3))
        return refined, records, all_source, np.asarray(corner_weights, np.float64)
    return refined, records


def _refined_uvs(tri_uvs: np.ndarray, source: np.ndarray, weights: list) -> np.ndarray:
    """(F, 3, 2) float32 UVs of the refined triangles' corners: their barycentric weights in the source
    triangle applied to its corners' UVs (NaN stays NaN: a prim without the set)."""
    if not weights:
        return np.zeros((0, 3, 2), np.float32)
    return np.einsum("fik,fkd->fid", np.concatenate(weights), tri_uvs[source].astype(np.float64)).astype(np.float32)


def _stored_lights(lights):
    """The lights with a textured dome's file read into its array: the refined Scene is a product the result
    cache stores as plain data, which holds arrays, not the file reader (``stages.sky_dome.DomeTexture``)."""
    if lights.dome_source is None or isinstance(lights.dome_source, np.ndarray):
        return lights
    return dataclasses.replace(lights, dome_source=np.array(lights.dome_texture))


def _refined_prim(scene: Scene, prim: int, points: np.ndarray, point_source: np.ndarray, triangles: np.ndarray,
                  source: np.ndarray, weights: np.ndarray, mirrored: bool) -> tuple[RefinedMesh, np.ndarray, np.ndarray]:
    """(record, the prim's new points in the scene frame, its triangles in refined-prim point indices,
    scene winding). A ``mirrored`` prim's record is wound back for rightHanded in its own space."""
    span = scene.prim_points(prim)
    authored_count = span.stop - span.start
    origin = point_source[triangles]
    is_new = origin < 0
    new_ids, first_use = np.unique(triangles[is_new], return_index=True)
    first_use_rank = np.argsort(np.argsort(first_use))  # of each sorted new id: its place in order of use
    local = np.where(is_new, 0, origin - span.start)
    local[is_new] = authored_count + first_use_rank[np.searchsorted(new_ids, triangles[is_new])]
    new_ids = new_ids[np.argsort(first_use)]  # in order of first use
    if mirrored:
        written, written_weights = local[:, ::-1], weights[:, ::-1, :]
    else:
        written, written_weights = local, weights
    record = RefinedMesh(
        prim=scene.prim_paths[prim], point_count=authored_count,
        triangles=np.ascontiguousarray(written, np.int32), face=scene.tri_face[source].astype(np.int32),
        source_corners=scene.tri_corner[source].astype(np.int32),
        corner_weights=np.ascontiguousarray(written_weights, np.float64))
    return record, np.asarray(points, np.float64)[new_ids], local
