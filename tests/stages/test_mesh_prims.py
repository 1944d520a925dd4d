"""stages.mesh_prims: which prims are drawn (renderable), one mesh read in its own space (read_mesh:
triangles through faceVertexIndices, per-face shading carried to triangles, holes and short faces left out
with a warning, flags), its refusals (StageError naming prim, attribute and value), and SceneBuilder.

Meshes placed in world space, winding and whole-stage visibility are tests/stages/test_extract.py's."""

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom

from stage_builders import add_mesh, add_preview_material, add_xform, bind, new_stage
from tolerances import FLOAT32_STORAGE
from usdbake.core.errors import StageError
from usdbake.stages.materials import MaterialReader
from usdbake.stages.mesh_prims import LocalMesh, SceneBuilder, read_mesh, renderable

DEFAULT = Usd.TimeCode.Default()

# A unit square (face 0) and a triangle beside it (face 1), sharing the edge 1-2.
SHAPE_POINTS = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0)]
SHAPE_COUNTS = [4, 3]
SHAPE_INDICES = [0, 1, 2, 3, 1, 4, 2]


def read(stage, path="/World/Shape", time=DEFAULT) -> tuple[LocalMesh, list]:
    warnings: list = []
    mesh = read_mesh(stage.GetPrimAtPath(path), time, MaterialReader(time, warnings=warnings), warnings)
    return mesh, warnings


def triangle_areas(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    a, b, c = (points[triangles[:, k]] for k in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


# --- renderable -------------------------------------------------------------------------------


def test_renderable_follows_visibility_and_purpose():
    stage = new_stage()
    cases = {"/World/Plain": {}, "/World/Render": {"purpose": UsdGeom.Tokens.render},
             "/World/Default": {"purpose": UsdGeom.Tokens.default_},
             "/World/Guide": {"purpose": UsdGeom.Tokens.guide}, "/World/Proxy": {"purpose": UsdGeom.Tokens.proxy},
             "/World/Hidden": {"visibility": UsdGeom.Tokens.invisible}}
    for path, attributes in cases.items():
        add_mesh(stage, path, SHAPE_POINTS, SHAPE_COUNTS, SHAPE_INDICES, **attributes)
    drawn = {path: renderable(stage.GetPrimAtPath(path), DEFAULT) for path in cases}
    assert drawn == {"/World/Plain": True, "/World/Render": True, "/World/Default": True, "/World/Guide": False,
                     "/World/Proxy": False, "/World/Hidden": False}


def test_a_prim_that_is_not_imageable_is_drawn():
    stage = new_stage()
    assert renderable(stage.DefinePrim("/World/Typeless"), DEFAULT)
    assert renderable(stage.DefinePrim("/World/Material", "Material"), DEFAULT)


def test_visibility_is_read_at_the_time_asked_for():
    stage = new_stage()
    mesh = add_mesh(stage, "/World/Blink", SHAPE_POINTS, SHAPE_COUNTS, SHAPE_INDICES)
    visibility = mesh.CreateVisibilityAttr()
    visibility.Set(UsdGeom.Tokens.inherited, 1.0)
    visibility.Set(UsdGeom.Tokens.invisible, 2.0)
    prim = mesh.GetPrim()
    assert renderable(prim, Usd.TimeCode(1.0)) and not renderable(prim, Usd.TimeCode(2.0))


# --- read_mesh --------------------------------------------------------------------------------


def test_a_mesh_is_triangulated_through_its_face_vertex_indices_in_its_own_space():
    stage = new_stage()
    add_xform(stage, "/World/Moved", translate=(100, 0, 0), scale=(3, 3, 3))
    add_mesh(stage, "/World/Moved/Shape", SHAPE_POINTS, SHAPE_COUNTS, SHAPE_INDICES)
    mesh, warnings = read(stage, "/World/Moved/Shape")
    assert warnings == []
    assert mesh.path == "/World/Moved/Shape" and mesh.face_count == 2
    np.testing.assert_array_equal(mesh.points, SHAPE_POINTS)  # local: the parent's transform is not applied
    assert mesh.points.dtype == np.float64
    # Convex faces are fans (0, k, k+1) over each face's slots of faceVertexIndices
    np.testing.assert_array_equal(mesh.tri_corner, [[0, 1, 2], [0, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(mesh.tri_face, [0, 0, 1])
    np.testing.assert_array_equal(mesh.triangles, np.array(SHAPE_INDICES)[mesh.tri_corner])
    assert mesh.triangles.dtype == np.int32 and mesh.tri_corner.dtype == np.int32
    # the triangles tile each face: areas 1 (the square) and 1/2 (the triangle)
    areas = triangle_areas(mesh.points, mesh.triangles)
    np.testing.assert_allclose(np.bincount(mesh.tri_face, weights=areas), [1.0, 0.5])
    assert (mesh.left_handed, mesh.double_sided, mesh.skip, mesh.surface) == (False, False, False, "")


def test_shading_is_read_per_face_and_carried_to_its_triangles():
    stage = new_stage()
    mesh = add_mesh(stage, "/World/Shape", SHAPE_POINTS, SHAPE_COUNTS, SHAPE_INDICES)
    colours = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray, "uniform")
    colours.Set([(0.8, 0.1, 0.1), (0.1, 0.7, 0.2)])
    read_back, _ = read(stage)
    np.testing.assert_allclose(read_back.tri_albedo, [(0.8, 0.1, 0.1), (0.8, 0.1, 0.1), (0.1, 0.7, 0.2)],
                               atol=FLOAT32_STORAGE)
    assert read_back.tri_albedo.dtype == np.float32
    np.testing.assert_array_equal(read_back.tri_emission, np.zeros((3, 3)))
    np.testing.assert_array_equal(read_back.tri_transmittance, np.zeros(3))


def test_a_bound_material_sets_the_surface_and_the_emission():
    stage = new_stage()
    mesh = add_mesh(stage, "/World/Shape", SHAPE_POINTS, SHAPE_COUNTS, SHAPE_INDICES)
    bind(mesh.GetPrim(), add_preview_material(stage, "/World/Looks/Lamp", diffuse=(0.2, 0.4, 0.6),
                                              emissive=(5, 4, 3)))
    read_back, _ = read(stage)
    assert read_back.surface == "/World/Looks/Lamp/Surface"
    np.testing.assert_allclose(read_back.tri_albedo, [(0.2, 0.4, 0.6)] * 3, atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(read_back.tri_emission, [(5, 4, 3)] * 3, atol=FLOAT32_STORAGE)


def test_flags_are_read_from_orientation_double_sided_and_bake_skip():
    stage = new_stage()
    mesh = add_mesh(stage, "/World/Shape", SHAPE_POINTS, SHAPE_COUNTS, SHAPE_INDICES,
                    orientation=UsdGeom.Tokens.leftHanded, doubleSided=True)
    mesh.GetPrim().CreateAttribute("bake:skip", Sdf.ValueTypeNames.Bool, custom=True).Set(True)
    read_back, _ = read(stage)
    assert (read_back.left_handed, read_back.double_sided, read_back.skip) == (True, True, True)
    # the winding is the authored one: facing is decided later, with the world transform
    np.testing.assert_array_equal(read_back.triangles[0], [0, 1, 2])


def test_holes_in_range_are_left_out_with_one_warning():
    stage = new_stage()
    add_mesh(stage, "/World/Shape", SHAPE_POINTS, SHAPE_COUNTS, SHAPE_INDICES, holeIndices=[1, 7, -1])
    read_back, warnings = read(stage)
    assert warnings == ["/World/Shape: 1 hole faces skipped"]  # 7 and -1 name no face
    np.testing.assert_array_equal(read_back.tri_face, [0, 0])
    assert read_back.face_count == 2  # faces keep their numbers


def test_faces_of_fewer_than_three_vertices_are_left_out_with_one_warning():
    stage = new_stage()
    add_mesh(stage, "/World/Shape", SHAPE_POINTS, [2, 0, 4, 1], [0, 1, 0, 1, 2, 3, 4], holeIndices=[0])
    read_back, warnings = read(stage)
    assert warnings == ["/World/Shape: 3 faces with fewer than 3 vertices skipped",
                        "/World/Shape: 1 hole faces skipped"]
    np.testing.assert_array_equal(read_back.tri_face, [2, 2])
    np.testing.assert_array_equal(read_back.tri_corner, [[2, 3, 4], [2, 4, 5]])


def test_topology_is_read_at_the_time_asked_for():
    stage = new_stage()
    mesh = add_mesh(stage, "/World/Shape", SHAPE_POINTS, SHAPE_COUNTS, SHAPE_INDICES)
    mesh.GetPointsAttr().Set([(x, y, 5.0) for x, y, _ in SHAPE_POINTS], 4.0)
    np.testing.assert_array_equal(read(stage, time=Usd.TimeCode(4.0))[0].points[:, 2], 5.0)
    np.testing.assert_array_equal(read(stage)[0].points[:, 2], 0.0)  # the default value is still there


# --- refusals ---------------------------------------------------------------------------------


@pytest.mark.parametrize("points, counts, indices, attribute, problem", [
    ([(0, 0, 0), (np.inf, 0, 0), (0, 1, 0), (0, np.nan, 1)], [3], [0, 1, 2], "points",
     "point 1 is (inf, 0.0, 0.0) (2 non-finite points); fix or remove them"),
    (SHAPE_POINTS, [4, 4], SHAPE_INDICES, "faceVertexCounts", "sum 8 != len(faceVertexIndices) 7"),
    (SHAPE_POINTS, [4, 4, -1], SHAPE_INDICES, "faceVertexCounts", "negative count -1"),
    (SHAPE_POINTS, SHAPE_COUNTS, [0, 1, 2, 3, 1, 5, 2], "faceVertexIndices", "index 5 at position 5 is outside 0..4"),
    (SHAPE_POINTS, SHAPE_COUNTS, [0, -2, 2, 3, 1, 4, 2], "faceVertexIndices", "index -2 at position 1 is outside 0..4"),
], ids=["non-finite-point", "count-sum", "negative-count", "index-past-the-end", "negative-index"])
def test_data_that_cannot_be_baked_is_a_stage_error_naming_it(points, counts, indices, attribute, problem):
    stage = new_stage()
    add_mesh(stage, "/World/Shape", points, counts, indices)
    with pytest.raises(StageError) as raised:
        read(stage)
    assert (raised.value.prim, raised.value.attribute) == ("/World/Shape", attribute)
    assert str(raised.value) == f"/World/Shape.{attribute}: {problem}"


def test_topology_with_only_time_samples_at_the_default_time_is_refused_naming_the_frames():
    stage = new_stage()
    mesh = UsdGeom.Mesh.Define(stage, "/World/Shape")
    for time in (1.0, 12.0, 24.0):
        mesh.GetPointsAttr().Set(SHAPE_POINTS, time)
    mesh.CreateFaceVertexCountsAttr(SHAPE_COUNTS)
    mesh.CreateFaceVertexIndicesAttr(SHAPE_INDICES)
    with pytest.raises(StageError) as raised:
        read(stage)
    assert str(raised.value) == ("/World/Shape.points: has 3 time samples (1..24) and no default value; bake one "
                                 "frame with --time T (hook: time=T)")
    assert len(read(stage, time=Usd.TimeCode(12.0))[0].triangles) == 3  # at a time it reads


# --- SceneBuilder -----------------------------------------------------------------------------


def test_the_builder_keeps_meshes_and_their_instance_roots_side_by_side():
    stage = new_stage()
    add_mesh(stage, "/World/Shape", SHAPE_POINTS, SHAPE_COUNTS, SHAPE_INDICES)
    mesh, _ = read(stage)
    builder = SceneBuilder()
    world = np.eye(4)
    builder.add(mesh, world, writable=True)
    builder.add(mesh, 2 * world, writable=False, instance=3, roots=("/World/A", "/World/A/B"))
    assert [(m is mesh, w[0, 0], writable, instance) for m, w, writable, instance in builder.meshes] == \
        [(True, 1.0, True, -1), (True, 2.0, False, 3)]
    assert builder.instance_roots == [(), ("/World/A", "/World/A/B")]
    assert builder.warnings == [] and SceneBuilder().meshes == []  # fresh lists per builder
