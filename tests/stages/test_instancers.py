"""stages.instancers called directly: the native instances above an instance proxy, the InstanceTable's
prototypes and native instances (named by what they reference), a PointInstancer's unmasked instances and
their placed prototype meshes, the per-instance array checks (warnings and StageErrors naming the
instancer, the attribute and the lengths), and Scene.instances at every authored time sample.

Instance matrices against Gf's composition and PointInstancers through the command are
tests/stages/test_extract.py's and tests/catalogue/test_hostile_inputs.py's."""

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from stage_builders import add_quads, add_xform, new_stage
from tolerances import FLOAT64_ROUNDING
from usdbake.core.errors import StageError
from usdbake.stages import instancers
from usdbake.stages.instancers import (InstanceTable, add_point_instancer, check_instancer_arrays, instance_roots,
                                       scene_instances)
from usdbake.stages.materials import MaterialReader
from usdbake.stages.mesh_prims import SceneBuilder, read_mesh

DEFAULT = Usd.TimeCode.Default()


def translation(x, y, z) -> np.ndarray:
    """A row-vector (Gf) translation matrix."""
    matrix = np.eye(4)
    matrix[3, :3] = (x, y, z)
    return matrix


def pawns(stage, count: int = 4, *, instancer_at=(0.0, 0.0, 5.0)) -> UsdGeom.PointInstancer:
    """/World/Rig (translated by ``instancer_at``) holding /World/Rig/Pawns: ``count`` instances of a unit quad
    at (2 i, 0, 0), its prototype a Mesh right under the instancer's Protos."""
    add_xform(stage, "/World/Rig", translate=instancer_at)
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Rig/Pawns")
    add_quads(stage, "/World/Rig/Pawns/Protos/Box")
    instancer.CreatePrototypesRel().SetTargets([Sdf.Path("/World/Rig/Pawns/Protos/Box")])
    instancer.CreateProtoIndicesAttr([0] * count)
    instancer.CreatePositionsAttr([Gf.Vec3f(2.0 * i, 0, 0) for i in range(count)])
    return instancer


def add(instancer: UsdGeom.PointInstancer, time=DEFAULT) -> tuple[InstanceTable, SceneBuilder]:
    """add_point_instancer as extraction calls it: meshes read once through read_mesh."""
    builder, table = SceneBuilder(), InstanceTable()
    materials = MaterialReader(time, warnings=builder.warnings)
    add_point_instancer(instancer.GetPrim(), time, UsdGeom.XformCache(time),
                        lambda prim: read_mesh(prim, time, materials, builder.warnings), builder, table)
    return table, builder


# --- instance_roots and the table's native instances ------------------------------------------


def nested_instances(stage):
    """/World/Outer (instanceable, references /Classes/Outer) whose Inner is itself an instance of /Classes/Leaf."""
    stage.CreateClassPrim("/Classes/Leaf")
    add_quads(stage, "/Classes/Leaf/Seat")
    stage.CreateClassPrim("/Classes/Outer")
    inner = stage.DefinePrim("/Classes/Outer/Inner", "Xform")
    inner.GetReferences().AddInternalReference("/Classes/Leaf")
    inner.SetInstanceable(True)
    outer = add_xform(stage, "/World/Outer", translate=(1, 2, 3)).GetPrim()
    outer.GetReferences().AddInternalReference("/Classes/Outer")
    outer.SetInstanceable(True)


def test_instance_roots_are_every_native_instance_above_outermost_first():
    stage = new_stage()
    nested_instances(stage)
    assert instance_roots(stage.GetPrimAtPath("/World/Outer/Inner/Seat")) == ("/World/Outer", "/World/Outer/Inner")
    assert instance_roots(add_quads(stage, "/World/Floor").GetPrim()) == ()


def chairs(stage, folder=None):
    """/World/A and /World/B: instanceable references to /Classes/Chair; /World/C: also inherits /Classes/Extra
    (so USD gives it a prototype of its own); /World/D: references props.usda's /Pawn when ``folder``."""
    stage.CreateClassPrim("/Classes/Chair")
    add_quads(stage, "/Classes/Chair/Seat")
    stage.CreateClassPrim("/Classes/Extra")
    for name, x in (("A", 0), ("B", 5), ("C", 10)):
        prim = add_xform(stage, f"/World/{name}", translate=(x, 0, 0)).GetPrim()
        prim.GetReferences().AddInternalReference("/Classes/Chair")
        if name == "C":
            prim.GetInherits().AddInherit("/Classes/Extra")
        prim.SetInstanceable(True)
    if folder is not None:
        props = new_stage()
        add_quads(props, "/Pawn/Body")
        props.GetRootLayer().Export(str(folder / "props.usda"))
        prim = add_xform(stage, "/World/D", translate=(0, 0, 7)).GetPrim()
        prim.GetReferences().AddReference(str(folder / "props.usda"), "/Pawn")
        prim.SetInstanceable(True)


def test_native_instances_share_a_prototype_named_by_what_they_reference(tmp_path):
    stage = new_stage()
    chairs(stage, tmp_path)
    xforms = UsdGeom.XformCache()
    table = InstanceTable()
    rows = [table.native(stage.GetPrimAtPath(f"/World/{name}"), xforms) for name in "ABCDA"]
    assert rows == [0, 1, 2, 3, 0]  # /World/A again: its row, not a new one
    prototype_c = str(stage.GetPrimAtPath("/World/C").GetPrototype().GetPath())
    assert table.prototype_paths == ["/Classes/Chair", f"/Classes/Chair ({prototype_c})", "props.usda:/Pawn"]
    assert table.prototype_targets == [["/World/A", "/World/B"], ["/World/C"], ["/World/D"]]
    assert table.instancer_paths == ["/World/A", "/World/B", "/World/C", "/World/D"]
    assert table.instancer_counts == [1, 1, 1, 1] and table.instancer_native == [True] * 4
    assert [(instancer, prototype, row) for instancer, prototype, _, row in table.rows] == \
        [(0, 0, 0), (1, 0, 0), (2, 1, 0), (3, 2, 0)]
    np.testing.assert_array_equal(table.rows[1][2], translation(5, 0, 0))
    np.testing.assert_array_equal(table.rows[3][2], translation(0, 0, 7))


def test_prototype_paths_are_registered_once():
    table = InstanceTable()
    assert [table.prototype(path) for path in ("/P/A", "/P/B", "/P/A")] == [0, 1, 0]
    assert table.prototype_paths == ["/P/A", "/P/B"] and table.prototype_targets == [["/P/A"], ["/P/B"]]


# --- add_point_instancer ----------------------------------------------------------------------


def test_unmasked_instances_are_rows_and_their_prototype_meshes_are_placed():
    stage = new_stage()
    instancer = pawns(stage, 4)
    instancer.DeactivateId(1)  # inactiveIds: instance 1 is masked out
    table, builder = add(instancer)
    assert table.instancer_paths == ["/World/Rig/Pawns"] and table.instancer_counts == [4]  # masked ones counted
    assert table.prototype_paths == ["/World/Rig/Pawns/Protos/Box"]
    assert [(i, p, row) for i, p, _, row in table.rows] == [(0, 0, 0), (0, 0, 2), (0, 0, 3)]  # authored rows kept
    for (_, _, matrix, row) in table.rows:
        np.testing.assert_allclose(matrix, translation(2.0 * row, 0, 5), atol=FLOAT64_ROUNDING)
    # one read-only mesh per kept instance, placed by the prototype's own (identity) transform times the instance's
    assert [(mesh.path, writable, instance) for mesh, _, writable, instance in builder.meshes] == \
        [("/World/Rig/Pawns/Protos/Box", False, k) for k in range(3)]
    assert builder.meshes[0][0] is builder.meshes[1][0]  # read once, shared
    for (_, world, _, _), (_, _, matrix, _) in zip(builder.meshes, table.rows):
        np.testing.assert_allclose(world, matrix, atol=FLOAT64_ROUNDING)
    [(prim, kept, proto_indices, first)] = table.sources
    assert prim.GetPath() == "/World/Rig/Pawns" and kept.tolist() == [0, 2, 3] and first == 0
    assert proto_indices.tolist() == [0, 0, 0, 0]


def test_a_mesh_under_a_prototype_root_is_placed_by_its_transform_relative_to_the_root():
    stage = new_stage()
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Pawns")
    add_xform(stage, "/World/Pawns/Protos/Chair", translate=(0, 0, 100))  # the root's own transform: included
    add_xform(stage, "/World/Pawns/Protos/Chair/Leg", translate=(0, 3, 0))
    add_quads(stage, "/World/Pawns/Protos/Chair/Leg/Mesh")
    guide = add_quads(stage, "/World/Pawns/Protos/Chair/Guide")
    guide.CreatePurposeAttr(UsdGeom.Tokens.guide)  # not drawn: left out
    instancer.CreatePrototypesRel().SetTargets([Sdf.Path("/World/Pawns/Protos/Chair")])
    instancer.CreateProtoIndicesAttr([0])
    instancer.CreatePositionsAttr([Gf.Vec3f(7, 0, 0)])
    table, builder = add(instancer)
    [(mesh, world, _, _)] = builder.meshes
    assert mesh.path == "/World/Pawns/Protos/Chair/Leg/Mesh"
    # row vectors: leg (0, 3, 0) relative to the root, then the root's own (0, 0, 100), then the position (7, 0, 0)
    np.testing.assert_allclose(world, translation(7, 3, 100), atol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(table.rows[0][2], translation(7, 0, 100), atol=FLOAT64_ROUNDING)


def test_an_instancer_without_instances_adds_nothing():
    stage = new_stage()
    instancer = pawns(stage, 0)
    instancer.GetPrototypesRel().ClearTargets(True)  # nothing targeted either: still no error
    table, builder = add(instancer)
    assert table.instancer_paths == [] and table.rows == [] and builder.meshes == []


@pytest.mark.parametrize("edit, attribute, problem", [
    (lambda inst: inst.GetPrototypesRel().ClearTargets(True), "prototypes",
     "targets nothing, but protoIndices names 3 instances"),
    (lambda inst: inst.GetPrototypesRel().SetTargets([Sdf.Path("/World/Rig/Pawns/Protos/Box"),
                                                      Sdf.Path("/World/Gone")]), "prototypes",
     "target /World/Gone does not exist"),
    (lambda inst: inst.GetProtoIndicesAttr().Set([0, 0, -1]), "protoIndices",
     "index -1 at instance 2, but prototypes has 1 target (0..0)"),
    (lambda inst: (inst.GetPrototypesRel().SetTargets([Sdf.Path("/World/Rig/Pawns/Protos/Box"),
                                                       Sdf.Path("/World/Rig/Pawns/Protos")]),
                   inst.GetProtoIndicesAttr().Set([0, 3, 5])), "protoIndices",
     "index 3 at instance 1, but prototypes has 2 targets (0..1)"),
], ids=["no-targets", "missing-target", "negative-index", "index-past-the-end"])
def test_prototypes_that_cannot_be_placed_are_a_stage_error_naming_them(edit, attribute, problem):
    stage = new_stage()
    instancer = pawns(stage, 3)
    edit(instancer)
    with pytest.raises(StageError) as raised:
        add(instancer)
    assert (raised.value.prim, raised.value.attribute) == ("/World/Rig/Pawns", attribute)
    assert str(raised.value) == f"/World/Rig/Pawns.{attribute}: {problem}"


def test_a_transform_that_overflows_float64_is_named_before_any_compute():
    stage = new_stage()
    instancer = pawns(stage, 2)
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Rig/Pawns/Protos/Box")).AddScaleOp(
        UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(1e300))
    instancer.CreateScalesAttr([Gf.Vec3f(1, 1, 1), Gf.Vec3f(3e38, 1, 1)])  # finite float32, but 3e338 in product
    with pytest.raises(StageError) as raised:
        add(instancer)
    assert str(raised.value) == ("/World/Rig/Pawns.positions: instance 1's transform is not finite "
                                 "(1 such instances)")


# --- check_instancer_arrays -------------------------------------------------------------------


def test_arrays_openusd_drops_are_warnings_and_empty_optional_arrays_are_fine():
    stage = new_stage()
    instancer = pawns(stage, 4)
    instancer.CreateOrientationsAttr(Vt.QuathArray())  # none: allowed
    instancer.CreateScalesAttr([])
    instancer.CreateAngularVelocitiesAttr([Gf.Vec3f(0, 1, 0)] * 3)
    instancer.CreateAccelerationsAttr([Gf.Vec3f(0, -9.8, 0)] * 5)
    instancer.CreateIdsAttr(Vt.Int64Array([7]))  # wrong length, but nothing masks by id
    warnings = check_instancer_arrays(instancer.GetPrim(), DEFAULT, 4, when=" at time 3")
    rest = "ignored, as OpenUSD does (the instances are placed as if every value were zero)"
    assert warnings == [f"/World/Rig/Pawns.angularVelocities: 3 values for 4 positions at time 3; {rest}",
                        f"/World/Rig/Pawns.accelerations: 5 values for 4 positions at time 3; {rest}"]


def test_add_point_instancer_passes_the_warnings_to_the_builder():
    stage = new_stage()
    instancer = pawns(stage, 2)
    instancer.CreateVelocitiesAttr([Gf.Vec3f(1, 0, 0)])
    _, builder = add(instancer)
    assert builder.warnings == ["/World/Rig/Pawns.velocities: 1 values for 2 positions; ignored, as OpenUSD does "
                                "(the instances are placed as if every value were zero)"]
    assert len(builder.meshes) == 2


@pytest.mark.parametrize("edit, attribute, problem", [
    (lambda inst: inst.GetPrim().CreateAttribute("orientationsf", Sdf.ValueTypeNames.QuatfArray).Set(
        Vt.QuatfArray([Gf.Quatf(1)] * 2)), "orientationsf", "2 values for 3 positions (one per instance, or none)"),
    (lambda inst: inst.GetPositionsAttr().Set([Gf.Vec3f(0), Gf.Vec3f(1), Gf.Vec3f(float("nan"), 0, 0)]),
     "positions", "value 2 is (nan, 0.0, 0.0) (1 non-finite values)"),
    (lambda inst: (inst.CreateIdsAttr(Vt.Int64Array([10, 11])), inst.DeactivateId(10)), "ids",
     "2 values for 3 protoIndices (invisibleIds and inactiveIds name instances by id: one id per instance)"),
], ids=["short-orientationsf", "nan-position", "ids-with-inactive-ids"])
def test_per_instance_arrays_that_cannot_be_read_are_refused(edit, attribute, problem):
    stage = new_stage()
    instancer = pawns(stage, 3)
    edit(instancer)
    with pytest.raises(StageError) as raised:
        check_instancer_arrays(instancer.GetPrim(), DEFAULT, 3)
    assert str(raised.value) == f"/World/Rig/Pawns.{attribute}: {problem}"


# --- scene_instances and time samples ---------------------------------------------------------


def animated(stage) -> UsdGeom.PointInstancer:
    """Two instances whose positions are sampled at t = 1, 2, 3; at t = 3 protoIndices drops one instance."""
    instancer = pawns(stage, 2, instancer_at=(0, 0, 0))
    instancer.GetPositionsAttr().Clear()
    for t, y in ((1.0, 0.0), (2.0, 5.0)):
        instancer.GetPositionsAttr().Set([Gf.Vec3f(0, y, 0), Gf.Vec3f(1, y, 0)], t)
    instancer.GetPositionsAttr().Set([Gf.Vec3f(0, 9, 0)], 3.0)
    instancer.GetProtoIndicesAttr().Clear()
    instancer.GetProtoIndicesAttr().Set([0, 0], 1.0)
    instancer.GetProtoIndicesAttr().Set([0], 3.0)
    return instancer


def test_instances_are_kept_at_each_time_their_set_is_the_same():
    stage = new_stage()
    instancer = animated(stage)
    table, _ = add(instancer, Usd.TimeCode(1.0))
    origin = np.array([0.5, 1.0, 0.0])
    instances = scene_instances(table, origin)
    assert instances.instancer_paths == ("/World/Rig/Pawns",)
    assert instances.prototype_paths == ("/World/Rig/Pawns/Protos/Box",)
    assert instances.instance_instancer.tolist() == [0, 0] and instances.instance_prototype.tolist() == [0, 0]
    assert instances.instance_index.tolist() == [0, 1] and instances.instancer_instance_count.tolist() == [2]
    assert instances.instancer_native.tolist() == [False]
    np.testing.assert_allclose(instances.instance_transforms, [translation(-0.5, -1, 0), translation(0.5, -1, 0)],
                               atol=FLOAT64_ROUNDING)
    np.testing.assert_array_equal(instances.instance_times, [1.0, 2.0])  # t = 3 has another set of instances
    expected = [[translation(0 - 0.5, y - 1, 0), translation(1 - 0.5, y - 1, 0)] for y in (0.0, 5.0)]
    np.testing.assert_allclose(instances.instance_transforms_at_times, expected, atol=FLOAT64_ROUNDING)


def test_native_instances_follow_their_roots_at_the_instancers_times():
    stage = new_stage()
    instancer = animated(stage)
    chairs(stage)
    translate = UsdGeom.Xformable(stage.GetPrimAtPath("/World/B")).GetOrderedXformOps()[0]
    translate.Set(Gf.Vec3d(5, 0, 1), 1.0)
    translate.Set(Gf.Vec3d(5, 0, 4), 2.0)
    table, _ = add(instancer, Usd.TimeCode(1.0))
    native = table.native(stage.GetPrimAtPath("/World/B"), UsdGeom.XformCache(Usd.TimeCode(1.0)))
    instances = scene_instances(table, np.zeros(3))
    assert native == 2 and instances.instancer_native.tolist() == [False, True]
    assert instances.targets(1) == ("/World/B",)
    np.testing.assert_allclose(instances.instance_transforms[native], translation(5, 0, 1), atol=FLOAT64_ROUNDING)
    np.testing.assert_array_equal(instances.instance_times, [1.0, 2.0])  # the instancer's times, not the root's
    np.testing.assert_allclose(instances.instance_transforms_at_times[:, native],
                               [translation(5, 0, 1), translation(5, 0, 4)], atol=FLOAT64_ROUNDING)


def test_time_samples_past_the_memory_cap_are_dropped(monkeypatch):
    stage = new_stage()
    instancer = animated(stage)
    table, _ = add(instancer, Usd.TimeCode(1.0))
    monkeypatch.setattr(instancers, "MAX_INSTANCE_TIME_BYTES", 2 * 128)  # one frame of 2 instances
    instances = scene_instances(table, np.zeros(3))
    np.testing.assert_array_equal(instances.instance_times, [1.0])
    assert instances.instance_transforms_at_times.shape == (1, 2, 4, 4)


def test_a_table_without_time_samples_has_empty_time_arrays():
    stage = new_stage()
    table, _ = add(pawns(stage, 3))
    instances = scene_instances(table, np.zeros(3))
    assert len(instances) == 3
    assert instances.instance_times.shape == (0,) and instances.instance_transforms_at_times.shape == (0, 3, 4, 4)
    empty = scene_instances(InstanceTable(), np.zeros(3))
    assert len(empty) == 0 and empty.instance_transforms.shape == (0, 4, 4)
