"""form_factors: patches, form factors against closed forms, the multi-bounce operator, compression."""

import dataclasses
import math

import numpy as np
import pytest
from tolerances import (BOUNCE_ENERGY, CATALOG_FORM_FACTOR, CLOSED_BOX_ESCAPES, FLOAT32_ACCUMULATED, FLOAT32_LONG_CHAIN,
                        FLOAT32_ROUNDING, FLOAT32_STORAGE, MC_SIGMAS, RECIPROCITY_FACE_SUMS, RECIPROCITY_FLOOR,
                        RELIGHT_TOLERANCE)
from usdbake.core import File, Prim
from usdbake.processors.radiosity.products import FormFactorProduct
from patch_scenes import box_parts, make_scene, quad
from usdbake.processors.radiosity import patches as geo_patches
from usdbake.processors.radiosity import operator_codec as codec
from usdbake.processors.radiosity.operator_relight import COMPRESSED, DENSE, OperatorRelighter, relight_indirect
from usdbake.kernels.tracer import Tracer
from usdbake.processors.radiosity import form_factors as ff

# ---------------------------------------------------------------------------
# Scene helpers (also used by test_radiosity)








def form_factors_of(scene, *, voxel, rays, seed=0):
    tracer = Tracer.from_scene(scene)
    patches = geo_patches.build_patches(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas,
                                        scene.tri_albedo, scene.tri_emission, voxel_size=voxel)
    return patches, ff.compute_form_factors(tracer, patches, scene.tri_normals, rays=rays, seed=seed)


# ---------------------------------------------------------------------------
# Closed forms (Howell's catalog of radiation configuration factors, C-11 and C-14)


def parallel_rectangles(a, b, c):
    """F between directly opposed parallel a x b rectangles at distance c."""
    x, y = a / c, b / c
    return 2 / (math.pi * x * y) * (
        0.5 * math.log((1 + x * x) * (1 + y * y) / (1 + x * x + y * y))
        + x * math.sqrt(1 + y * y) * math.atan(x / math.sqrt(1 + y * y))
        + y * math.sqrt(1 + x * x) * math.atan(y / math.sqrt(1 + x * x)) - x * math.atan(x) - y * math.atan(y))


def perpendicular_rectangles(h, w):
    """F from a rectangle (w along the shared edge... normalized: H = h/l, W = w/l) to a perpendicular one."""
    a = (1 + w * w) * (1 + h * h) / (1 + w * w + h * h)
    b = (w * w * (1 + w * w + h * h) / ((1 + w * w) * (w * w + h * h))) ** (w * w)
    c = (h * h * (1 + h * h + w * w) / ((1 + h * h) * (h * h + w * w))) ** (h * h)
    return 1 / (math.pi * w) * (w * math.atan(1 / w) + h * math.atan(1 / h)
                                - math.sqrt(h * h + w * w) * math.atan(1 / math.sqrt(h * h + w * w))
                                + 0.25 * math.log(a * b * c))


RAYS_CLOSED_FORM = 16384
FF_TOLERANCE = MC_SIGMAS * math.sqrt(0.2 * 0.8 / RAYS_CLOSED_FORM)
"""MC_SIGMAS standard deviations of a binomial hit share near F = 0.2 with 16384 rays (0.0125); the
stratification makes the real spread smaller (measured errors 0.0010 to 0.0015)."""


def test_parallel_unit_squares_match_closed_form():
    bottom = quad([0, 0, 0], [1, 0, 0], [0, 1, 0])  # normal +z
    top = quad([0, 0, 1], [0, 1, 0], [1, 0, 0])  # normal -z
    scene = make_scene([bottom, top])
    patches, form = form_factors_of(scene, voxel=4.0, rays=RAYS_CLOSED_FORM)
    assert patches.count == 2
    expected = parallel_rectangles(1, 1, 1)
    assert abs(expected - 0.19982) < CATALOG_FORM_FACTOR  # the catalog value
    np.testing.assert_allclose([form[0, 1], form[1, 0]], expected, atol=FF_TOLERANCE)
    assert form[0, 0] == 0 and form[1, 1] == 0


def test_perpendicular_unit_squares_match_closed_form():
    floor = quad([0, 0, 0], [1, 0, 0], [0, 1, 0])  # z = 0, normal +z
    wall = quad([0, 0, 0], [0, 0, 1], [1, 0, 0])  # y = 0, normal +y, shares the edge along x
    scene = make_scene([floor, wall])
    _, form = form_factors_of(scene, voxel=4.0, rays=RAYS_CLOSED_FORM)
    expected = perpendicular_rectangles(1.0, 1.0)
    assert abs(expected - 0.20004) < CATALOG_FORM_FACTOR
    np.testing.assert_allclose([form[0, 1], form[1, 0]], expected, atol=FF_TOLERANCE)


def test_closed_box_rows_sum_to_one_and_reciprocity_holds():
    scene = make_scene(box_parts(grid=2))
    patches, form = form_factors_of(scene, voxel=0.34, rays=4096)
    checks = ff.form_factor_checks(form, patches.patch_areas)
    assert checks["row_sum_min"] > 1 - CLOSED_BOX_ESCAPES  # every ray from inside a closed box lands somewhere
    assert checks["row_sum_max"] <= 1.0 + FLOAT32_STORAGE
    flux = form * patches.patch_areas[:, None]
    # Reciprocity: A_i F_ij = A_j F_ji. Pairwise values are noisy; face-to-face sums are not.
    face = np.abs(patches.patch_normals).argmax(1) * 2 + (patches.patch_normals.sum(1) < 0)
    groups = np.zeros((6, 6))
    np.add.at(groups, (face[:, None].repeat(len(face), 1), face[None, :].repeat(len(face), 0)), flux)
    np.testing.assert_allclose(groups, groups.T, rtol=RECIPROCITY_FACE_SUMS, atol=RECIPROCITY_FLOOR)
    more_rays = ff.form_factor_checks(form_factors_of(scene, voxel=0.34, rays=16384)[1], patches.patch_areas)
    assert more_rays["reciprocity_error"] < checks["reciprocity_error"]  # MC noise shrinks with rays


def test_patches_cover_the_surface_and_map_hits_to_fragments():
    scene = make_scene(box_parts(size=2.0))
    patches = geo_patches.build_patches(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas,
                                        scene.tri_albedo, scene.tri_emission, voxel_size=0.5)
    np.testing.assert_allclose(patches.patch_areas.sum(), 24.0, rtol=FLOAT32_ACCUMULATED)
    assert (patches.tri_subdivision > 1).all()  # 2.8-long triangles split at voxel 0.5
    np.testing.assert_allclose(np.linalg.norm(patches.patch_normals, axis=1), 1.0, rtol=FLOAT32_ACCUMULATED)
    # Rays straight down onto the floor at fragment centres hit those fragments' patches.
    tracer = Tracer.from_scene(scene)
    floor_frag = np.flatnonzero(scene.tri_normals[patches.fragment_tri][:, 2] > 0.5)
    centres = patches.fragment_vertices[floor_frag].mean(axis=1)
    hits = tracer.closest_hit(centres + [0, 0, 1.0], np.tile([0, 0, -1.0], (len(centres), 1)))
    import warp as wp
    from usdbake.processors.radiosity.patch_kernels import fragment_of_hit

    @wp.kernel
    def lookup(face: wp.array(dtype=int), uv: wp.array(dtype=wp.vec2), sub: wp.array(dtype=int),
               first: wp.array(dtype=int), out: wp.array(dtype=int)):
        i = wp.tid()
        out[i] = fragment_of_hit(face[i], uv[i][0], uv[i][1], sub, first)

    out = wp.zeros(len(centres), dtype=int)
    wp.launch(lookup, len(centres), [wp.array(hits.hit_triangle, dtype=int), wp.array(hits.hit_uv, dtype=wp.vec2),
                                     wp.array(patches.tri_subdivision, dtype=int),
                                     wp.array(patches.tri_fragment_start, dtype=int), out])
    np.testing.assert_array_equal(out.numpy(), floor_frag)


def test_voxel_size_is_chosen_for_the_target_count():
    scene = make_scene(box_parts(grid=3))
    voxel = geo_patches.choose_voxel_size(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas, 600)
    count = geo_patches.count_patches(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas, voxel)
    assert 400 < count < 900


# ---------------------------------------------------------------------------
# Multi-bounce operator


def test_closed_box_bounce_energy_is_albedo_powers():
    # Closed box, uniform albedo rho: each bounce returns rho times the power it received, so the
    # indirect power is P0 (rho + rho^2 + rho^3) for k = 3 -- and never more than the incident power
    # times rho / (1 - rho) (energy conservation).
    rho = 0.6
    scene = make_scene(box_parts(grid=2), albedo=(rho, rho, rho))
    patches, form = form_factors_of(scene, voxel=0.34, rays=4096)
    operator = ff.multibounce_operator(form, patches.patch_albedo, bounces=3)
    rng = np.random.default_rng(5)  # fixed seed: an arbitrary non-negative direct light
    e0 = rng.uniform(0, 1, (patches.count, 3)).astype(np.float32)
    indirect = np.einsum("cij,jc->ic", operator, e0)
    p0 = (patches.patch_areas[:, None] * e0).sum(0)
    p_ind = (patches.patch_areas[:, None] * indirect).sum(0)
    np.testing.assert_allclose(p_ind, p0 * (rho + rho ** 2 + rho ** 3), rtol=BOUNCE_ENERGY)
    infinite = ff.multibounce_operator(form, patches.patch_albedo, infinite=True)
    p_inf = (patches.patch_areas[:, None] * np.einsum("cij,jc->ic", infinite, e0)).sum(0)
    assert (p_inf <= p0 * rho / (1 - rho) * (1 + BOUNCE_ENERGY)).all() and (p_inf > p_ind).all()


def test_infinite_closed_form_equals_a_long_series():
    rng = np.random.default_rng(6)  # fixed seed: a random sub-stochastic matrix
    form = rng.uniform(0, 1, (30, 30)).astype(np.float32)
    form /= form.sum(1, keepdims=True) * 1.1
    albedo = rng.uniform(0.2, 0.8, (30, 3)).astype(np.float32)
    np.testing.assert_allclose(ff.multibounce_operator(form, albedo, infinite=True),
                               ff.multibounce_operator(form, albedo, bounces=80),
                               rtol=FLOAT32_LONG_CHAIN, atol=FLOAT32_STORAGE)


# ---------------------------------------------------------------------------
# Compression


@pytest.fixture(scope="module")
def box_operator():
    albedo = np.array([[0.7, 0.5, 0.3]] * 6, np.float32)
    albedo[2] = [0.2, 0.7, 0.3]
    scene = make_scene(box_parts(grid=2), albedo=albedo)
    patches, form = form_factors_of(scene, voxel=0.1, rays=256)
    return patches, ff.multibounce_operator(form, patches.patch_albedo, bounces=3)


def test_compression_keeps_top_entries_exact_and_is_small(box_operator):
    patches, operator = box_operator
    n = patches.count
    compressed = codec.compress_operator(operator)
    assert compressed.stats["memory_ratio"] <= 1 / 8
    assert sorted(compressed.permutation) == list(range(n))
    perm = compressed.permutation
    stored = np.moveaxis(operator, 0, -1)[np.ix_(perm, perm)]
    decoded = np.moveaxis(codec.decompress_operator(compressed), 0, -1)[np.ix_(perm, perm)]
    rows = np.repeat(np.arange(n), np.diff(compressed.sparse_indptr))
    exact = np.zeros((n, n), bool)
    exact[rows, compressed.sparse_indices] = True
    # The exact part holds the top 4 % (and the entries the BC1 part missed by more than MAX_ERROR):
    # texel + exact value = the operator there.
    top = stored.max(-1) >= np.sort(stored.max(-1).ravel())[-int(round(0.04 * n * n))]
    assert exact[top].all()
    assert exact.sum() - top.sum() == compressed.stats["promoted_entries"]
    np.testing.assert_allclose(decoded[exact], stored[exact], rtol=FLOAT32_ROUNDING, atol=FLOAT32_ROUNDING)
    # Every coded entry decodes within MAX_ERROR of the largest coded value (after the row correction).
    vmax = compressed.stats["residual_max"]
    assert np.abs(decoded[~exact] - stored[~exact]).max() <= codec.MAX_ERROR * vmax * (1 + FLOAT32_ACCUMULATED)
    assert compressed.stats["corrected_error_max"] <= codec.MAX_ERROR * (1 + FLOAT32_ACCUMULATED)


@pytest.mark.parametrize("quantization", ["log", "linear"])
def test_compressed_relight_matches_dense_and_permutation_is_consistent(box_operator, quantization):
    patches, operator = box_operator
    rng = np.random.default_rng(7)  # fixed seed: arbitrary light
    e0 = np.zeros((patches.count, 3), np.float32)
    e0[patches.patch_normals[:, 2] < -0.5] = rng.uniform(0.5, 1.5, 3)  # ceiling lit
    dense = np.einsum("cij,jc->ic", operator, e0)
    results = {}
    for passes in (0, 2):
        compressed = codec.compress_operator(operator, reorder_passes=passes, quantization=quantization)
        relit = relight_indirect(compressed, e0)
        # Both run-time forms (the Warp kernel decoding blocks, BLAS on the dense decode) equal the
        # numpy decode of the same data.
        decoded = np.einsum("cij,jc->ic", codec.decompress_operator(compressed), e0)
        for form in (COMPRESSED, DENSE):
            np.testing.assert_allclose(OperatorRelighter(compressed, form=form).apply(e0), decoded,
                                       rtol=FLOAT32_LONG_CHAIN, atol=FLOAT32_ROUNDING)
        error = np.sqrt(np.mean((relit - dense) ** 2) / np.mean(dense ** 2))
        assert error < RELIGHT_TOLERANCE, (passes, error)
        results[passes] = relit
    # With and without reordering the answer is the same light in patch order.
    np.testing.assert_allclose(results[0], results[2], rtol=0, atol=RELIGHT_TOLERANCE * 2 * np.abs(dense).max())


def test_reordering_lowers_the_summed_error(box_operator):
    _, operator = box_operator
    none = codec.compress_operator(operator, reorder_passes=0, row_correction=False).stats
    two = codec.compress_operator(operator, reorder_passes=2, row_correction=False).stats
    assert two["error_sum"] < none["error_sum"]


def test_greedy_order_groups_similar_rows():
    rng = np.random.default_rng(8)  # fixed seed: two row families, shuffled
    base = np.stack([np.zeros(16), np.full(16, 100)])
    labels = rng.permutation(np.repeat([0, 1], 10))
    rows = base[labels] + rng.integers(0, 10, (20, 16))
    order = codec.greedy_order(rows)
    assert sorted(order) == list(range(20))
    assert np.count_nonzero(np.diff(labels[order])) == 1  # one switch between the families


def plain_greedy(signatures: np.ndarray) -> np.ndarray:
    """The greedy pass written plainly: from item 0, the nearest (L1) remaining item, the lowest index on ties."""
    n = len(signatures)
    remaining, order, current = list(range(1, n)), [0], 0
    while remaining:
        dist = [int(np.abs(signatures[j] - signatures[current]).sum()) for j in remaining]
        current = remaining.pop(int(np.argmin(dist)))  # argmin: the first of the equal ones, remaining is sorted
        order.append(current)
    return np.array(order)


def test_greedy_order_equals_the_plain_greedy_with_ties():
    rng = np.random.default_rng(12)  # fixed: few values, so many rows are equally near
    rows = rng.integers(0, 3, (150, 5))
    np.testing.assert_array_equal(codec.greedy_order(rows), plain_greedy(rows))
    big = rng.integers(0, 48_961, (60, 256))  # column-group code sums of 16k patches (765 x 64 at most)
    np.testing.assert_array_equal(codec.greedy_order(big), plain_greedy(big))


# ---------------------------------------------------------------------------
# Processor


def test_processor_outputs_patch_prim_and_files(tmp_path):
    from usdbake.core import Context

    scene = make_scene(box_parts(grid=2))
    proc = ff.FormFactors()
    params = ff.FormFactors.Params(target_patches=150, rays=64)
    result = proc.run(Context(scene=scene, params=params, tracer=Tracer.from_scene(scene)))
    product = result.products[FormFactorProduct]
    assert 100 < product.patches.count < 220
    prims = [r for r in result.outputs if isinstance(r, Prim)]
    assert any(r.type_name == "RadiosityPatches" and r.path == ff.PATCHES_PRIM for r in prims)
    files = {r.path: r.data for r in result.outputs if isinstance(r, File)}
    dds_name = next(name for name in files if name.endswith(".dds"))
    from usdbake.processors.radiosity import dds

    blocks, width, height = dds.read_dds_bc1(files[dds_name])
    np.testing.assert_array_equal(blocks, product.operator.blocks)
    assert width == height == product.operator.padded
    names = {r.name for r in result.outputs if getattr(r, "prim", None) == ff.PATCHES_PRIM}
    assert {"centroids", "normals", "areas", "albedo", "trianglePatch", "matrixFile", "sparseFile", "bounces",
            "quantizationScale", "quantizationOffset", "permutation"} <= names
    assert result.stats["row_sum_min"] > 1 - CLOSED_BOX_ESCAPES


def test_bad_params_are_rejected():
    from usdbake.core import ParamError

    with pytest.raises(ParamError):
        ff.FormFactors.Params(exact_fraction=1.5)
    with pytest.raises(ParamError):
        ff.FormFactors.Params(quantization="cubic")
    with pytest.raises(ParamError):
        ff.FormFactors.Params(reorder_passes=3)


def test_degenerate_triangles_do_not_break_patches():
    parts = box_parts()
    degenerate = (np.array([[0.5, 0.5, 0.5]] * 3), np.array([[0, 1, 2]]))
    scene = make_scene([*parts, degenerate])
    patches, form = form_factors_of(scene, voxel=0.5, rays=64)
    assert np.isfinite(form).all() and np.isfinite(patches.patch_centroids).all()
    assert patches.tri_patch[-1] == -1


def test_too_fine_voxels_are_refused_with_a_message():
    scene = make_scene(box_parts(size=100.0))
    with pytest.raises(ValueError, match="voxel_size=0.01"):
        geo_patches.build_patches(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas,
                                  scene.tri_albedo, scene.tri_emission, voxel_size=0.01)


# ---------------------------------------------------------------------------
# Instanced layouts (issue 27): instances share patches, the count keeps to target_patches


def spheres_on_a_floor(per_side: int, *, writable: bool = False):
    """An 8 x 8 floor (the receiver) under per_side^2 instances of a 0.2-radius icosphere (80 triangles)."""
    from instanced_scenes import build_scene, grid, icosphere, translate

    sphere, triangles = icosphere(1)
    ticks = (np.arange(per_side) + 0.5) / per_side * 8.0 - 4.0
    instances = [(0, translate(x, 0.2, z, scale=(0.2, 0.2, 0.2))) for x in ticks for z in ticks]
    scene = build_scene([("/World/Floor", *grid(4.0, 4))], [("/World/Proto/Sphere", sphere, triangles)], instances)
    if writable:  # the same spheres as ordinary meshes: receivers, patches of their own
        scene = dataclasses.replace(scene, prim_writable=np.ones(len(scene.prim_paths), bool))
    return scene


@pytest.mark.parametrize("per_side", [4, 8])
def test_instances_share_patches_and_the_count_keeps_to_the_target(per_side):
    scene = spheres_on_a_floor(per_side)
    params = ff.FormFactors.Params(target_patches=60, rays=16)
    product, dense = ff.precompute(Tracer.from_scene(scene), scene, params)
    patches = product.patches
    assert 0.6 * 60 <= patches.count <= 1.5 * 60  # 16 or 64 spheres: per-prim patches would be >= 96 / 384
    instance = scene.tri_instance[patches.fragment_tri] >= 0
    mixed = np.intersect1d(patches.fragment_patch[instance], patches.fragment_patch[~instance])
    assert mixed.size == 0  # the floor's patches hold the floor only
    spans = [np.unique(scene.tri_instance[patches.fragment_tri[patches.fragment_patch == k]]).size
             for k in np.unique(patches.fragment_patch[instance])]
    assert max(spans) > 1  # a patch spans instances
    assert dense["form"].sum(axis=1).max() <= 1.0 + FLOAT32_ACCUMULATED


def test_receiver_meshes_keep_patches_of_their_own():
    """The same spheres as writable meshes receive radiosity's output: a patch never spans two of them
    (so the target cannot be reached: at least one patch per sphere and normal axis)."""
    scene = spheres_on_a_floor(4, writable=True)
    product, _ = ff.precompute(Tracer.from_scene(scene), scene, ff.FormFactors.Params(target_patches=60, rays=16))
    patches = product.patches
    owners = [np.unique(scene.tri_prim[patches.fragment_tri[patches.fragment_patch == k]]).size
              for k in range(patches.count)]
    assert max(owners) == 1 and patches.count >= 6 * 16
