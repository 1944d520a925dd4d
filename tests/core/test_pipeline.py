"""The DAG runner: wiring, ordering, broken graphs, skip reasons, caching, failures, params, and the one
run-time object every step reads.

Fake processors (tests/fake_processors.py) need no tracer and no pxr, so
these tests exercise the runner alone (their runs' tracer factory fails if
called); they assert which steps ran and which were reused from the cache.
"""

import math

import numpy as np
import pytest

import fake_processors as fakes
from usdbake import core
from usdbake.processors.occlusion.ambient_occlusion import AmbientOcclusion
from usdbake.core.cache import CacheWarning
from usdbake.core.pipeline import GraphError, ParamsOutsideRun, Pipeline, ProcessorFailed, build_steps, step_key
from usdbake.core.runtime import Runtime


@pytest.fixture
def register():
    """Register fake processors for one test; remove them from the global registry afterwards."""
    core.registry.registry()  # load built-ins and entry points first, so teardown restores exactly this state
    added = []

    def _register(*classes):
        for cls in classes:
            core.registry.register(cls)
            added.append(cls.name)

    fakes.CALLS.clear()
    yield _register
    for name in added:
        core.registry.unregister(name)
    fakes.CALLS.clear()


def no_tracer(scene, **options):
    raise AssertionError("a fake processor asked for a tracer")


def fake_run(**options) -> Runtime:
    """The run-time object of a run of fake processors: nothing may trace."""
    return Runtime(no_tracer, **options)


def names(steps):
    return [step.name for step in steps]


def actions(steps):
    return {step.name: step.action for step in steps}


# ---------------------------------------------------------------------------
# Wiring


def test_build_steps_adds_dependencies_in_topological_order(register):
    register(fakes.FakeA, fakes.FakeB)
    assert names(build_steps(["fake_b"])) == ["fake_a", "fake_b"]
    # Asking for both, in either order, gives each once, producer first.
    assert names(build_steps(["fake_b", "fake_a"])) == ["fake_a", "fake_b"]
    assert names(build_steps(["fake_a", "fake_b"])) == ["fake_a", "fake_b"]


def test_build_steps_default_is_ambient_occlusion():
    assert names(build_steps(None)) == ["ambient_occlusion"]


def test_params_for_unknown_processor_rejected():
    with pytest.raises(core.ParamError, match="nope"):
        build_steps(["ambient_occlusion"], {"nope": {"x": 1}})


def test_unknown_processor_rejected():
    with pytest.raises(core.ParamError, match="unknown processor 'nope'"):
        build_steps(["nope"])


def test_params_for_a_processor_outside_the_run_are_refused_unless_ignorable(register):
    """The one check of params against the run (the hook, the command and bake_many all reach it)."""
    register(fakes.FakeA, fakes.FakeB)
    with pytest.raises(ParamsOutsideRun) as raised:
        build_steps(["fake_a"], {"fake_b": {"gain": 2.0}})
    assert (raised.value.processor, raised.value.running) == ("fake_b", ("fake_a",))
    assert str(raised.value) == ("params for 'fake_b', which is not part of this run (fake_a); "
                                 "add it to the processors")
    pipeline = Pipeline.build(["fake_a"], {"fake_b": {"gain": 2.0}}, runtime=fake_run(), ignorable=["fake_b"])
    assert (names(pipeline.steps), pipeline.ignored_params) == (["fake_a"], ("fake_b",))
    dependency = Pipeline.build(["fake_b"], {"fake_a": {"scale": 2.0}}, runtime=fake_run(), ignorable=["fake_a"])
    assert dependency.ignored_params == () and dependency.steps[0].params.scale == 2.0  # a dependency is part of the run


def test_two_producers_of_one_product_is_a_graph_error(register):
    register(fakes.FakeA, fakes.FakeB, fakes.FakeDuplicateA)
    with pytest.raises(GraphError, match="ProductA is provided by both"):
        build_steps(["fake_b"])


def test_requirement_nobody_provides_is_a_graph_error(register):
    register(fakes.FakeOrphan)
    with pytest.raises(GraphError, match="requires ProductNobodyMakes"):
        build_steps(["fake_orphan"])


def test_cycle_is_a_graph_error(register):
    register(fakes.FakeCycleC, fakes.FakeCycleD)
    with pytest.raises(GraphError, match="cycle"):
        build_steps(["fake_cycle_c"])


def test_register_refuses_a_taken_name():
    class Impostor(core.Processor):
        name = "ambient_occlusion"

    with pytest.raises(ValueError, match="taken"):
        core.registry.register(Impostor)
    assert core.registry.get("ambient_occlusion") is AmbientOcclusion


# ---------------------------------------------------------------------------
# Skips


def test_not_applicable_skips_it_and_its_dependents(register, tmp_path):
    register(fakes.FakeNotApplicable, fakes.FakeAfterNA)
    pipeline = Pipeline.build(["fake_after_na"], runtime=fake_run(), cache_dir=tmp_path / "cache")
    steps = {step.name: step for step in pipeline.run(fakes.make_scene())}
    assert steps["fake_na"].action == "skip"
    assert steps["fake_na"].reason == "not applicable: no lights in the scene"
    assert steps["fake_after_na"].action == "skip"
    assert steps["fake_after_na"].reason == "requires fake_na (skipped)"
    assert fakes.CALLS == {}
    assert pipeline.outputs() == []


# ---------------------------------------------------------------------------
# Caching


def run(names_, tmp_path, scene=None, params=None, force=False):
    pipeline = Pipeline.build(names_, params, runtime=fake_run(), cache_dir=tmp_path / "cache", force=force)
    return pipeline.run(scene if scene is not None else fakes.make_scene())


def test_second_run_is_cached_and_does_not_call_run(register, tmp_path):
    register(fakes.FakeA, fakes.FakeB)
    first = run(["fake_b"], tmp_path)
    assert actions(first) == {"fake_a": "run", "fake_b": "run"}
    assert fakes.CALLS == {"fake_a": 1, "fake_b": 1}

    second = run(["fake_b"], tmp_path)
    assert actions(second) == {"fake_a": "cached", "fake_b": "cached"}
    assert all(step.reason.startswith("up to date") for step in second)
    assert fakes.CALLS == {"fake_a": 1, "fake_b": 1}
    # The cached result is the same data, products included.
    np.testing.assert_array_equal(second[1].result.products[fakes.ProductB].values, first[1].result.products[fakes.ProductB].values)
    assert [s.key for s in second] == [s.key for s in first]


def test_changing_a_downstream_param_reruns_only_it(register, tmp_path):
    register(fakes.FakeA, fakes.FakeB)
    run(["fake_b"], tmp_path)
    steps = run(["fake_b"], tmp_path, params={"fake_b": {"gain": 2.0}})
    assert actions(steps) == {"fake_a": "cached", "fake_b": "run"}
    assert fakes.CALLS == {"fake_a": 1, "fake_b": 2}
    np.testing.assert_allclose(steps[1].result.products[fakes.ProductB].values, 2.0 * fakes.make_scene().points[:, 0])


def test_changing_an_upstream_param_reruns_downstream_too(register, tmp_path):
    register(fakes.FakeA, fakes.FakeB)
    run(["fake_b"], tmp_path)
    steps = run(["fake_b"], tmp_path, params={"fake_a": {"scale": 3.0}})
    assert actions(steps) == {"fake_a": "run", "fake_b": "run"}


def test_changing_geometry_reruns_what_reads_it_only(register, tmp_path):
    register(fakes.FakeA, fakes.FakeB, fakes.FakeLights)
    run(["fake_b", "fake_lights"], tmp_path)
    moved = fakes.make_scene().points + np.float32(0.25)
    steps = run(["fake_b", "fake_lights"], tmp_path, scene=fakes.make_scene(moved))
    assert actions(steps) == {"fake_a": "run", "fake_b": "run", "fake_lights": "cached"}
    assert fakes.CALLS == {"fake_a": 2, "fake_b": 2, "fake_lights": 1}


def test_force_reruns_everything(register, tmp_path):
    register(fakes.FakeA, fakes.FakeB)
    run(["fake_b"], tmp_path)
    steps = run(["fake_b"], tmp_path, force=True)
    assert actions(steps) == {"fake_a": "run", "fake_b": "run"}
    assert all(step.reason == "forced" for step in steps)
    assert fakes.CALLS == {"fake_a": 2, "fake_b": 2}


def test_unreadable_cache_entry_is_recomputed(register, tmp_path):
    register(fakes.FakeA)
    first = run(["fake_a"], tmp_path)
    (tmp_path / "cache" / f"fake_a-{first[0].key}.json").write_bytes(b"not a manifest")
    with pytest.warns(CacheWarning, match="not a JSON manifest"):
        steps = run(["fake_a"], tmp_path)
    assert actions(steps) == {"fake_a": "run"}
    assert fakes.CALLS == {"fake_a": 2}


def test_no_cache_dir_means_no_caching(register):
    register(fakes.FakeA)
    for _ in range(2):
        steps = Pipeline.build(["fake_a"], runtime=fake_run()).run(fakes.make_scene())
        assert actions(steps) == {"fake_a": "run"}
    assert fakes.CALLS == {"fake_a": 2}


def test_fingerprint_sees_dtype_and_shape_not_only_bytes():
    scene = fakes.make_scene()
    assert scene.fingerprint(("geometry",)) == fakes.make_scene().fingerprint(("geometry",))

    # Same bytes, another dtype: float32 points reinterpreted as int32.
    as_int = fakes.make_scene(scene.points.view(np.int32))
    assert as_int.points.tobytes() == scene.points.tobytes()
    assert as_int.fingerprint(("geometry",)) != scene.fingerprint(("geometry",))

    # Same bytes and dtype, another shape.
    reshaped = fakes.make_scene(tri_face=np.zeros((1, 2), np.int32))
    assert reshaped.tri_face.tobytes() == scene.tri_face.tobytes()
    assert reshaped.fingerprint(("geometry",)) != scene.fingerprint(("geometry",))


def test_step_key_depends_on_params_version_and_upstream():
    scene = fakes.make_scene()
    step, other = build_steps(["ambient_occlusion"])[0], build_steps(["ambient_occlusion"])[0]
    assert step_key(step, scene, []) == step_key(other, scene, [])
    other.params = AmbientOcclusion.Params(seed=1)
    assert step_key(step, scene, []) != step_key(other, scene, [])
    assert step_key(step, scene, []) != step_key(step, scene, ["upstream-key"])

    class Bumped(AmbientOcclusion):
        version = "999"

    bumped = build_steps(["ambient_occlusion"])[0]
    bumped.processor = Bumped()
    assert step_key(step, scene, []) != step_key(bumped, scene, [])


# ---------------------------------------------------------------------------
# Failures


def test_processor_that_raises_is_named_and_nothing_is_cached(register, tmp_path):
    register(fakes.FakeA, fakes.FakeBoom)
    pipeline = Pipeline.build(["fake_boom"], runtime=fake_run(), cache_dir=tmp_path / "cache")
    with pytest.raises(ProcessorFailed, match="fake_boom.*RuntimeError: kaboom") as info:
        pipeline.run(fakes.make_scene())
    assert info.value.name == "fake_boom"
    assert isinstance(info.value.error, RuntimeError)
    assert not list((tmp_path / "cache").glob("fake_boom-*"))
    failed = next(step for step in pipeline.steps if step.name == "fake_boom")
    assert failed.result is None


# ---------------------------------------------------------------------------
# Params


def test_params_defaults_and_string_conversion():
    p = fakes.FakeB.Params.from_dict({"gain": "2.5", "steps": "8", "enabled": "false"})
    assert (p.gain, p.steps, p.enabled) == (2.5, 8, False)
    assert type(p.steps) is int and type(p.gain) is float
    assert fakes.FakeB.Params.from_dict({"enabled": "TRUE"}).enabled is True
    assert fakes.FakeB.Params.from_dict({}) == fakes.FakeB.Params()

    ao = AmbientOcclusion.Params.from_dict({"samples": "16", "max_distance": "inf", "per_face": "true"})
    assert ao.samples == 16 and math.isinf(ao.max_distance) and ao.per_face is True


@pytest.mark.parametrize("values, match", [
    ({"gain": -1.0}, "below the minimum"),
    ({"gain": "1000"}, "above the maximum"),
    ({"steps": "0"}, "below the minimum"),
    ({"gain": "nan"}, "nan"),
    ({"steps": "abc"}, "not a valid int"),
    ({"steps": "2.5"}, "not a valid int"),
    ({"enabled": "maybe"}, "not a valid bool"),
    ({"nope": 1}, "unknown parameter 'nope'"),
    # Non-string values (TOML, Python) must already have the field's type.
    ({"steps": True}, "not a valid int"),
    ({"steps": 2.5}, "not a valid int"),
    ({"enabled": 1}, "not a valid bool"),
    ({"gain": "fast"}, "not a valid float"),
])
def test_invalid_params_raise_param_error(values, match):
    with pytest.raises(core.ParamError, match=match):
        fakes.FakeB.Params.from_dict(values)


def test_params_bounds_checked_at_construction():
    with pytest.raises(core.ParamError, match="samples"):
        AmbientOcclusion.Params(samples=0)
    with pytest.raises(core.ParamError, match="max_distance"):
        AmbientOcclusion.Params(max_distance=-1.0)


def test_params_describe_rows_have_default_and_doc():
    rows = {row["name"]: row for row in AmbientOcclusion.Params.describe()}
    assert set(rows) == {"samples", "max_distance", "per_face", "connect_occlusion", "seed", "instances", "target",
                         "texel_density", "max_texture_size", "margin", "denoise"}
    assert rows["samples"]["default"] == 256 and rows["samples"]["low"] == 1
    assert all(row["doc"] for row in rows.values())


def test_two_processors_declaring_one_property_are_refused_before_compute(register, tmp_path):
    register(fakes.FakeA, fakes.FakeB, fakes.FakeSamePrimvar)
    with pytest.raises(GraphError, match=r"(fake_b and fake_same_primvar|fake_same_primvar and fake_b) both write "
                                         r"primvars:bake:fakeB; run one of them"):
        Pipeline.build(["fake_b", "fake_same_primvar"], runtime=fake_run(), cache_dir=tmp_path)


def test_a_property_the_processor_did_not_declare_is_refused(register, tmp_path):
    register(fakes.FakeUndeclared)
    pipeline = Pipeline.build(["fake_undeclared"], runtime=fake_run(), cache_dir=tmp_path)
    pipeline.run(fakes.make_scene())
    with pytest.raises(ProcessorFailed, match=r"bake:stray, which its `writes` does not declare"):
        pipeline.outputs()


def test_the_built_in_processors_that_write_ao_are_refused_together():
    with pytest.raises(GraphError, match="ambient_occlusion and instance_ao both write primvars:bake:ao"):
        Pipeline.build(["ambient_occlusion", "instance_ao"], runtime=fake_run())


def test_cache_key_changes_with_the_processor_code(register, tmp_path, monkeypatch):
    """Editing a processor's module (without a version bump) must not serve the old cached result."""
    import importlib
    import sys

    module = tmp_path / "edited_processor.py"
    source = textwrap_processor("1.0")
    module.write_text(source)
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module("edited_processor")
    register(mod.Edited)
    scene = fakes.make_scene()
    first = Pipeline.build(["edited"], runtime=fake_run(), cache_dir=tmp_path / "cache").plan(scene)[0].key
    module.write_text(textwrap_processor("22.0"))  # same version string, different code (and size)
    second = Pipeline.build(["edited"], runtime=fake_run(), cache_dir=tmp_path / "cache").plan(scene)[0].key
    assert first != second
    sys.modules.pop("edited_processor", None)


def textwrap_processor(constant: str) -> str:
    return (
        "from usdbake.core import Processor, Result\n"
        "class Edited(Processor):\n"
        "    name = 'edited'\n"
        f"    def run(self, ctx):\n        return Result(stats={{'x': {constant}}})\n"
    )


# ---------------------------------------------------------------------------
# The run-time object


class FakeRuntimeReader(core.Processor):
    """Records what its Context holds in applies() and run()."""

    name = "fake_runtime_reader"
    seen: list = []

    def applies(self, ctx):
        self.seen.append((self.name, ctx.device, ctx.threads, ctx.tracer, ctx.chunks.tracer))
        return True, ""

    def run(self, ctx):
        self.seen.append((self.name, ctx.device, ctx.threads, ctx.tracer, ctx.chunks.tracer))
        return core.Result()


class FakeRuntimeReaderToo(FakeRuntimeReader):
    name = "fake_runtime_reader_too"


def test_every_step_reads_the_one_runtime(register):
    """applies() and run() of every step see the run's device and threads, and one BVH per scene: built
    once, by the runtime's tracer factory, for the chunk runner too."""
    register(FakeRuntimeReader, FakeRuntimeReaderToo)
    FakeRuntimeReader.seen.clear()
    built = []

    def build_tracer(scene, *, device, threads):
        built.append((scene, device, threads))
        return object()

    scene = fakes.make_scene()
    Pipeline.build(["fake_runtime_reader", "fake_runtime_reader_too"], runtime=Runtime(build_tracer, threads=3)) \
        .run(scene)
    assert built == [(scene, "cpu", 3)]
    assert sorted(seen[0] for seen in FakeRuntimeReader.seen) == \
        ["fake_runtime_reader"] * 2 + ["fake_runtime_reader_too"] * 2  # applies() of each, then run()
    assert {seen[1:3] for seen in FakeRuntimeReader.seen} == {("cpu", 3)}
    assert len({id(tracer) for seen in FakeRuntimeReader.seen for tracer in seen[3:]}) == 1


def test_a_step_asks_for_its_refiner_when_the_run_has_none():
    """radiosity.refined_by = sky_visibility: added (not requested, asked_by radiosity) to a run without a
    refiner, left out with refine = false, and not doubled when a refiner is already in the run."""
    steps = {step.name: step for step in build_steps(["radiosity"])}
    assert steps["sky_visibility"].asked_by == "radiosity" and not steps["sky_visibility"].requested
    assert steps["radiosity"].after == ("sky_visibility",) and steps["form_factors"].after == ("sky_visibility",)
    assert "sky_visibility" not in {step.name for step in build_steps(["radiosity"], {"radiosity": {"refine": False}})}
    asked = [step.asked_by for step in build_steps(["sky_visibility", "radiosity"])]
    assert asked == [""] * len(asked)


def test_an_asked_for_refiner_is_skipped_where_the_asker_needs_none():
    """The Cornell box has no DomeLight: the sky refinement radiosity asked for is skipped, with the reason."""
    from usdbake.stages.extract import extract_scene
    from pxr import Usd
    from repo_paths import SAMPLES

    from usdbake.kernels.tracer import Tracer

    scene = extract_scene(Usd.Stage.Open(str(SAMPLES / "cornell_box.usda")))
    pipeline = Pipeline.build(["radiosity"], runtime=Runtime(Tracer.from_scene))
    steps = {step.name: step for step in pipeline.plan(scene)}
    assert steps["sky_visibility"].action == "skip"
    assert "radiosity needs no refinement here: no DomeLight" in steps["sky_visibility"].reason
    assert steps["radiosity"].action == "run"


def test_target_reaches_the_steps_with_a_target_param_and_leaves_the_other_params_alone():
    steps = {step.name: step for step in build_steps(["radiosity"], {"form_factors": {"rays": 64}},
                                                     target="texture")}
    assert steps["radiosity"].params.target == "texture" and steps["form_factors"].params.rays == 64
    own = {step.name: step for step in build_steps(["radiosity"], {"radiosity": {"target": "both"}},
                                                   target="texture")}
    assert own["radiosity"].params.target == "both"  # a processor's own target wins
    with pytest.raises(core.ParamError, match="target='uv'"):
        build_steps(["radiosity"], target="uv")
