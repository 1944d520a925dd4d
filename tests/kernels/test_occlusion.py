"""kernels.occlusion: the AO ray settings, the ray directions (cosine-weighted about the normal, against
the moments of pdf cos(theta)/pi; one ray per cell of the strata grid) and the launch helper, with a
test kernel of its own."""

import math

import numpy as np
import pytest
import warp as wp
from kernel_twins import malley_direction_to_square_np
from tolerances import FLOAT32_STORAGE, MC_SIGMAS
from usdbake.kernels.occlusion import AORays, ao_direction, ao_point, ao_rays, as_points_and_normals, launch_ao, stratum_table
from usdbake.kernels.tracer import FAR, Tracer

SAMPLES = 64


@pytest.fixture(scope="module")
def tracer():
    return Tracer(np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.int32([[0, 1, 2]]), threads=1)


@wp.kernel
def directions_kernel(start: int, rays: AORays, normals: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    i = start + wp.tid()
    point = ao_point(rays, normals[i], i)
    for k in range(rays.strata * rays.strata):
        out[i * rays.strata * rays.strata + k] = ao_direction(rays, point, k)


@wp.kernel
def cos_mean_kernel(start: int, rays: AORays, normals: wp.array(dtype=wp.vec3), ao: wp.array(dtype=float)):
    i = start + wp.tid()
    point = ao_point(rays, normals[i], i)
    total = float(0.0)
    for k in range(rays.strata * rays.strata):
        total += wp.dot(ao_direction(rays, point, k), normals[i])
    ao[i] = total / float(rays.strata * rays.strata)


def directions(tracer, normals, *, seed=3):
    rays = ao_rays(tracer.scene, samples=SAMPLES, max_distance=np.inf, epsilon=1e-4, seed=seed)
    out = wp.zeros(len(normals) * SAMPLES, dtype=wp.vec3, device="cpu")
    tracer.launch(directions_kernel, len(normals), [rays, tracer.array(np.float32(normals), wp.vec3), out])
    return out.numpy().reshape(len(normals), SAMPLES, 3).astype(np.float64)


def test_ao_rays_round_samples_to_a_square_and_cap_the_distance(tracer):
    rays = ao_rays(tracer.scene, samples=50, max_distance=np.inf, epsilon=0.25, seed=9)
    assert (rays.strata, rays.max_distance, rays.epsilon, rays.seed) == (7, FAR, 0.25, 9)
    assert ao_rays(tracer.scene, samples=0, max_distance=2.0, epsilon=0.0, seed=0).strata == 1
    assert ao_rays(tracer.scene, samples=1, max_distance=2.0, epsilon=0.0, seed=0).max_distance == 2.0


def test_directions_are_unit_and_cosine_distributed_about_the_normal(tracer):
    normals = np.array([[0, 0, 1], [1, 0, 0], [0, -0.6, 0.8], [0, 0, -1]] * 64, np.float64)
    d = directions(tracer, normals)
    np.testing.assert_allclose(np.linalg.norm(d, axis=2), 1.0, atol=FLOAT32_STORAGE)
    cosines = np.einsum("psk,pk->ps", d, normals)
    assert (cosines >= -FLOAT32_STORAGE).all()
    # pdf cos(theta)/pi: E[cos] = 2/3, E[cos^2] = 1/2 (variance 1/18), E[tangent components] = 0.
    count = cosines.size
    assert abs(cosines.mean() - 2 / 3) < MC_SIGMAS * math.sqrt(1 / 18 / count)
    assert abs((cosines ** 2).mean() - 0.5) < MC_SIGMAS * math.sqrt((1 / 3 - 1 / 4) / count)  # E[cos^4] = 1/3
    up = d[normals[:, 2] == 1].reshape(-1, 3)
    assert np.abs(up[:, :2].mean(axis=0)).max() < MC_SIGMAS * math.sqrt(1 / 6 / len(up))  # E[x^2] = (1 - 1/2) / 2


def test_rays_depend_on_the_seed_and_the_point_only(tracer):
    d = directions(tracer, np.array([[0, 0, 1]] * 4, np.float64))
    assert not np.array_equal(d[0], d[1])  # each point its own jitter
    np.testing.assert_array_equal(d, directions(tracer, np.array([[0, 0, 1]] * 4, np.float64)))
    assert not np.array_equal(d, directions(tracer, np.array([[0, 0, 1]] * 4, np.float64), seed=4))


def test_ray_k_lies_in_cell_k_of_the_grid(tracer):
    """Stratification: mapped back to the unit square (the inverse of the concentric map and Malley's lift, in
    the frame of the normal), ray k of every point falls in cell k (column k % strata, row k // strata); its
    place in the cell differs from point to point and is uniform over them."""
    strata = int(math.isqrt(SAMPLES))
    d = directions(tracer, np.array([[0, 0, 1]] * 50, np.float64))  # tangent_frame of +z: x and y themselves
    u = malley_direction_to_square_np(d.reshape(-1, 3)).reshape(50, SAMPLES, 2)
    k = np.arange(SAMPLES)
    inside = 1e-4  # float32 directions, inverted in float64, at a cell's edge
    assert (u[..., 0] >= (k % strata) / strata - inside).all() and (u[..., 0] <= (k % strata + 1) / strata + inside).all()
    assert (u[..., 1] >= (k // strata) / strata - inside).all() and (u[..., 1] <= (k // strata + 1) / strata + inside).all()
    within = np.mod(u * strata, 1.0)  # the jitter inside the cell: one per point, not one pattern for all
    assert np.ptp(within[..., 0], axis=0).min() > 0.5 and np.ptp(within[..., 1], axis=0).min() > 0.5
    assert abs(within.mean() - 0.5) < MC_SIGMAS * math.sqrt(1 / 12 / within.size)


def test_the_cell_table_holds_each_cells_corner():
    table = stratum_table(3).astype(np.float64)
    np.testing.assert_allclose(table, np.stack([np.tile([0, 1, 2], 3), np.repeat([0, 1, 2], 3)], 1) / 3, atol=1e-7)


def test_launch_ao_returns_the_kernel_output_and_counts_the_rays(tracer):
    normals = np.float32([[0, 0, 1], [0, 1, 0], [1, 0, 0]])
    rays = ao_rays(tracer.scene, samples=16, max_distance=1.0, epsilon=1e-4, seed=1)
    before = tracer.rays_cast
    means = launch_ao(tracer, cos_mean_kernel, 3, rays, [tracer.array(normals, wp.vec3)])
    assert means.shape == (3,) and means.dtype == np.float32
    assert (np.abs(means - 2 / 3) < MC_SIGMAS * math.sqrt(1 / 18 / 16)).all()  # mean cosine of 16 rays
    assert tracer.rays_cast - before == 3 * 16


def test_points_and_normals_are_made_float32_rows_of_three():
    points, normals = as_points_and_normals(np.arange(6.0), [[0, 0, 1], [0, 1, 0]])
    assert points.shape == normals.shape == (2, 3) and points.dtype == normals.dtype == np.float32
    assert points.flags.c_contiguous
    with pytest.raises(ValueError, match="differ"):
        as_points_and_normals(np.zeros((2, 3)), np.zeros((3, 3)))
