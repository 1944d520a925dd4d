"""instance_ao: AO through displacement fields against the exact ray-cast AO (ambient_occlusion).

The two processors cast the same rays (same seeds, strata and ray offsets), so their
difference is the field approximation alone.
"""

from repo_paths import SAMPLES

import numpy as np
import pytest
from instanced_scenes import build_scene, grid, icosphere, run_processor, translate
from tolerances import (AO_RMS_FIGURE, CELL_BORDER_FLIPS, FLOAT32_STORAGE, FLOAT64_AMPLIFIED, INSIDE_RMS,
                        INSTANCE_MEAN_TOL, RAY_MISMATCH, SHARED_FIELD_RMS, SINGLE_RAY_FLIP, SYNTHETIC_RMS)

from usdbake.processors.instancing.products import DisplacementFieldSet, InstanceOcclusionProduct
from usdbake.processors.occlusion.products import AmbientOcclusionProduct
from usdbake import core
from usdbake.processors.instancing import instance_ao as ia
from usdbake.processors.occlusion.ambient_occlusion import AmbientOcclusion
from usdbake.processors.instancing.displacement_fields import DisplacementFields, build_field
from usdbake.processors.instancing.transforms import invertible
from usdbake.processors.instancing import field_kernels as displacement_field
from usdbake.processors.instancing.instance_ao import InstanceAO, parse_frames, query_field
from usdbake.kernels.tracer import Tracer


def exact_ao(scene, samples=256, **params) -> np.ndarray:
    """ambient_occlusion's AO at the receivers' points (1 at instances' points, as instance_ao leaves them)."""
    params = {"instances": "skip", **params}
    ctx = core.Context(scene=scene, params=AmbientOcclusion.Params(samples=samples, **params),
                       tracer=Tracer.from_scene(scene))
    return AmbientOcclusion().run(ctx).products[AmbientOcclusionProduct].point_ao


def field_ao(scene, fields_params=None, ao_params=None, fields=None):
    if fields is None:
        fields = run_processor(DisplacementFields, scene, fields_params).products[DisplacementFieldSet].fields
    result = run_processor(InstanceAO, scene, ao_params, {DisplacementFieldSet: DisplacementFieldSet(fields)})
    return result, fields


def receiver_rms(scene, a, b) -> float:
    mask = np.isin(scene.point_prim, np.flatnonzero(scene.prim_writable))
    return float(np.sqrt(np.mean((a[mask] - b[mask]) ** 2)))


# ---------------------------------------------------------------------------
# instanced_props.usda: the figure, and per-frame AO


@pytest.fixture(scope="module")
def props():
    from pxr import Usd

    from usdbake.stages.extract import extract_scene

    stage = Usd.Stage.Open(str(SAMPLES / "instanced_props.usda"))
    scene = extract_scene(stage)
    fields = run_processor(DisplacementFields, scene).products[DisplacementFieldSet].fields  # 4225 x 32x32 uint8
    return stage, scene, fields


def test_field_ao_matches_exact_ao_on_instanced_props(props):
    _, scene, fields = props
    assert sorted(fields) == ["/World/Scatter/Prototypes/Crate", "/World/Scatter/Prototypes/Vase"]
    assert all(f.side ** 2 == 4225 and f.map_size == 32 and f.encoding == "uint8" for f in fields.values())
    result, _ = field_ao(scene, fields=fields)
    ao = result.products[InstanceOcclusionProduct].point_ao_by_frame[None]
    reference = exact_ao(scene)
    rms = receiver_rms(scene, ao, reference)
    assert rms <= AO_RMS_FIGURE, rms
    # the instances do occlude the floor (the comparison is not trivially 1 = 1)
    floor = np.isin(scene.point_prim, np.flatnonzero(scene.prim_writable))
    assert (reference[floor] < 0.9).sum() >= 10
    primvars = [r for r in result.outputs if isinstance(r, core.Primvar)]
    assert [(r.prim, r.name, r.interpolation, r.time) for r in primvars] == [("/World/Floor", "bake:ao", "vertex",
                                                                             None)]


def test_frames_give_time_samples_without_rebuilding_the_bvh(props, monkeypatch):
    from usdbake.stages.extract import extract_scene

    stage, scene, fields = props
    np.testing.assert_array_equal(scene.instances.instance_times, [1, 2, 3])
    built = []

    class CountingTracer(Tracer):
        def __init__(self, *args, **kwargs):
            built.append(1)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(ia, "Tracer", CountingTracer)
    monkeypatch.setattr(displacement_field, "Tracer", CountingTracer)  # FieldSet's prototype BVHs
    result, _ = field_ao(scene, ao_params={"frames": "1:3"}, fields=fields)
    assert len(built) == 2  # the scene BVH and one of every prototype (self-occlusion), not one per frame
    by_frame = result.products[InstanceOcclusionProduct].point_ao_by_frame
    assert sorted(by_frame) == [1.0, 2.0, 3.0]
    assert sorted(r.time for r in result.outputs) == [1.0, 2.0, 3.0]
    # the props move 15 cm per frame: frame 3 differs from frame 1, and matches the exact AO at time 3
    assert np.abs(by_frame[3.0] - by_frame[1.0]).max() > 0.02
    at_three = extract_scene(stage, time=3.0)
    assert at_three.prim_paths == scene.prim_paths
    # extraction's per-time transforms are the transforms a scene read at that time holds (world space)
    world_at = scene.instances.instance_transforms_at_times[2].copy()
    world_at[:, 3, :3] += scene.origin
    world_three = at_three.instances.instance_transforms.copy()
    world_three[:, 3, :3] += at_three.origin
    np.testing.assert_allclose(world_at, world_three, atol=FLOAT64_AMPLIFIED)
    rms = receiver_rms(scene, by_frame[3.0], exact_ao(at_three))
    assert rms <= AO_RMS_FIGURE, rms


def test_frames_param_selects_authored_time_codes_and_names_missing_ones():
    times = np.array([1.0, 2.0, 3.0, 4.0])
    assert parse_frames("", times) is None
    assert parse_frames("all", times) == [1, 2, 3, 4]
    assert parse_frames("1:4:2", times) == [1, 3]
    assert parse_frames("2,4", times) == [2, 4]
    with pytest.raises(ValueError, match=r"time code\(s\) 5 have no authored instance transforms"):
        parse_frames("4:5", times)
    with pytest.raises(ValueError, match="authored: none"):
        parse_frames("1", np.zeros(0))


# ---------------------------------------------------------------------------
# Synthetic scenes


def _balls_scene(extra=()):
    """Ground grid with a row of balls (one prototype) sitting on it, plus ``extra`` instances."""
    ball, ball_tris = icosphere(3)
    dumbbell = np.r_[ball * 0.3 + [0.6, 0, 0], ball * 0.3 - [0.6, 0, 0]]
    dumbbell_tris = np.r_[ball_tris, ball_tris + len(ball)]
    ground, ground_tris = grid(3, 24)
    prototypes = [("/World/P/Ball", ball * 0.4, ball_tris), ("/World/P/Dumbbell", dumbbell, dumbbell_tris)]
    instances = [(0, translate(-2 + 1.2 * i, 0.4, 0.3 * i - 1)) for i in range(4)] + list(extra)
    return build_scene([("/World/Ground", ground, ground_tris)], prototypes, instances)


SMALL_FIELDS = {"positional_samples": 1089, "direction_map_size": 16, "force": "Ball,Dumbbell"}


def test_without_fields_instance_ao_is_ambient_occlusion():
    """Forbidding every field sends all triangles through the BVH: the same rays give the same AO."""
    scene = _balls_scene()
    result, fields = field_ao(scene, {"forbid": "Ball,Dumbbell"}, {"samples": 64})
    assert fields == {}
    np.testing.assert_array_equal(result.products[InstanceOcclusionProduct].point_ao_by_frame[None], exact_ao(scene, samples=64))


def test_instance_inside_another_instances_sphere_and_receivers_inside_spheres():
    """A ball inside the dumbbell's bounding sphere (between its lobes), everything resting on the ground."""
    inner = [(1, translate(1.5, 0.3, 1.5, rotate_y=0.4)), (0, translate(1.5, 0.4, 1.5, scale=(0.5,) * 3))]
    scene = _balls_scene(inner)
    centers = [m[3, :3] for m in scene.instances.instance_transforms]
    assert np.linalg.norm(centers[4] - centers[5]) < 0.3  # the ball sits inside the dumbbell's sphere
    result, fields = field_ao(scene, {"force": "Ball,Dumbbell"}, {"samples": 256})  # 4225 x 32x32
    assert len(fields) == 2
    ao = result.products[InstanceOcclusionProduct].point_ao_by_frame[None]
    reference = exact_ao(scene, samples=256)
    assert np.isfinite(ao).all() and (ao >= 0).all() and (ao <= 1).all()
    assert receiver_rms(scene, ao, reference) <= AO_RMS_FIGURE
    # ground points inside the dumbbell's sphere (radius 0.9 around (1.5, 0.3, 1.5)) are the hard case
    ground = scene.points[:625]
    inside = np.linalg.norm(ground - [1.5, 0.3, 1.5], axis=1) < 0.9
    assert inside.sum() >= 5
    assert np.sqrt(np.mean((ao[:625][inside] - reference[:625][inside]) ** 2)) <= INSIDE_RMS


def test_singular_instances_are_traced_as_triangles():
    flat = [(0, translate(1.5, 0.01, 1.5, scale=(2.0, 0.0, 2.0)))]  # a squashed ball: a flat disc
    scene = _balls_scene(flat)
    assert invertible(scene.instances.instance_transforms).tolist() == [True] * 4 + [False]
    result, _ = field_ao(scene, SMALL_FIELDS, {"samples": 64})
    assert result.stats["traced_triangles"] == 2 * 24 * 24 + 1280
    ao = result.products[InstanceOcclusionProduct].point_ao_by_frame[None]
    assert np.isfinite(ao).all()
    assert receiver_rms(scene, ao, exact_ao(scene, samples=64)) <= SYNTHETIC_RMS


def _dumbbell_field(samples=1089, size=16):
    ball, ball_tris = icosphere(3)
    points = np.r_[ball * 0.3 + [0.6, 0, 0], ball * 0.3 - [0.6, 0, 0]]
    return points, np.r_[ball_tris, ball_tris + len(ball)].astype(np.int32), \
        build_field(points, np.r_[ball_tris, ball_tris + len(ball)], positional_samples=samples, map_size=size)


def test_rotation_and_non_uniform_scale_are_handled_exactly_by_the_affine_inverse():
    """World rays through a rotated, sheared, non-uniformly scaled instance see what the mapped rays see."""
    points, triangles, field = _dumbbell_field()
    rotation = np.linalg.qr(np.random.default_rng(11).normal(size=(3, 3)))[0]  # fixed seed
    matrix = np.eye(4)
    matrix[:3, :3] = np.diag([2.0, 0.5, 1.3]) @ rotation
    matrix[1, 0] += 0.3  # shear
    matrix[3, :3] = [5.0, -2.0, 1.0]
    rng = np.random.default_rng(12)  # fixed seed
    n = 20000
    proto_origins = rng.normal(size=(n, 3))
    proto_origins *= (field.radius * rng.uniform(1.05, 3.0, n) / np.linalg.norm(proto_origins, axis=1))[:, None]
    targets = field.center + rng.normal(size=(n, 3)) * 0.4
    proto_dirs = targets - proto_origins
    proto_dirs /= np.linalg.norm(proto_dirs, axis=1, keepdims=True)
    world_origins = (np.c_[proto_origins, np.ones(n)] @ matrix)[:, :3]
    world_dirs = proto_dirs @ matrix[:3, :3]
    world_dirs /= np.linalg.norm(world_dirs, axis=1, keepdims=True)
    in_world = query_field(field, matrix, world_origins, world_dirs)
    in_proto = query_field(field, np.eye(4), proto_origins, proto_dirs)
    assert np.mean(in_world != in_proto) < CELL_BORDER_FLIPS  # float32 rounding at cell borders only
    # and both agree with exact ray casts against the transformed geometry
    world_points = (np.c_[points, np.ones(len(points))] @ matrix)[:, :3]
    exact = Tracer(world_points.astype(np.float32), triangles).occluded(world_origins, world_dirs)
    assert 0.2 < exact.mean() < 0.8
    exact_proto = Tracer(points.astype(np.float32), triangles).occluded(proto_origins, proto_dirs)
    wrong_world, wrong_proto = np.mean((1 - in_world) != exact), np.mean((1 - in_proto) != exact_proto)
    assert wrong_world <= wrong_proto + CELL_BORDER_FLIPS  # the transform adds no error (measured: equal, 5.0%)
    assert wrong_proto < RAY_MISMATCH


def test_rays_grazing_the_bounding_sphere():
    _, _, field = _dumbbell_field(samples=289, size=8)
    c, r = field.center, field.radius
    angles = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    offsets = np.stack([np.zeros_like(angles), np.cos(angles), np.sin(angles)], axis=1)
    direction = np.tile([1.0, 0.0, 0.0], (len(angles), 1))
    for factor, expect_one in ((1.0 + 1e-4, True), (1.0, False), (1.0 - 1e-4, False)):
        origins = c - [3 * r, 0, 0] + offsets * r * factor
        visibility = query_field(field, np.eye(4), origins, direction, interpolation="quadrilinear")
        assert np.isfinite(visibility).all() and (visibility >= 0).all() and (visibility <= 1).all()
        if expect_one:
            np.testing.assert_array_equal(visibility, 1.0)
    # a ray from inside the sphere pointing away from the prototype through empty space sees nothing
    inside = query_field(field, np.eye(4), np.array([c + [0, 0.5 * r, 0]]), np.array([[0.0, 1.0, 0.0]]))
    assert inside[0] == 1.0
    # a ray starting inside the sphere, off the axis, towards the +x lobe is blocked
    origin = c + [0.0, 0.5, 0.0]
    towards = np.array([[0.6, -0.5, 0.0]]) / np.hypot(0.6, 0.5)
    assert query_field(field, np.eye(4), np.array([origin]), towards)[0] == 0.0
    # documented limitation: from the centre towards +x, the first hit along the line is the -x lobe,
    # behind the origin; the +x lobe ahead is not stored, so the ray counts as unoccluded
    between = query_field(field, np.eye(4), np.array([c]), np.array([[1.0, 0.0, 0.0]]))
    assert between[0] == 1.0
    # a lobe behind an origin inside the sphere does not block: its hit lies behind the origin
    origin = c + [0.6, 0.0, 0.45]  # above the +x lobe (radius 0.3), inside the bounding sphere (0.75 < 0.9)
    behind = query_field(field, np.eye(4), np.array([origin]), np.array([[0.0, 0.0, 1.0]]))
    assert behind[0] == 1.0
    ahead = query_field(field, np.eye(4), np.array([origin]), np.array([[0.0, 0.0, -1.0]]))
    assert ahead[0] == 0.0


def test_bake_instanced_props_end_to_end(tmp_path):
    """Through the Python hook: fields on the prototypes with the applied API, AO time samples on the floor."""
    from pxr import Usd, UsdGeom

    import usdbake

    stage = Usd.Stage.Open(str(SAMPLES / "instanced_props.usda"))
    layer = usdbake.bake(stage, ["instance_ao"], {"displacement_fields": {"positional_samples": 289,
                                                                         "direction_map_size": 8},
                                                  "instance_ao": {"samples": 16, "frames": "all"}},
                         texture_dir=str(tmp_path))
    assert layer is not None
    vase = stage.GetPrimAtPath("/World/Scatter/Prototypes/Vase")
    assert vase.HasAPI("DisplacementFieldAPI")
    assert vase.GetAttribute("bake:field:encoding").Get() == "uint8"
    assert vase.GetAttribute("bake:field:positionalSamples").Get() == 289
    file_name = vase.GetAttribute("bake:field:file").Get().path
    assert (tmp_path / file_name).exists()
    ao = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Floor")).GetPrimvar("bake:ao")
    assert ao.GetInterpolation() == "vertex"
    assert ao.GetAttr().GetTimeSamples() == [1.0, 2.0, 3.0]
    values = np.array(ao.Get(2.0))
    assert len(values) == 256 and np.isfinite(values).all() and values.min() < 0.9


def _instance_means(scene, ao) -> np.ndarray:
    """Area-weighted mean of per-point AO over each instance's points."""
    area = np.zeros(scene.num_points)
    np.add.at(area, scene.tri_vertices.ravel(), np.repeat(scene.tri_areas.astype(np.float64) / 3, 3))
    prim_instance = np.full(len(scene.prim_paths), -1)
    prim_instance[scene.tri_prim] = scene.tri_instance
    instance = prim_instance[scene.point_prim]
    mine = instance >= 0
    total = np.bincount(instance[mine], weights=(ao * area)[mine], minlength=len(scene.instances))
    return total / np.bincount(instance[mine], weights=area[mine], minlength=len(scene.instances))


def test_instances_receive_self_and_mutual_occlusion_per_frame():
    import dataclasses

    ball, ball_tris = icosphere(3)
    ground, ground_tris = grid(3, 12)
    at_rest = [translate(-0.45, 0.4, 0), translate(0.45, 0.4, 0), translate(2.0, 0.4, 2.0)]
    moved = [translate(-0.45, 0.4, 0), translate(-2.0, 0.4, -2.0, rotate_y=1.0), translate(2.0, 0.4, 2.0)]
    prototypes = [("/World/P/Ball", ball * 0.4, ball_tris)]
    scene = build_scene([("/World/Ground", ground, ground_tris)], prototypes, [(0, m) for m in at_rest],
                        times=[1.0, 2.0], transforms_at_times=[at_rest, moved])
    result, fields = field_ao(scene, SMALL_FIELDS, {"samples": 256, "frames": "all", "instances": True})
    per_instance = result.products[InstanceOcclusionProduct].instance_ao_by_frame
    records = [r for r in result.outputs if r.prim == "/World/Scatter"]
    assert [(r.name, r.interpolation, r.time, len(r.values)) for r in records] == [
        ("bake:ao", "vertex", 1.0, 3), ("bake:ao", "vertex", 2.0, 3)]
    for frame, transforms in ((1.0, at_rest), (2.0, moved)):
        exact_scene = build_scene([("/World/Ground", ground, ground_tris)], prototypes, [(0, m) for m in transforms])
        exact_scene = dataclasses.replace(exact_scene, prim_writable=np.ones(len(exact_scene.prim_paths), bool))
        exact = _instance_means(exact_scene, exact_ao(exact_scene, samples=256))
        np.testing.assert_allclose(per_instance[frame], exact, atol=INSTANCE_MEAN_TOL)
    # balls 0 and 1 (0.1 apart) shade each other at frame 1; at frame 2 ball 1 has moved away from ball 0
    assert per_instance[1.0][0] < per_instance[1.0][2] - 0.02
    assert per_instance[2.0][0] > per_instance[1.0][0] + 0.01


# ---------------------------------------------------------------------------
# One field for copies of a prototype moved rigidly or rounded (issue 27)


def lopsided_prototype() -> tuple[np.ndarray, np.ndarray]:
    """A bent, asymmetric blob (no symmetry a wrong rotation could hide behind): (P, 3) points, triangles."""
    points, triangles = icosphere(2)
    points = points * [0.6, 0.35, 0.25]
    points[:, 0] += 2.4 * np.maximum(points[:, 1], 0) ** 2
    points[:, 2] += 0.2 * (points[:, 0] > 0.2)
    return points, triangles


def moved_copies_scene(*, fold: bool = False):
    """A floor with six instances of one lopsided shape, in world space the same shape at six places. Their
    prototypes: A; B = A turned and moved (its instances undo that motion); C = A with 1e-6 relative noise.
    ``fold``: the twin scene where every instance is one of A, with B's motion folded into its transforms.
    Returns (scene, prototypes, motion S with B = [A, 1] @ S)."""
    a, triangles = lopsided_prototype()
    rng = np.random.default_rng(7)  # fixed seed: a reproducible turn and noise
    rotation = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    rotation[:, 0] *= np.sign(np.linalg.det(rotation))  # proper
    motion = np.eye(4)
    motion[:3, :3], motion[3, :3] = rotation, [0.4, -0.2, 0.7]
    b = a @ rotation + motion[3, :3]
    c = a + rng.normal(size=a.shape) * 1e-6 * np.ptp(a, axis=0).max()
    prototypes = [("/World/A/Prototypes/P", a, triangles), ("/World/B/Prototypes/P", b, triangles),
                  ("/World/C/Prototypes/P", c, triangles)]
    world = [(0, translate(-1.5, 0.4, -1.0, rotate_y=0.3)), (0, translate(1.2, 0.45, 1.3, rotate_y=2.0)),
             (1, translate(0.0, 0.4, 0.2, rotate_y=1.1)), (1, translate(-1.0, 0.5, 1.6)),
             (2, translate(1.5, 0.4, -1.2, rotate_y=-0.7)), (2, translate(-2.0, 0.45, 0.3, rotate_y=0.9))]
    instances = [(k, np.linalg.inv(motion) @ m if k == 1 else m) for k, m in world]
    if fold:
        prototypes, instances = prototypes[:1], [(0, motion @ m if k == 1 else m) for k, m in instances]
    return build_scene([("/World/Floor", *grid(3, 30))], prototypes, instances), prototypes, motion


SHARED_FIELD = {"positional_samples": 1089, "direction_map_size": 16, "min_instances": 1}


def test_moved_and_rounded_copies_share_one_field_folded_into_their_instances():
    """B (turned and moved) and C (1e-6 noise) share A's field: one build. instance_ao through it equals the
    twin scene where B's motion is folded into its instances' transforms (the fold is exact), and agrees
    with fields built for each copy within SHARED_FIELD_RMS; both stay within SYNTHETIC_RMS of exact AO."""
    scene, prototypes, motion = moved_copies_scene()
    fields = run_processor(DisplacementFields, scene, SHARED_FIELD).products[DisplacementFieldSet].fields
    a, b, c = (fields[path] for path, _, _ in prototypes)
    assert b.texels is a.texels and c.texels is a.texels
    np.testing.assert_allclose(b.frame, motion, atol=FLOAT32_STORAGE)  # recovered from float32 scene points
    assert (c.frame[:3, :3] == np.eye(3)).all()
    samples = 256
    shared, _ = field_ao(scene, fields=fields, ao_params={"samples": samples})
    shared = shared.products[InstanceOcclusionProduct].point_ao_by_frame[None]

    folded_scene, _, _ = moved_copies_scene(fold=True)
    folded, _ = field_ao(folded_scene, SHARED_FIELD, {"samples": samples})
    floor = scene.point_prim == 0
    np.testing.assert_allclose(shared[floor], folded.products[InstanceOcclusionProduct].point_ao_by_frame[None][floor],
                               atol=SINGLE_RAY_FLIP / samples)

    own = {path: build_field(points, triangles, prototype=path, positional_samples=1089, map_size=16)
           for path, points, triangles in prototypes}
    separate, _ = field_ao(scene, fields=own, ao_params={"samples": samples})
    separate = separate.products[InstanceOcclusionProduct].point_ao_by_frame[None]
    reference = exact_ao(scene, samples=samples)
    assert (reference[floor] < 0.9).sum() >= 100  # the copies do shade the floor
    rms = receiver_rms(scene, shared, separate)
    print(f"shared vs separately built fields: RMS {rms:.4f}, max {np.abs(shared - separate)[floor].max():.4f}")
    assert rms <= SHARED_FIELD_RMS
    assert receiver_rms(scene, shared, reference) <= SYNTHETIC_RMS
    assert receiver_rms(scene, separate, reference) <= SYNTHETIC_RMS
