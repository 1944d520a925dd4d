"""displacement_fields: analytic distances on a sphere prototype, encodings and atlas, cost model, records.

The synthetic scenes are built by instanced_scenes.py (shared with test_instance_ao.py).
"""

import numpy as np
from stage_builders import base_context
import pytest
from tolerances import (BOUNDING_SPHERE_SLACK, FIELD_GRAZING_ERROR, FLOAT32_STORAGE, FLOAT64_AMPLIFIED,
                        ICOSPHERE_SAGITTA, ROUNDING_MEAN_SHARE, UINT8_CODE_STEP)

from kernel_twins import cosine_hemisphere_np, grid_cell_centers_np
from usdbake.processors.instancing.products import DisplacementFieldSet
from usdbake import core
from usdbake.processors.instancing.field_kernels import MAX_HIT_CODE, MISS_CODE, field_atlas, field_from_atlas
from usdbake.processors.instancing.displacement_fields import (DisplacementFields, build_field, choose_prototypes,
                                                    field_records, prototype_geometry, side_for)
from instanced_scenes import build_scene, grid, icosphere, run_processor, translate

# ---------------------------------------------------------------------------
# Synthetic geometry and scenes (no USD)












# ---------------------------------------------------------------------------
# Field values


SPHERE_LEVEL = 5
"""Icosphere level of the sphere prototype: 20480 triangles, sagitta ~1.2e-4 of the radius."""


def test_sphere_prototype_field_matches_analytic_distances():
    """Distances t / 2R from every sample and texel against the exact ray-sphere distance.

    The prototype is a unit sphere plus a small marker ball 3 units away, so the bounding
    sphere (R ~ 2.03) is not the sphere itself: rays travel, hit at all depths or miss.
    """
    ball, ball_tris = icosphere(SPHERE_LEVEL)
    marker, marker_tris = icosphere(1)
    offset = np.array([0.5, -3.0, 1.0])  # off the origin
    marker_center = np.array([3.0, 0.0, 0.0])
    points = np.r_[ball, marker * 0.05 + marker_center] + offset
    triangles = np.r_[ball_tris, marker_tris + len(ball)]
    field = build_field(points, triangles, positional_samples=17 ** 2, map_size=16)
    n, m = field.side, field.map_size
    assert n == 17
    radius = field.radius
    np.testing.assert_allclose(field.center, offset + [1.025, 0, 0], atol=FLOAT64_AMPLIFIED)
    assert 2.025 <= radius <= 2.025 * (1 + ICOSPHERE_SAGITTA)
    s = grid_cell_centers_np(n)
    a, b = np.meshgrid((np.arange(m) + 0.5) / m, (np.arange(m) + 0.5) / m)  # texel (row b, column a)
    local = cosine_hemisphere_np(a.ravel(), b.ravel())  # (M*M, 3)
    codes = field.texels.reshape(n * n, m * m)
    errors, hits, misses = [], 0, 0
    for k in range(n * n):
        d = local @ _duff_frame(-s[k]).T
        origin = field.center + s[k] * radius - offset  # relative to the unit sphere's centre
        bq = -(d @ origin)  # t of the closest approach to the centre
        closest = np.linalg.norm(origin + bq[:, None] * d, axis=1)
        to_marker = origin - marker_center
        near_marker = np.linalg.norm(to_marker - (to_marker @ d.T)[:, None] * d, axis=1) < 0.1
        # skip rays within a sagitta of tangency (the tessellation decides) and rays near the marker
        clear = (np.abs(closest - 1.0) > 4e-3) & ~near_marker
        hit = closest < 1.0
        exact = bq - np.sqrt(np.maximum(1.0 - closest ** 2, 0.0))
        stored = codes[k] != MISS_CODE
        np.testing.assert_array_equal(stored[clear], hit[clear], err_msg=f"sample {k}")
        both = clear & hit
        errors.append(codes[k][both] / MAX_HIT_CODE * 2 * radius - exact[both])
        hits += both.sum()
        misses += (clear & ~hit).sum()
    errors = np.concatenate(errors)
    assert hits > 10000 and misses > 10000  # both outcomes are exercised (18k and 56k of 74k rays)
    half_step = 2 * radius / (2 * MAX_HIT_CODE)
    # quantization (half a code step) + the chord sagitta seen at grazing incidence
    assert np.abs(errors).max() <= half_step + FIELD_GRAZING_ERROR
    assert np.abs(errors).mean() <= ROUNDING_MEAN_SHARE * half_step  # rounding errors spread evenly
    assert errors.max() > 0.5 * half_step  # the distances do span the quantization steps


def _duff_frame(n: np.ndarray) -> np.ndarray:
    """numpy copy of sampling.tangent_frame: (3, 3) with columns t, s, n."""
    sign = 1.0 if n[2] >= 0 else -1.0
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    t = np.array([1 + sign * n[0] ** 2 * a, sign * b, -sign * n[0]])
    s = np.array([b, sign + n[1] ** 2 * a, -n[1]])
    return np.stack([t, s, n], axis=1)


def test_uint8_and_bit1_fields_agree_on_hits_and_bit1_is_about_8x_smaller():
    points, triangles = icosphere(3)
    uint8 = build_field(points, triangles, positional_samples=81, map_size=16, encoding="uint8")
    bit1 = build_field(points, triangles, positional_samples=81, map_size=16, encoding="bit1")
    hits_uint8 = uint8.texels.reshape(81, -1) != MISS_CODE
    hits_bit1 = np.unpackbits(bit1.texels, axis=1, bitorder="little").astype(bool)
    np.testing.assert_array_equal(hits_uint8, hits_bit1)
    # the per-sample mean is the mean of the 8-bit distances of the hits (one extra rounding)
    mean = np.array([uint8.texels[k][uint8.texels[k] != MISS_CODE].mean() for k in range(81)])
    np.testing.assert_allclose(bit1.mean_codes, mean, atol=UINT8_CODE_STEP)
    assert 7.0 <= uint8.nbytes / bit1.nbytes <= 8.0


@pytest.mark.parametrize("encoding", ["uint8", "bit1"])
def test_atlas_round_trip_through_a_png(tmp_path, encoding):
    import OpenImageIO as oiio

    from usdbake.stages.sidecars import write_texture

    points, triangles = icosphere(2)
    field = build_field(points * 0.3, triangles, prototype="/World/Proto", positional_samples=25, map_size=8,
                        encoding=encoding)
    records = field_records(field)
    texture = records[0]
    assert isinstance(texture, core.Texture) and texture.pixels.dtype == np.uint8
    path = write_texture(texture, str(tmp_path))
    pixels = oiio.ImageBuf(path).get_pixels(oiio.UINT8)
    np.testing.assert_array_equal(pixels[:, :, 0], field_atlas(field))
    texels, means = field_from_atlas(pixels, side=5, map_size=8, encoding=encoding)
    np.testing.assert_array_equal(texels, field.texels)
    if encoding == "bit1":
        np.testing.assert_array_equal(means, field.mean_codes)


# ---------------------------------------------------------------------------
# The processor: cost model, records, degenerate input


def _props_scene(counts=(6, 1)):
    ball, ball_tris = icosphere(2)
    cube = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float) - 0.5
    cube_tris = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4], [2, 6, 3], [3, 6, 7],
                          [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], np.int32)
    floor, floor_tris = grid(5, 4)
    prototypes = [("/World/Scatter/Prototypes/Ball", ball * 0.4, ball_tris),
                  ("/World/Scatter/Prototypes/Box", cube, cube_tris)]
    instances = [(0, translate(-3 + i, 0.4, 1)) for i in range(counts[0])]
    instances += [(1, translate(-3 + i, 0.5, -2)) for i in range(counts[1])]
    return build_scene([("/World/Floor", floor, floor_tris)], prototypes, instances)


def test_prototype_geometry_is_recovered_in_prototype_space():
    scene = _props_scene()
    points, triangles, instance = prototype_geometry(scene, 0)
    expected, _ = icosphere(2)
    np.testing.assert_allclose(points, expected * 0.4, atol=FLOAT32_STORAGE)  # float32 scene points
    assert len(triangles) == 320 and instance == 0


def test_cost_model_force_forbid_and_min_instances():
    scene = _props_scene(counts=(6, 1))
    params = DisplacementFields.Params
    chosen, messages = choose_prototypes(scene, params())
    assert chosen == [0]
    assert "1 instance(s) < min_instances=2" in messages[1]
    chosen, messages = choose_prototypes(scene, params(force="Box", forbid="/World/Scatter/Prototypes/Ball"))
    assert chosen == [1] and "forbidden" in messages[0] and "forced" in messages[1]
    chosen, messages = choose_prototypes(scene, params(expected_rays_per_instance=1e3))
    assert chosen == [] and "build rays" in messages[0]


def test_applies_and_param_validation():
    empty = build_scene([("/World/Floor", *grid(1, 1))], [], [])
    assert DisplacementFields().applies(base_context(empty)) == (False, "no instanced prototypes")
    assert DisplacementFields().applies(base_context(_props_scene()))[0]
    with pytest.raises(core.ParamError, match="multiple of 8"):
        DisplacementFields.Params(encoding="bit1", direction_map_size=12)
    with pytest.raises(core.ParamError, match="encoding"):
        DisplacementFields.Params(encoding="float")
    assert side_for(4226) == 65 and side_for(1090) == 33
    with pytest.raises(core.ParamError, match="rays per prototype is above the maximum"):
        DisplacementFields.Params(positional_samples=66049, direction_map_size=256)


def test_run_writes_texture_and_applied_schema_on_the_prototype():
    result = run_processor(DisplacementFields, _props_scene(), {"positional_samples": 64, "direction_map_size": 8})
    fields = result.products[DisplacementFieldSet].fields
    assert list(fields) == ["/World/Scatter/Prototypes/Ball"]
    prims = [r for r in result.outputs if isinstance(r, core.Prim)]
    assert prims == [core.Prim("/World/Scatter/Prototypes/Ball", api_schemas=("DisplacementFieldAPI",))]
    attributes = {r.name: r for r in result.outputs if isinstance(r, core.Attribute)}
    assert attributes["bake:field:file"].value == "./displacement_fields/World_Scatter_Prototypes_Ball.png"
    assert attributes["bake:field:positionalSamples"].value == 64
    assert attributes["bake:field:directionMapSize"].type_name == "int2"
    assert attributes["bake:field:positionMapping"].value == "octahedralEqualArea"
    assert attributes["bake:field:directionMapping"].value == "concentricMalley"
    assert abs(attributes["bake:field:radius"].value - 0.4) < BOUNDING_SPHERE_SLACK
    assert any("Box: no field" in message for message in result.messages)


def test_degenerate_prototype_is_skipped_with_a_reason():
    point = np.zeros((3, 3))
    scene = build_scene([("/World/Floor", *grid(1, 1))], [("/World/P/Dot", point, np.array([[0, 1, 2]], np.int32))],
                        [(0, translate(0, 0, 0)), (0, translate(1, 0, 0))])
    result = run_processor(DisplacementFields, scene, {"positional_samples": 16, "direction_map_size": 8})
    assert result.products[DisplacementFieldSet].fields == {}
    assert any("no extent" in message for message in result.messages)


def test_identical_prototypes_share_one_field():
    """Two instancers' copies of one ball (different paths, instances at other places and rotations) get
    one field, built once; a different shape gets its own."""
    ball, ball_tris = icosphere(2)
    floor, floor_tris = grid(5, 4)
    prototypes = [("/World/A/Prototypes/Ball", ball * 0.4, ball_tris),
                  ("/World/B/Prototypes/Ball", ball * 0.4, ball_tris),
                  ("/World/C/Prototypes/Ball", ball * 0.5, ball_tris)]
    instances = [(k % 3, translate(-3 + k, 0.5, 1.5 * (k % 2), rotate_y=37.0 * k)) for k in range(9)]
    scene = build_scene([("/World/Floor", floor, floor_tris)], prototypes, instances)
    params = {"positional_samples": 64, "direction_map_size": 8, "min_instances": 1}
    result = run_processor(DisplacementFields, scene, params)
    fields = result.products[DisplacementFieldSet].fields
    assert set(fields) == {path for path, _, _ in prototypes}
    a, b, c = (fields[path] for path, _, _ in prototypes)
    assert a.texels is b.texels and a.prototype != b.prototype and c.texels is not a.texels
    assert "/World/B/Prototypes/Ball: shares the field of /World/A/Prototypes/Ball (same shape)" in result.messages
    assert result.stats["rays"] == 2 * a.side ** 2 * a.map_size ** 2  # two fields built, not three


def test_a_turned_copy_shares_the_field_and_its_records_say_how_it_is_turned():
    """A prototype authored a second time turned 90 degrees about y and moved (its instances undo it), and a
    third time with 1e-6 relative noise: one field built; the turned one's records give the shared sphere
    centre in its own space and the turn as bake:field:orientation (real, i, j, k); the noisy one has none."""
    ball, ball_tris = icosphere(2)
    shape = ball * [0.5, 0.3, 0.2] + [0.1, 0.0, 0.0]  # not symmetric about its box centre
    turn = translate(0.3, 0.2, -0.1, rotate_y=np.pi / 2)
    rng = np.random.default_rng(5)  # fixed seed: reproducible noise
    noisy = shape + rng.normal(size=shape.shape) * 1e-6 * np.ptp(shape, axis=0).max()
    prototypes = [("/World/A/Prototypes/P", shape, ball_tris),
                  ("/World/B/Prototypes/P", (np.c_[shape, np.ones(len(shape))] @ turn)[:, :3], ball_tris),
                  ("/World/C/Prototypes/P", noisy, ball_tris)]
    instances = [(0, translate(0, 0.5, 0)), (1, np.linalg.inv(turn) @ translate(2, 0.5, 0)),
                 (2, translate(-2, 0.5, 0))]
    scene = build_scene([("/World/Floor", *grid(4, 4))], prototypes, instances)
    result = run_processor(DisplacementFields, scene, {"positional_samples": 64, "direction_map_size": 8,
                                                       "min_instances": 1})
    fields = result.products[DisplacementFieldSet].fields
    assert result.stats["rays"] == 64 * 8 * 8  # one field built
    assert "/World/B/Prototypes/P: shares the field of /World/A/Prototypes/P (same shape, rotated 90 degrees, " \
           "moved 0.374)" in result.messages
    assert "/World/C/Prototypes/P: shares the field of /World/A/Prototypes/P (same shape)" in result.messages
    attributes = {(r.prim, r.name): r.value for r in result.outputs if isinstance(r, core.Attribute)}
    a = fields["/World/A/Prototypes/P"]
    np.testing.assert_allclose(attributes["/World/B/Prototypes/P", "bake:field:center"],
                               (np.r_[a.center, 1.0] @ turn)[:3], atol=FLOAT32_STORAGE)
    # rotate_y = pi/2 turns x into -z: +90 degrees about +y, q = (cos 45, 0, sin 45, 0) (tests/geometry/
    # test_transforms.py checks the convention against Gf)
    half = np.sqrt(0.5)
    np.testing.assert_allclose(attributes["/World/B/Prototypes/P", "bake:field:orientation"],
                               [half, 0.0, half, 0.0], atol=FLOAT32_STORAGE)
    assert ("/World/A/Prototypes/P", "bake:field:orientation") not in attributes
    assert ("/World/C/Prototypes/P", "bake:field:orientation") not in attributes
    assert attributes["/World/B/Prototypes/P", "bake:field:file"] == "./displacement_fields/World_A_Prototypes_P.png"
