"""processors.daylight.patch_visibility on its own: ``compute_patch_visibility``, ``traced_rays``,
``visibility_pass_chunk`` and ``row_sums``.

- an open face, tilted or not, and in a Y-up frame: V of every patch wholly above its plane is the exact
  patch mean cosine (written here in float64 from int r dz = (z r + asin z) / 2, itself checked against a
  midpoint rule), patches wholly below get 0, the patches across its horizon the mean of max(0, cos)
  within Monte Carlo noise; nothing is partial;
- a face beside a tall wall: the patches behind the wall see nothing, those away from it everything,
  only the patches across the wall's edge are partial ("share": min of the two, "any": their sum);
- a face under a horizontal pane: each patch's V lies between the falloff at its lowest and highest
  altitude times the mean cosine;
- seeding by ``tri_ids`` and batching do not change a face's row; ``traced_rays`` counts and
  ``rays_cast``; the per-face reduction of ``visibility_pass_chunk``; ``row_sums`` against BLAS and
  bit for bit by chunks.
"""

from __future__ import annotations

import numpy as np
import pytest

from patch_scenes import quad
from tolerances import (FLOAT32_ACCUMULATED, FLOAT32_STORAGE, FLOAT64_ROUNDING, MC_SIGMAS, PATCH_MIDPOINT_RULE,
                        UINT8_HALF_STEP)
from usdbake.kernels.sky import enu_to_world, tregenza_patches, uniform_patches
from usdbake.kernels.tracer import Tracer
from usdbake.processors.daylight import patch_visibility
from usdbake.processors.daylight.glazing import Glazing, radiance_glass_transmittance
from usdbake.processors.daylight.patch_visibility import (QUANT_LEVELS, compute_patch_visibility, row_sums,
                                                          traced_rays, visibility_pass_chunk)

SAMPLES = 16
"""Rays per (face, patch) pair: a 4 x 4 stratified grid."""


def corners_normals(points, tris):
    corners = points[tris].astype(np.float64)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return corners, cross / np.linalg.norm(cross, axis=1, keepdims=True)


def tracer_over(*parts) -> Tracer:
    points, tris, start = [], [], 0
    for p, t in parts:
        points.append(p)
        tris.append(t + start)
        start += len(p)
    return Tracer(np.concatenate(points), np.concatenate(tris))


def patch_mean_cosine_np(bounds: np.ndarray, n_enu: np.ndarray) -> np.ndarray:
    """(N,) exact mean of n . w over each patch (z, azimuth uniform): w = (r sin a, r cos a, z), r = sqrt(1 - z^2)."""
    z0, z1, a0, a1 = bounds.T
    antiderivative = lambda z: 0.5 * (z * np.sqrt(np.maximum(1 - z * z, 0.0)) + np.arcsin(np.clip(z, -1, 1)))  # noqa: E731
    int_r = antiderivative(z1) - antiderivative(z0)
    integral = (n_enu[0] * int_r * (np.cos(a0) - np.cos(a1)) + n_enu[1] * int_r * (np.sin(a1) - np.sin(a0))
                + n_enu[2] * 0.5 * (z1 ** 2 - z0 ** 2) * (a1 - a0))
    return integral / ((z1 - z0) * (a1 - a0))


def patch_mean_np(bounds: np.ndarray, n_enu: np.ndarray, f=lambda c: c, steps: int = 200) -> np.ndarray:
    """(N,) midpoint rule of the patch mean of f(n . w) over steps x steps cells in (z, azimuth)."""
    t = (np.arange(steps) + 0.5) / steps
    z = bounds[:, 0, None, None] + t[None, :, None] * (bounds[:, 1] - bounds[:, 0])[:, None, None]
    a = bounds[:, 2, None, None] + t[None, None, :] * (bounds[:, 3] - bounds[:, 2])[:, None, None]
    r = np.sqrt(np.maximum(1 - z * z, 0.0))
    cos = n_enu[0] * r * np.sin(a) + n_enu[1] * r * np.cos(a) + n_enu[2] * z
    return f(cos).mean(axis=(1, 2))


def cosine_range(bounds: np.ndarray, n_enu: np.ndarray, steps: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """(N,) smallest and largest n . w over each patch (on a fine grid of its (z, azimuth) rectangle)."""
    t = np.linspace(0.0, 1.0, steps)
    z = bounds[:, 0, None, None] + t[None, :, None] * (bounds[:, 1] - bounds[:, 0])[:, None, None]
    a = bounds[:, 2, None, None] + t[None, None, :] * (bounds[:, 3] - bounds[:, 2])[:, None, None]
    r = np.sqrt(np.maximum(1 - z * z, 0.0))
    cos = n_enu[0] * r * np.sin(a) + n_enu[1] * r * np.cos(a) + n_enu[2] * z
    return cos.min(axis=(1, 2)), cos.max(axis=(1, 2))


def horizon_split(bounds: np.ndarray, n_enu: np.ndarray):
    """Patches wholly above and wholly below the plane of n."""
    low, high = cosine_range(bounds, n_enu)
    return low >= 0, high < 0


def test_the_closed_form_mean_cosine_agrees_with_a_midpoint_rule():
    bounds = tregenza_patches().patch_bounds
    n = np.array([0.3, -0.5, 0.81])
    n /= np.linalg.norm(n)
    np.testing.assert_allclose(patch_mean_cosine_np(bounds, n), patch_mean_np(bounds, n), atol=PATCH_MIDPOINT_RULE)


@pytest.mark.parametrize("normal", [(0.0, 0.0, 1.0), (1.0, 0.0, 1.0), (0.0, -1.0, 0.2)])
def test_an_open_face_sees_the_exact_mean_cosine_of_each_patch(normal):
    """A single open triangle of the given (ENU = scene frame, Z up) normal, alone in the tracer."""
    n = np.asarray(normal) / np.linalg.norm(normal)
    helper = np.cross(n, [0.3, 0.7, 0.1])
    u = helper / np.linalg.norm(helper)
    v = np.cross(n, u)
    corners = np.array([[[0, 0, 0], u, v]], np.float64)
    patches = uniform_patches(64)
    tracer = Tracer(corners.reshape(-1, 3), np.array([[0, 1, 2]]))
    vis, partial = compute_patch_visibility(tracer, corners, n[None], patches, enu_to_world("Z"), samples=SAMPLES)
    assert vis.shape == partial.shape == (1, len(patches)) and vis.dtype == np.float32
    above, below = horizon_split(patches.patch_bounds, n)
    exact = patch_mean_cosine_np(patches.patch_bounds, n)
    np.testing.assert_allclose(vis[0, above], exact[above], atol=FLOAT32_STORAGE)
    assert not vis[0, below].any()
    across = ~above & ~below
    if across.any():  # a plain Monte Carlo mean over SAMPLES rays of max(0, cos), which spans [0, high]
        clipped = patch_mean_np(patches.patch_bounds[across], n, lambda c: np.maximum(c, 0.0))
        _, high = cosine_range(patches.patch_bounds[across], n)
        assert (np.abs(vis[0, across] - clipped) <= MC_SIGMAS * 0.5 * high / np.sqrt(SAMPLES)).all()
    assert not partial.any()
    # an open face sees the sky's whole cosine-weighted hemisphere above it (pi, less what lies below the horizon)
    if not across.any():
        assert vis[0].astype(np.float64) @ patches.patch_solid_angles == pytest.approx(np.pi, rel=FLOAT32_ACCUMULATED)


def test_a_y_up_frame_maps_the_patches_onto_the_scene():
    """Y up: the scene's +y is the zenith, its -z north (enu_to_world). An open face of normal +y sees the
    mean of z; one of normal -z sees the mean of the northward component."""
    to_world = enu_to_world("Y")
    patches = uniform_patches(64)
    corners = np.array([[[0, 0, 0], [0, 0, 1], [1, 0, 0]]], np.float64)  # normal +y
    tracer = Tracer(corners.reshape(-1, 3), np.array([[0, 1, 2]]))
    vis, _ = compute_patch_visibility(tracer, corners, np.array([[0.0, 1.0, 0.0]]), patches, to_world,
                                      samples=SAMPLES)
    np.testing.assert_allclose(vis[0], patch_mean_cosine_np(patches.patch_bounds, np.array([0.0, 0.0, 1.0])),
                               atol=FLOAT32_STORAGE)
    north = to_world.T @ np.array([0.0, 0.0, -1.0])
    np.testing.assert_allclose(north, [0.0, 1.0, 0.0], atol=FLOAT64_ROUNDING)
    facing_north = np.array([[[0, 0, 0], [0, 1, 0], [1, 0, 0]]], np.float64)  # normal -z: north, Y up
    tracer = Tracer(facing_north.reshape(-1, 3), np.array([[0, 1, 2]]))
    vis, _ = compute_patch_visibility(tracer, facing_north, np.array([[0.0, 0.0, -1.0]]), patches, to_world,
                                      samples=SAMPLES)
    above, below = horizon_split(patches.patch_bounds, north)
    np.testing.assert_allclose(vis[0, above], patch_mean_cosine_np(patches.patch_bounds, north)[above],
                               atol=FLOAT32_STORAGE)
    assert not vis[0, below].any()


def wall_scene():
    """A small upward face at the origin and a wall 200 wide and 100 high in the plane y = 0.5: the sky
    north of the face (azimuth within 90 deg of north) is hidden up to ~90 deg of altitude."""
    face_points, face_tris = quad([-0.01, -0.01, 0], [0.02, 0, 0], [0, 0.02, 0])
    wall = quad([-100, 0.5, 0], [200, 0, 0], [0, 0, 100])
    return face_points, face_tris, tracer_over((face_points, face_tris), wall)


def wrapped(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def test_a_wall_hides_the_patches_behind_it_and_only_the_edge_patches_are_partial():
    points, tris, tracer = wall_scene()
    corners, normals = corners_normals(points, tris)
    patches = uniform_patches(64)
    bounds = patches.patch_bounds
    lo, hi = wrapped(bounds[:, 2]), wrapped(bounds[:, 3])
    low_sky = bounds[:, 1] < 0.99  # below ~82 deg: the wall (height / distance = 200) hides all of the north
    margin = 0.05
    north = low_sky & (lo > -np.pi / 2 + margin) & (hi < np.pi / 2 - margin) & (lo < hi)
    south = low_sky & ((lo > np.pi / 2 + margin) | (hi < -np.pi / 2 - margin) | (lo > hi)) & \
        ~((lo < np.pi / 2) & (hi > np.pi / 2)) & ~((lo < -np.pi / 2) & (hi > -np.pi / 2))
    edge = ((lo < np.pi / 2 - margin) & (hi > np.pi / 2 + margin)) | ((lo < -np.pi / 2 - margin) & (hi > -np.pi / 2 + margin))
    assert north.sum() > 5 and south.sum() > 5 and edge.sum() >= 2  # the check is not vacuous
    exact = patch_mean_cosine_np(bounds, np.array([0.0, 0.0, 1.0]))
    share, partial_share = compute_patch_visibility(tracer, corners, normals, patches, enu_to_world("Z"),
                                                    samples=SAMPLES)
    for row in range(len(corners)):
        assert not share[row, north].any() and not partial_share[row, north].any()
        np.testing.assert_allclose(share[row, south], exact[south], atol=FLOAT32_STORAGE)
        assert not partial_share[row, south].any()
        # across the edge both sides have samples: min(seen, occluded) > 0, and V + that min <= the mean cosine
        assert (partial_share[row, edge] > 0).all()
        assert (share[row, edge] > 0).all() and (share[row, edge] < exact[edge]).all()
    _, partial_any = compute_patch_visibility(tracer, corners, normals, patches, enu_to_world("Z"), samples=SAMPLES,
                                              criterion="any")
    # "any": the whole cosine-weighted share (visible + occluded = the exact mean cosine after rescaling)
    np.testing.assert_allclose(partial_any[:, edge], np.broadcast_to(exact[edge], partial_any[:, edge].shape),
                               atol=FLOAT32_STORAGE)
    assert not partial_any[:, north | south].any()


def test_a_face_under_a_pane_sees_each_patch_through_its_falloff():
    """A wide horizontal pane of VLT 0.6 above an upward face: a ray at altitude z crosses it at cos = z, so
    V_j = C_j sum T(z_k) z_k / sum z_k lies between C_j T(z_lo) and C_j T(z_hi); glass counts as seen."""
    vlt = 0.6
    face_points, face_tris = quad([0, 0, 0], [1, 0, 0], [0, 1, 0])
    pane_points, pane_tris = quad([-500, -500, 0.5], [1000, 0, 0], [0, 1000, 0])
    points = np.concatenate([face_points, pane_points])
    tris = np.concatenate([face_tris, pane_tris + len(face_points)])
    corners, normals = corners_normals(points, tris)
    glazing = Glazing(points, tris, normals, np.array([0.0, 0.0, vlt, vlt]))
    patches = uniform_patches(64)
    vis, partial = compute_patch_visibility(glazing.opaque_tracer, corners[:2], normals[:2], patches,
                                            enu_to_world("Z"), samples=SAMPLES, glazing=glazing)
    z_lo, z_hi = patches.patch_bounds[:, 0], patches.patch_bounds[:, 1]
    exact = patch_mean_cosine_np(patches.patch_bounds, np.array([0.0, 0.0, 1.0]))
    low = exact * radiance_glass_transmittance(z_lo, vlt)
    high = exact * radiance_glass_transmittance(z_hi, vlt)
    assert (vis >= low - FLOAT32_STORAGE).all() and (vis <= high + FLOAT32_STORAGE).all()
    assert not partial.any()
    opaque, _ = compute_patch_visibility(glazing.opaque_tracer, corners[:2], normals[:2], patches,
                                         enu_to_world("Z"), samples=SAMPLES)
    np.testing.assert_allclose(opaque, np.broadcast_to(exact, opaque.shape), atol=FLOAT32_STORAGE)


def test_a_faces_row_depends_on_its_id_not_its_place_or_batch(monkeypatch):
    points, tris, tracer = wall_scene()
    corners, normals = corners_normals(points, tris)
    patches = uniform_patches(64)
    args = (patches, enu_to_world("Z"))
    both, both_partial = compute_patch_visibility(tracer, corners, normals, *args, tri_ids=np.array([7, 9]))
    alone, alone_partial = compute_patch_visibility(tracer, corners[1:], normals[1:], *args, tri_ids=np.array([9]))
    np.testing.assert_array_equal(alone, both[1:])
    np.testing.assert_array_equal(alone_partial, both_partial[1:])
    monkeypatch.setattr(patch_visibility, "PAIRS_PER_BATCH", len(patches))  # one face per launch
    batched, batched_partial = compute_patch_visibility(tracer, corners, normals, *args, tri_ids=np.array([7, 9]))
    np.testing.assert_array_equal(batched, both)
    np.testing.assert_array_equal(batched_partial, both_partial)
    other_seed, _ = compute_patch_visibility(tracer, corners, normals, *args, tri_ids=np.array([7, 9]), seed=1)
    assert not np.array_equal(other_seed, both)  # the partial edge patches see other rays


def test_traced_rays_counts_the_pairs_above_the_horizon():
    patches = tregenza_patches()
    to_world = enu_to_world("Z")
    up, down = np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, -1.0]])
    assert traced_rays(up, patches, to_world, 16) == len(patches) * 16
    # a downward face: only the lowest ring (12 deg high, reaching the horizon) is not wholly below it
    lowest_ring = int((patches.patch_bounds[:, 0] <= 0.0).sum())
    assert lowest_ring == 30
    assert traced_rays(down, patches, to_world, 16) == lowest_ring * 16
    # samples round to the nearest square
    assert traced_rays(up, patches, to_world, 7) == len(patches) * 9
    assert traced_rays(up, patches, to_world, 5) == len(patches) * 4
    assert traced_rays(np.concatenate([up, down]), patches, to_world, 1) == len(patches) + lowest_ring
    assert traced_rays(np.zeros((1, 3)), patches, to_world, 16) == 0  # a degenerate face casts nothing


def test_compute_patch_visibility_adds_its_rays_to_the_tracer():
    points, tris, tracer = wall_scene()
    corners, normals = corners_normals(points, tris)
    patches = tregenza_patches()
    before = tracer.rays_cast
    compute_patch_visibility(tracer, corners, normals, patches, enu_to_world("Z"), samples=4)
    assert tracer.rays_cast - before == 2 * len(patches) * 4


@pytest.mark.parametrize("criterion", ["share", "any", "paper"])
def test_visibility_pass_chunk_reduces_each_face(criterion):
    points, tris, tracer = wall_scene()
    corners, normals = corners_normals(points, tris)
    patches = uniform_patches(64)
    to_world = enu_to_world("Z")
    ids = np.array([3, 4], np.int32)
    quantized, exposure, quant_error, score = visibility_pass_chunk(
        tracer, 0, corners, normals, ids, patches=patches, to_world=to_world, samples=SAMPLES, seed=0,
        criterion=criterion)
    vis, part = compute_patch_visibility(tracer, corners, normals, patches, to_world, samples=SAMPLES, tri_ids=ids,
                                         criterion="any" if criterion == "paper" else criterion)
    solid = patches.patch_solid_angles
    assert quantized.dtype == np.uint8 and quantized.shape == vis.shape
    assert (np.abs(quantized / QUANT_LEVELS - vis) <= UINT8_HALF_STEP + FLOAT32_STORAGE).all()
    np.testing.assert_allclose(exposure, vis.astype(np.float64) @ solid / np.pi, rtol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(quant_error, np.abs((quantized / QUANT_LEVELS - vis) @ solid) / np.pi,
                               atol=FLOAT64_ROUNDING)
    assert (quant_error <= UINT8_HALF_STEP * 2.0 + FLOAT64_ROUNDING).all()  # half a step over 2 pi sr, / pi
    if criterion == "paper":  # the largest n . c over the partly visible patches
        cosines = normals @ (patches.patch_directions @ to_world.T).T
        expected = np.array([cosines[i, part[i] > 0].max() for i in range(2)])
        np.testing.assert_allclose(score, expected, atol=FLOAT64_ROUNDING)
    else:
        expected = (2.0 if criterion == "share" else 1.0) / np.pi * part.astype(np.float64) @ solid
        np.testing.assert_allclose(score, expected, rtol=FLOAT64_ROUNDING)
    assert (score > 0).all()  # the wall's edge patches are partial for both faces


def test_row_sums_match_blas_and_repeat_bit_for_bit_by_chunks():
    rng = np.random.default_rng(5)  # any values; the sums are compared, not drawn
    values = rng.random((257, 145)).astype(np.float32)
    weights = rng.random(145)
    total = row_sums(values, weights)
    assert total.dtype == np.float64 and total.shape == (257,)
    np.testing.assert_allclose(total, values.astype(np.float64) @ weights, rtol=FLOAT64_ROUNDING)
    for lo, hi in ((0, 1), (3, 70), (100, 257)):
        np.testing.assert_array_equal(row_sums(values[lo:hi], weights), total[lo:hi])
    # (T, K, 1) values with (K, N) weights: sum_k values[:, k] * weights[k], a (T, N) result
    normals = rng.normal(size=(9, 3))
    centers = rng.normal(size=(3, 145))
    np.testing.assert_allclose(row_sums(normals[:, :, None], centers), normals @ centers, atol=FLOAT64_ROUNDING)
    assert row_sums(np.zeros((0, 4)), np.ones(4)).shape == (0,)
