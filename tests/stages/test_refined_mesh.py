"""Refinement carries every authored attribute onto the child faces (issue: real assets, item 1).

The meshes are refined uniformly (every face split ``LEVELS`` times by sky_visibility's own
refinement), so each check below covers corners at edge midpoints and inside faces. References
are analytic: on a flat-shaded box the authored UVs are an affine function of the position on
each face, the authored normals are the face normals, a primvar authored as f(position) must
read f(position) at every new point.
"""

from __future__ import annotations

import filecmp
import shutil

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from production_assets import add_box, add_floor, new_stage, room_with_box, topology_mismatches
from tolerances import FLOAT32_ACCUMULATED, FLOAT32_ROUNDING, FLOAT32_STORAGE
from usdbake.cli.main import main
from usdbake.core.records import Attribute, Block, Primvar
from usdbake.processors.daylight.refined_scene import refine_scene
from usdbake.kernels.sky import patch_layout
from usdbake.kernels.tracer import Tracer
from usdbake.processors.daylight.sky_visibility import compute_sky_visibility
from usdbake.stages.bake_layer import author
from usdbake.stages.extract import extract_scene
from usdbake.stages.refined_mesh import complete_outputs

LEVELS = 2
"""Uniform four-way splits: every authored triangle becomes 16."""


def refined_stage(path):
    """Open ``path``, refine every receiver uniformly and author the carried records over it (session layer)."""
    stage = Usd.Stage.Open(str(path))
    scene = extract_scene(stage)
    product, _ = compute_sky_visibility(Tracer.from_scene(scene), scene, patches=patch_layout("uniform", count=8),
                                        samples=1, uniform=True, max_level=LEVELS)
    _, records = refine_scene(scene, product.face_points, product.point_source, product.face_vertices,
                              product.face_source, product.face_corner_weights)
    outputs = complete_outputs(stage, list(records))
    layer = Sdf.Layer.CreateAnonymous("bake")
    stage.GetSessionLayer().subLayerPaths.append(layer.identifier)
    author(layer, outputs, {})
    return stage, scene


def authored(path, prim: str, attribute: str = "points") -> np.ndarray:
    """An attribute's value in the unbaked file (the stage is kept open while it is read)."""
    stage = Usd.Stage.Open(str(path))
    return np.asarray(stage.GetPrimAtPath(prim).GetAttribute(attribute).Get())


def face_corners(mesh: UsdGeom.Mesh) -> np.ndarray:
    """(F, 3, 3) local positions of a triangle mesh's face corners."""
    points = np.asarray(mesh.GetPointsAttr().Get(), np.float64)
    return points[np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)]


@pytest.fixture
def room(tmp_path):
    return room_with_box(tmp_path)


def test_refined_box_and_floor_fit_their_topology(room):
    stage, _ = refined_stage(room)
    assert topology_mismatches(stage) == []
    box = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Box"))
    assert len(box.GetFaceVertexCountsAttr().Get()) == 6 * 2 * 4 ** LEVELS
    assert set(box.GetFaceVertexCountsAttr().Get()) == {3}


def test_authored_points_keep_their_index_and_new_points_lie_on_their_faces(room):
    before = authored(room, "/World/Box")
    stage, _ = refined_stage(room)
    box = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Box"))
    points = np.asarray(box.GetPointsAttr().Get())
    np.testing.assert_array_equal(points[:len(before)], before)
    lo, hi = before.min(axis=0), before.max(axis=0)
    on_surface = (np.isclose(points, lo) | np.isclose(points, hi)).any(axis=1)
    assert on_surface.all()


def test_face_varying_indexed_uvs_are_the_affine_map_of_each_face(room):
    stage, _ = refined_stage(room)
    box = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Box"))
    st = UsdGeom.PrimvarsAPI(box).GetPrimvar("st")
    assert st.IsIndexed()
    uv = np.asarray(st.ComputeFlattened(), np.float64).reshape(-1, 3, 2)
    quads = authored(room, "/World/Box").astype(np.float64).reshape(6, 4, 3)
    per_face = 2 * 4 ** LEVELS  # faces stay grouped by authored quad, in order
    for face, (corner_positions, corner_uv) in enumerate(zip(face_corners(box), uv)):
        # Authored quad k has points 4k..4k+3 with uv (0,0), (1,0), (1,1), (0,1): u, v are affine in position.
        quad = quads[face // per_face]
        origin, e1, e3 = quad[0], quad[1] - quad[0], quad[3] - quad[0]
        expected = np.stack([(corner_positions - origin) @ e1 / (e1 @ e1),
                             (corner_positions - origin) @ e3 / (e3 @ e3)], 1)
        np.testing.assert_allclose(corner_uv, expected, atol=FLOAT32_STORAGE)


def test_vertex_normals_are_carried_and_unit(room):
    stage, _ = refined_stage(room)
    box = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Box"))
    normals = np.asarray(box.GetNormalsAttr().Get(), np.float64)
    assert len(normals) == len(box.GetPointsAttr().Get())
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=FLOAT32_STORAGE)
    corners = face_corners(box)
    face_normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    face_normal /= np.linalg.norm(face_normal, axis=1, keepdims=True)
    indices = np.asarray(box.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    for k in range(3):  # unwelded box: the authored normal of every corner is its face's normal
        np.testing.assert_allclose(normals[indices[:, k]], face_normal, atol=FLOAT32_STORAGE)


def test_face_varying_normals_primvar_on_the_floor(room):
    stage, _ = refined_stage(room)
    floor = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Floor"))
    normals = np.asarray(UsdGeom.PrimvarsAPI(floor).GetPrimvar("normals").Get())
    assert len(normals) == len(floor.GetFaceVertexIndicesAttr().Get()) == 3 * 2 * 4 ** LEVELS
    np.testing.assert_allclose(normals, np.tile([0.0, 1.0, 0.0], (len(normals), 1)), atol=FLOAT32_ROUNDING)


def test_constant_normals_are_left_as_authored(tmp_path):
    """normals may be constant (one for the mesh): it holds for the refined faces as it is (was: indexed as if per
    point, an IndexError after the whole compute)."""
    def build(mesh):
        mesh.CreateNormalsAttr(Vt.Vec3fArray([Gf.Vec3f(0, 1, 0)]))
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.constant)

    stage, _ = refined_stage(write_floor_with(tmp_path, build))
    floor = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Floor"))
    assert len(floor.GetFaceVertexCountsAttr().Get()) == 2 * 4 ** LEVELS  # refined
    assert list(floor.GetNormalsAttr().Get()) == [Gf.Vec3f(0, 1, 0)]
    assert floor.GetNormalsInterpolation() == UsdGeom.Tokens.constant
    assert topology_mismatches(stage) == []


def test_uniform_values_and_subsets_follow_their_faces(room):
    colors = authored(room, "/World/Box", "primvars:displayColor")
    stage, _ = refined_stage(room)
    box = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Box"))
    refined_colors = np.asarray(UsdGeom.PrimvarsAPI(box).GetPrimvar("displayColor").Get())
    per_face = 2 * 4 ** LEVELS  # an authored quad is 2 triangles, each split LEVELS times
    np.testing.assert_array_equal(refined_colors, np.repeat(colors, per_face, axis=0))
    subsets = {s.GetPrim().GetName(): np.asarray(s.GetIndicesAttr().Get())
               for s in UsdGeom.Subset.GetAllGeomSubsets(box)}
    np.testing.assert_array_equal(subsets["sides"], np.arange(4 * per_face))
    np.testing.assert_array_equal(subsets["caps"], np.arange(4 * per_face, 6 * per_face))


def write_floor_with(tmp_path, build):
    """A stage with one refinable floor quad, passed to ``build(mesh)`` for extra authored data."""
    path = tmp_path / "floor.usda"
    stage = new_stage(path)
    mesh = add_floor(stage, "/World/Floor", size=2.0)
    build(mesh)
    stage.Save()
    return path


def test_time_samples_and_element_size_are_carried(tmp_path):
    def build(mesh):
        points = np.asarray(mesh.GetPointsAttr().Get(), np.float64)
        api = UsdGeom.PrimvarsAPI(mesh)
        temperature = api.CreatePrimvar("temperature", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)
        for time in (1.0, 2.0):
            temperature.Set(Vt.FloatArray((time * points[:, 0]).tolist()), time)
        pair = api.CreatePrimvar("xz", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex, elementSize=2)
        pair.Set(Vt.FloatArray(points[:, [0, 2]].ravel().tolist()))

    stage, _ = refined_stage(write_floor_with(tmp_path, build))
    floor = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Floor"))
    points = np.asarray(floor.GetPointsAttr().Get(), np.float64)
    api = UsdGeom.PrimvarsAPI(floor)
    temperature = api.GetPrimvar("temperature")
    assert temperature.GetAttr().GetTimeSamples() == [1.0, 2.0]
    for time in (1.0, 2.0):
        np.testing.assert_allclose(np.asarray(temperature.Get(time)), time * points[:, 0], atol=FLOAT32_ACCUMULATED)
    xz = api.GetPrimvar("xz")
    assert xz.GetElementSize() == 2
    np.testing.assert_allclose(np.asarray(xz.Get()).reshape(-1, 2), points[:, [0, 2]], atol=FLOAT32_STORAGE)
    assert topology_mismatches(stage) == []


def test_a_blocked_time_sample_stays_blocked(tmp_path):
    def build(mesh):
        points = np.asarray(mesh.GetPointsAttr().Get(), np.float64)
        temperature = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("temperature", Sdf.ValueTypeNames.FloatArray,
                                                               UsdGeom.Tokens.vertex)
        temperature.Set(Vt.FloatArray(points[:, 0].tolist()), 1.0)
        temperature.Set(Sdf.ValueBlock(), 2.0)
        velocities = mesh.CreateVelocitiesAttr()
        velocities.Set(Vt.Vec3fArray([Gf.Vec3f(1, 0, 0)] * 4), 1.0)
        velocities.Set(Sdf.ValueBlock(), 2.0)

    stage, _ = refined_stage(write_floor_with(tmp_path, build))  # was: TypeError after the whole compute
    floor = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Floor"))
    points = np.asarray(floor.GetPointsAttr().Get(), np.float64)
    temperature = UsdGeom.PrimvarsAPI(floor).GetPrimvar("temperature")
    np.testing.assert_allclose(np.asarray(temperature.Get(1.0)), points[:, 0], atol=FLOAT32_ACCUMULATED)
    assert temperature.Get(2.0) is None and floor.GetVelocitiesAttr().Get(2.0) is None
    assert len(floor.GetVelocitiesAttr().Get(1.0)) == len(points)


def test_crease_edges_are_split_at_their_new_points(tmp_path):
    def build(mesh):
        mesh.CreateCreaseIndicesAttr([0, 1])
        mesh.CreateCreaseLengthsAttr([2])
        mesh.CreateCreaseSharpnessesAttr([4.0])

    stage, _ = refined_stage(write_floor_with(tmp_path, build))
    floor = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Floor"))
    points = np.asarray(floor.GetPointsAttr().Get(), np.float64)
    chain = list(floor.GetCreaseIndicesAttr().Get())
    assert chain[0] == 0 and chain[-1] == 1 and len(chain) == 2 ** LEVELS + 1
    assert list(floor.GetCreaseLengthsAttr().Get()) == [len(chain)]
    assert list(floor.GetCreaseSharpnessesAttr().Get()) == [4.0]
    along = points[chain] - points[0]
    distance = np.linalg.norm(along, axis=1)
    assert np.all(np.diff(distance) > 0)  # ordered from one end to the other
    np.testing.assert_allclose(np.cross(along, points[1] - points[0]), 0.0, atol=FLOAT32_STORAGE)  # all on the edge


def test_hole_faces_are_left_out_and_hole_indices_cleared(tmp_path):
    path = tmp_path / "holes.usda"
    stage = new_stage(path)
    add_box(stage, "/World/Box").CreateHoleIndicesAttr([1])
    stage.Save()
    refined, _ = refined_stage(path)
    box = UsdGeom.Mesh(refined.GetPrimAtPath("/World/Box"))
    assert list(box.GetHoleIndicesAttr().Get()) == []
    assert len(box.GetFaceVertexCountsAttr().Get()) == 5 * 2 * 4 ** LEVELS
    assert topology_mismatches(refined) == []


def facing(scene) -> np.ndarray:
    """Sign of each triangle's normal along the direction from the scene's centre to the triangle."""
    centroids = scene.points[scene.tri_vertices].mean(axis=1)
    return np.sign(np.einsum("ij,ij->i", scene.tri_normals, centroids - scene.points.mean(axis=0)))


def test_mirrored_left_handed_mesh_keeps_its_facing(tmp_path):
    path = tmp_path / "mirrored.usda"
    stage = new_stage(path)
    xform = UsdGeom.Xform.Define(stage, "/World/Mirror")
    xform.AddScaleOp().Set(Gf.Vec3f(-1, 1, 1))
    mesh = add_box(stage, "/World/Mirror/Box")
    mesh.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    stage.Save()
    before = extract_scene(Usd.Stage.Open(str(path)))
    refined, _ = refined_stage(path)
    after = extract_scene(refined)
    assert after.num_triangles == before.num_triangles * 4 ** LEVELS
    # leftHanded under a mirror: Hydra's front faces point inward, and stay so on the refined mesh
    assert np.all(facing(before) == -1) and np.all(facing(after) == -1)


def test_processor_values_replace_an_indexed_primvar_and_block_its_indices(room):
    stage = Usd.Stage.Open(str(room))
    box = stage.GetPrimAtPath("/World/Box")
    values = np.zeros((12, 2), np.float32)
    outputs = complete_outputs(stage, [Primvar("/World/Box", "st", values, "texCoord2f", "faceVarying")])
    blocks = [r for r in outputs if isinstance(r, Attribute) and r.name == "primvars:st:indices"]
    assert len(blocks) == 1 and isinstance(blocks[0].value, Block)
    layer = Sdf.Layer.CreateAnonymous("bake")
    stage.GetSessionLayer().subLayerPaths.append(layer.identifier)
    author(layer, outputs, {})
    assert not UsdGeom.PrimvarsAPI(box).GetPrimvar("st").IsIndexed()


# ---------------------------------------------------------------------------
# Through the command: one run refines and bakes per-vertex results on the refined mesh

FAST = ["--set", "sky_visibility.patch_count=32", "--set", "sky_visibility.tolerance=0.01",
        "--set", "sky_visibility.max_level=3", "--set", "ambient_occlusion.samples=16"]


def test_per_vertex_results_follow_refinement_in_one_run(room, tmp_path, capsys):
    copy = tmp_path / "copy.usda"
    shutil.copy(room, copy)
    out = tmp_path / "out.usda"
    code, err = run_bake(capsys, "bake", room, "-o", out, "-p", "sky_visibility", "-p", "ambient_occlusion", *FAST)
    assert code == 0, err
    assert filecmp.cmp(room, copy, shallow=False)  # the input is untouched
    stage = Usd.Stage.Open(str(out))
    assert topology_mismatches(stage) == []
    floor = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Floor"))
    assert len(floor.GetFaceVertexCountsAttr().Get()) > 2  # refined
    ao = np.asarray(UsdGeom.PrimvarsAPI(floor).GetPrimvar("bake:ao").Get())
    assert len(ao) == len(floor.GetPointsAttr().Get())
    assert np.all((ao >= 0) & (ao <= 1)) and ao.min() < 0.9  # the box shadows the floor near it


def run_bake(capsys, *argv):
    capsys.readouterr()
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


def test_uncarriable_primvar_is_refused_before_compute(tmp_path, capsys):
    def build(mesh):
        UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("materialId", Sdf.ValueTypeNames.IntArray,
                                                UsdGeom.Tokens.vertex).Set(Vt.IntArray([0, 1, 2, 3]))

    path = write_floor_with(tmp_path, build)
    before = path.read_bytes()
    out = tmp_path / "out.usda"
    code, err = run_bake(capsys, "bake", path, "-o", out, "-p", "sky_visibility")
    assert code == 2
    assert err.strip().splitlines()[-1] == ("usdbake: error: /World/Floor.primvars:materialId: vertex int values cannot be "
                           "interpolated onto refined faces (no barycentric mean for int); mark the prim "
                           "bake:skip = true, or bake it without sky_visibility/daylight")
    assert not out.exists() and path.read_bytes() == before
    code, err = run_bake(capsys, "bake", path, "-o", out, "-p", "ambient_occlusion",
                         "--set", "ambient_occlusion.samples=16")
    assert code == 0, err  # nothing is refined: the int primvar is no obstacle


def test_animated_points_are_refused_before_compute(tmp_path, capsys):
    def build(mesh):
        points = mesh.GetPointsAttr().Get()
        for time in (1.0, 2.0):
            mesh.GetPointsAttr().Set(points, time)

    path = write_floor_with(tmp_path, build)
    code, err = run_bake(capsys, "bake", path, "-o", tmp_path / "out.usda", "-p", "sky_visibility")
    assert code == 2
    assert err.strip().splitlines()[-1].startswith("usdbake: error: /World/Floor.points: 2 time samples: a refined mesh is "
                                  "computed at one time and cannot follow animated points")
