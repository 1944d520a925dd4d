"""Skip what a scene doesn't need, made visible: one test per reason the plan gives."""

from __future__ import annotations

from repo_paths import SAMPLES

from pxr import Gf, Usd, UsdGeom, UsdLux

from usdbake.stages.extract import extract_scene
from usdbake.core.pipeline import Pipeline
from usdbake.core.runtime import Runtime
from usdbake.kernels.tracer import Tracer



def quad_stage(*, light: bool) -> Usd.Stage:
    stage = Usd.Stage.CreateInMemory()
    mesh = UsdGeom.Mesh.Define(stage, "/World/floor")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 0, -1), (0, 0, -1)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    if light:
        UsdLux.DistantLight.Define(stage, "/World/sun")
    return stage


def instancer_stage(instances: int) -> Usd.Stage:
    """Only a PointInstancer: every triangle is an instance, nothing is writable."""
    stage = Usd.Stage.CreateInMemory()
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/scatter")
    proto = UsdGeom.Mesh.Define(stage, "/World/scatter/protos/tri")
    proto.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    proto.CreateFaceVertexCountsAttr([3])
    proto.CreateFaceVertexIndicesAttr([0, 1, 2])
    instancer.CreatePrototypesRel().SetTargets([proto.GetPath()])
    instancer.CreateProtoIndicesAttr([0] * instances)
    instancer.CreatePositionsAttr([Gf.Vec3f(2.0 * i, 0, 0) for i in range(instances)])
    return stage


def plan(stage: Usd.Stage, names, params=None, cache_dir=None) -> dict:
    pipeline = Pipeline.build(names, params, runtime=Runtime(Tracer.from_scene), cache_dir=cache_dir)
    return {step.name: (step.action, step.reason) for step in pipeline.plan(extract_scene(stage))}


NO_RECEIVERS = ("not applicable: no writable meshes (all instanced, bake:skip or empty); bake natively instanced "
                "meshes per vertex with --deinstance (hook: deinstance=True)")


def test_no_writable_meshes():
    assert plan(instancer_stage(3), ["progressive_mesh"])["progressive_mesh"] == ("skip", NO_RECEIVERS)
    assert plan(instancer_stage(3), ["ambient_occlusion"], {"ambient_occlusion": {"instances": "skip"}})[
        "ambient_occlusion"] == ("skip", NO_RECEIVERS)


def test_instance_ao_with_instances_applies_to_a_scene_of_instances_only():
    params = {"displacement_fields": {"force": "tri", "positional_samples": 16, "direction_map_size": 4}}
    assert plan(instancer_stage(3), ["instance_ao"], params)["instance_ao"] == ("skip", NO_RECEIVERS)
    steps = plan(instancer_stage(3), ["instance_ao"], {**params, "instance_ao": {"instances": True}})
    assert steps["instance_ao"][0] == "run"


def test_instances_alone_are_baked_by_ambient_occlusion():
    assert plan(instancer_stage(3), ["ambient_occlusion"])["ambient_occlusion"][0] == "run"


def test_no_instanced_prototypes_and_dependents_follow():
    steps = plan(quad_stage(light=True), ["instance_ao"])
    assert steps["displacement_fields"] == ("skip", "not applicable: no instanced prototypes")
    assert steps["instance_ao"] == ("skip", "requires displacement_fields (skipped)")


def test_dependencies_of_a_skipped_processor_do_not_run():
    """radiosity without light is skipped, so form_factors, which only radiosity needs, is too."""
    steps = plan(quad_stage(light=False), ["radiosity"])
    assert steps["radiosity"][0] == "skip"
    assert steps["form_factors"] == ("skip", "needed only by radiosity (skipped)")
    assert plan(quad_stage(light=False), ["radiosity", "form_factors"])["form_factors"][0] == "run"  # asked for


def closed_box_stage(*, opening: bool) -> Usd.Stage:
    """A room of six inward-facing walls (Y up); with ``opening`` the ceiling is left out."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, "Y")
    corners = [(x, y, z) for y in (0, 1) for z in (0, 1) for x in (0, 1)]
    faces = {"floor": (0, 1, 3, 2), "ceiling": (4, 6, 7, 5), "back": (0, 4, 5, 1), "front": (2, 3, 7, 6),
             "left": (0, 2, 6, 4), "right": (1, 5, 7, 3)}
    if opening:
        del faces["ceiling"]
    mesh = UsdGeom.Mesh.Define(stage, "/World/room")
    mesh.CreatePointsAttr([Gf.Vec3f(*map(float, c)) for c in corners])
    mesh.CreateFaceVertexCountsAttr([4] * len(faces))
    mesh.CreateFaceVertexIndicesAttr([i for face in faces.values() for i in reversed(face)])  # inward
    return stage


def test_no_sky_visible_faces():
    assert plan(closed_box_stage(opening=False), ["sky_visibility"])["sky_visibility"] == (
        "skip", "not applicable: no sky-visible faces (every face is enclosed or faces away from the sky)")
    assert plan(closed_box_stage(opening=True), ["sky_visibility"])["sky_visibility"][0] == "run"


def test_no_lights():
    action, reason = plan(quad_stage(light=False), ["radiosity"])["radiosity"]
    assert action == "skip" and reason == ("not applicable: no lights (no UsdLux light with radiance and no emissive "
                                           "triangle): add a sky and sun with 'usdbake sky STAGE -o STAGE.sky.usda' "
                                           "and bake that layer, or add a UsdLux DomeLight, a DistantLight or an "
                                           "emissive material")
    assert plan(quad_stage(light=True), ["radiosity"])["radiosity"][0] == "run"


def test_fields_pay_off_by_the_cost_model():
    stage = Usd.Stage.Open(str(SAMPLES / "instanced_props.usda"))
    action, reason = plan(stage, ["displacement_fields"])["displacement_fields"]
    assert action == "run" and reason.startswith("pays off for Vase")
    action, reason = plan(stage, ["displacement_fields"],
                          {"displacement_fields": {"min_instances": 1000}})["displacement_fields"]
    assert action == "skip" and "no prototype pays off" in reason


def test_up_to_date(tmp_path):
    stage, names = quad_stage(light=True), ["ambient_occlusion"]
    params = {"ambient_occlusion": {"samples": 4}}
    pipeline = Pipeline.build(names, params, runtime=Runtime(Tracer.from_scene), cache_dir=tmp_path)
    pipeline.run(extract_scene(stage))
    assert plan(stage, names, params, cache_dir=tmp_path)["ambient_occlusion"] == (
        "cached", "up to date: fingerprint unchanged")
    assert plan(stage, names, {"ambient_occlusion": {"samples": 9}}, cache_dir=tmp_path)["ambient_occlusion"][0] \
        == "run"
