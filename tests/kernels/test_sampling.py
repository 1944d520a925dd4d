"""The sampling maps in processors/kernels/sampling.py: properties of the numpy
twins (hypothesis), their moments under uniform inputs (closed forms), and
agreement of the Warp functions with the twins."""

import math

import numpy as np
import warp as wp
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from tolerances import (POLYNOMIAL_SIN_COS, FINITE_DIFFERENCE, FLOAT32_STORAGE, FLOAT32_WARP_MATH, FLOAT64_ROUNDING, MC_SIGMAS,
                        MIDPOINT_MOMENT_FACTOR, MIDPOINT_RIM_FACTOR)
from kernel_twins import concentric_disk_np, cosine_hemisphere_np
from usdbake.kernels.sampling import cosine_hemisphere, sin_cos, stratified_pair, tangent_frame, triangle_point

wp.set_module_options({"enable_backward": False})

GRID = 1024
"""Side of the grid of cell centres over [0,1)^2 used as a deterministic uniform input."""

UNIT = st.floats(min_value=0.0, max_value=1.0, exclude_max=True, allow_nan=False)
"""A uniform input of the maps: [0, 1)."""

PROPERTY = settings(derandomize=True, deadline=None)
"""Hypothesis with a fixed seed sequence (reproducible like the fixed seeds elsewhere); no deadline, since the
first Warp example may load a module."""

POLY_MOMENT_TOL = MIDPOINT_MOMENT_FACTOR / GRID**2
"""Midpoint rule on the grid: polynomial moments of r (see MIDPOINT_MOMENT_FACTOR)."""

Z_MOMENT_TOL = MIDPOINT_RIM_FACTOR * GRID**-1.5
"""Midpoint rule on the grid: E[z], singular at the disk's rim (see MIDPOINT_RIM_FACTOR)."""


@wp.kernel
def eval_sampling_kernel(
    u: wp.array(dtype=wp.vec2),
    n: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    frames: wp.array(dtype=wp.mat33),
):
    """Evaluate cosine_hemisphere(u) and tangent_frame(n) for each row (test-only)."""
    i = wp.tid()
    directions[i] = cosine_hemisphere(u[i][0], u[i][1])
    frames[i] = tangent_frame(n[i])


def eval_warp(u: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) inputs and (N, 3) normals -> (N, 3) directions and (N, 3, 3) frames, via Warp on the CPU."""
    count = len(u)
    directions = wp.zeros(count, dtype=wp.vec3, device="cpu")
    frames = wp.zeros(count, dtype=wp.mat33, device="cpu")
    wp.launch(eval_sampling_kernel, dim=count, device="cpu", inputs=[
        wp.array(np.asarray(u, np.float32), dtype=wp.vec2, device="cpu"),
        wp.array(np.asarray(n, np.float32), dtype=wp.vec3, device="cpu"), directions, frames])
    return directions.numpy(), frames.numpy()


def grid_inputs(side: int = GRID) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres of a side x side grid over [0,1)^2, flattened to two (side^2,) arrays."""
    centres = (np.arange(side) + 0.5) / side
    u1, u2 = np.meshgrid(centres, centres)
    return u1.ravel(), u2.ravel()


# -- concentric disk -------------------------------------------------------------------------------------------


@PROPERTY
@given(UNIT, UNIT)
def test_concentric_disk_lands_in_unit_disk_at_chebyshev_radius(u1, u2):
    # The concentric map sends the square of Chebyshev radius r (in [-1,1]^2) onto the circle of radius r.
    d = concentric_disk_np(np.array([u1]), np.array([u2]))[0]
    chebyshev = max(abs(2 * u1 - 1), abs(2 * u2 - 1))
    np.testing.assert_allclose(np.hypot(*d), chebyshev, rtol=0, atol=FLOAT64_ROUNDING)
    assert np.hypot(*d) <= 1.0 + FLOAT64_ROUNDING


@PROPERTY
@given(UNIT, UNIT)
def test_concentric_disk_jacobian_is_pi(u1, u2):
    """Area preservation, pointwise: [0,1)^2 (area 1) onto the unit disk (area pi) with |det J| = pi."""
    a, b = 2 * u1 - 1, 2 * u2 - 1
    step = 1e-6
    # The map is smooth inside each wedge; keep the finite-difference stencil off the wedge seams and the centre.
    assume(abs(abs(a) - abs(b)) > 1e-4 and max(abs(a), abs(b)) > 1e-3 and step < u1 < 1 - step and step < u2 < 1 - step)
    du1 = (concentric_disk_np(np.array([u1 + step]), np.array([u2])) -
           concentric_disk_np(np.array([u1 - step]), np.array([u2])))[0] / (2 * step)
    du2 = (concentric_disk_np(np.array([u1]), np.array([u2 + step])) -
           concentric_disk_np(np.array([u1]), np.array([u2 - step])))[0] / (2 * step)
    det = du1[0] * du2[1] - du1[1] * du2[0]
    # Central differences in float64: truncation O(step^2 * d''') ~1e-12, cancellation ~1e-16/step ~1e-10.
    np.testing.assert_allclose(abs(det), math.pi, rtol=FINITE_DIFFERENCE)


def test_concentric_disk_grid_moments_match_uniform_disk():
    # Uniform on the unit disk: E[r^2] = 1/2, E[r^4] = 1/3, E[x^2] = 1/4, E[x^4] = 1/8, E[x^2 y^2] = 1/24.
    d = concentric_disk_np(*grid_inputs())
    x, y = d[:, 0], d[:, 1]
    r2 = x * x + y * y
    moments = [r2.mean(), (r2 * r2).mean(), (x * x).mean(), (y * y).mean(), (x**4).mean(), (x * x * y * y).mean()]
    np.testing.assert_allclose(moments, [1 / 2, 1 / 3, 1 / 4, 1 / 4, 1 / 8, 1 / 24], rtol=0, atol=POLY_MOMENT_TOL)


def test_concentric_disk_grid_fills_equal_area_annuli_and_sectors_equally():
    bins = 8
    d = concentric_disk_np(*grid_inputs())
    r2 = (d * d).sum(axis=1)
    ring = np.minimum((r2 * bins).astype(int), bins - 1)  # annuli of equal area: r^2 in [k/K, (k+1)/K)
    sector = ((np.arctan2(d[:, 1], d[:, 0]) + math.pi) / (2 * math.pi) * bins).astype(int) % bins
    expected = GRID * GRID / bins
    # Deterministic grid, so the only error is cells cut by a bin boundary. An annulus boundary is a square of
    # Chebyshev radius r, crossing ~2 r GRID cells per side; for the thinnest (outer) annulus, dr ~ 1/(2K),
    # that bounds the relative error by 8 K / GRID. A sector boundary is a segment of <= sqrt(2) (GRID/2) cells,
    # crossing <= GRID + 2 cells; two per sector bound the relative error by 2 K (GRID + 2) / GRID^2.
    ring_tol = 8 * bins / GRID
    sector_tol = 2 * bins * (GRID + 2) / GRID**2
    np.testing.assert_allclose(np.bincount(ring, minlength=bins) / expected, 1.0, rtol=0, atol=ring_tol)
    np.testing.assert_allclose(np.bincount(sector, minlength=bins) / expected, 1.0, rtol=0, atol=sector_tol)


def test_concentric_disk_centre_maps_to_origin():
    np.testing.assert_array_equal(concentric_disk_np(np.array([0.5]), np.array([0.5])), [[0.0, 0.0]])


# -- cosine hemisphere -------------------------------------------------------------------------------------------


@PROPERTY
@given(UNIT, UNIT)
def test_cosine_hemisphere_is_unit_and_upper(u1, u2):
    w = cosine_hemisphere_np(np.array([u1]), np.array([u2]))[0]
    np.testing.assert_allclose(np.linalg.norm(w), 1.0, rtol=0, atol=FLOAT64_ROUNDING)
    assert w[2] >= 0.0


def test_cosine_hemisphere_grid_moments_match_cosine_pdf():
    # pdf cos(theta)/pi: E[cos] = (1/pi) int cos^2 dw = 2/3, E[cos^2] = (1/pi) int cos^3 dw = 1/2;
    # E[x] = E[y] = 0 by symmetry.
    w = cosine_hemisphere_np(*grid_inputs())
    np.testing.assert_allclose(w[:, 2].mean(), 2 / 3, rtol=0, atol=Z_MOMENT_TOL)
    np.testing.assert_allclose((w[:, 2] ** 2).mean(), 1 / 2, rtol=0, atol=POLY_MOMENT_TOL)
    np.testing.assert_allclose(w[:, :2].mean(axis=0), [0.0, 0.0], rtol=0, atol=POLY_MOMENT_TOL)


# -- Warp agrees with the numpy twins ----------------------------------------------------------------------------

POLES = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], np.float64)
NEAR_SOUTH = np.array([[1e-4, 0, -1], [0, -1e-4, -1], [3e-4, 2e-4, -1]], np.float64)
"""Normals next to (0,0,-1), where naive frame constructions divide by ~0 (normalised below)."""


def random_unit(count: int, rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=(count, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_warp_cosine_hemisphere_matches_numpy_twin():
    rng = np.random.default_rng(20240611)  # fixed seed: any inputs do, reproducible ones are easier to debug
    u = np.concatenate([
        rng.random((4096, 2)),
        [[0.5, 0.5], [0.0, 0.0], [0.0, 0.5], [0.5, 0.0], [0.999999, 0.999999], [0.25, 0.75], [0.75, 0.75]],
    ]).astype(np.float32)
    directions, _ = eval_warp(u, np.tile([0.0, 0.0, 1.0], (len(u), 1)))
    expected = cosine_hemisphere_np(u[:, 0].astype(np.float64), u[:, 1].astype(np.float64))
    np.testing.assert_allclose(directions[:, :2], expected[:, :2], rtol=0, atol=FLOAT32_WARP_MATH)
    # z = sqrt(1 - r^2) amplifies float32 roundoff of r^2 by 1/(2z) at the rim (measured 2e-4 at u = (0, 0));
    # z^2 = 1 - r^2 carries no such amplification, so compare that.
    np.testing.assert_allclose(directions[:, 2] ** 2, expected[:, 2] ** 2, rtol=0, atol=FLOAT32_WARP_MATH)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, rtol=0, atol=FLOAT32_WARP_MATH)
    assert (directions[:, 2] >= 0).all()


def assert_orthonormal_frames(frames: np.ndarray, normals: np.ndarray) -> None:
    """Each (3, 3) frame: orthonormal, right-handed, with the normal as its third column."""
    eye = np.broadcast_to(np.eye(3), frames.shape)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", frames, frames), eye, rtol=0, atol=4 * FLOAT32_WARP_MATH)
    np.testing.assert_allclose(frames[:, :, 2], normals, rtol=0, atol=FLOAT32_WARP_MATH)
    np.testing.assert_allclose(np.linalg.det(frames), 1.0, rtol=0, atol=4 * FLOAT32_WARP_MATH)


def test_warp_tangent_frame_is_orthonormal_basis_around_n():
    rng = np.random.default_rng(7)  # fixed seed: reproducible random normals
    near_south = NEAR_SOUTH / np.linalg.norm(NEAR_SOUTH, axis=1, keepdims=True)
    normals = np.concatenate([POLES, near_south, random_unit(4096, rng)]).astype(np.float32)
    _, frames = eval_warp(np.zeros((len(normals), 2)), normals)
    assert np.isfinite(frames).all()
    assert_orthonormal_frames(frames, normals)


@settings(PROPERTY, max_examples=50)  # 50 launches are plenty; the batch test covers 4096 normals
@given(st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 3))
def test_warp_tangent_frame_property(v):
    v = np.asarray(v, np.float64)
    assume(np.linalg.norm(v) > 1e-3)
    n = (v / np.linalg.norm(v)).astype(np.float32)[None]
    _, frames = eval_warp(np.zeros((1, 2)), n)
    assert_orthonormal_frames(frames, n)


def test_warp_frame_maps_cosine_samples_around_n():
    # frame * cosine_hemisphere(u) must lie in the hemisphere of n with cos(theta) = the sample's z.
    rng = np.random.default_rng(11)  # fixed seed: reproducible inputs
    normals = np.concatenate([POLES, random_unit(1024, rng)]).astype(np.float32)
    u = rng.random((len(normals), 2)).astype(np.float32)
    directions, frames = eval_warp(u, normals)
    world = np.einsum("nij,nj->ni", frames, directions)
    np.testing.assert_allclose(np.einsum("ni,ni->n", world, normals), directions[:, 2], rtol=0,
                               atol=4 * FLOAT32_WARP_MATH)
    np.testing.assert_allclose(np.linalg.norm(world, axis=1), 1.0, rtol=0, atol=4 * FLOAT32_WARP_MATH)


@wp.func
def _stratified_through_a_func(state: wp.uint32, strata: int, index: int) -> wp.vec2:
    return stratified_pair(index, strata, state)


@wp.kernel
def _stratified_cells_kernel(strata: int, out: wp.array(dtype=wp.vec2)):
    index = wp.tid()
    state = wp.rand_init(3, 0)  # one generator shared by every cell, as inside a per-point loop
    out[index] = _stratified_through_a_func(state, strata, index)


def test_stratified_pair_jitters_each_cell_independently():
    """Each cell gets its own jitter even when the caller's state is passed down by value."""
    strata = 16
    out = wp.zeros(strata * strata, dtype=wp.vec2, device="cpu")
    wp.launch(_stratified_cells_kernel, dim=strata * strata, inputs=[strata], outputs=[out], device="cpu")
    points = out.numpy() * strata
    cells = np.stack([np.arange(strata * strata) % strata, np.arange(strata * strata) // strata], axis=1)
    jitter = points - cells
    assert ((jitter >= 0) & (jitter < 1)).all()  # every sample stays in its own cell
    # Independent uniform jitters: std ~ 0.29; a shared jitter would give 0.
    assert jitter.std(axis=0).min() > 0.2


@wp.kernel
def _triangle_points_kernel(u: wp.array(dtype=wp.vec2), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = triangle_point(wp.vec3(0.0, 0.0, 0.0), wp.vec3(1.0, 0.0, 0.0), wp.vec3(0.0, 1.0, 0.0), u[i][0], u[i][1])


def test_triangle_point_is_uniform_on_the_triangle():
    """Points stay inside, and the mean is the centroid (1/3, 1/3) with the second moments of a uniform
    density on the unit right triangle (E[x^2] = 1/6, E[xy] = 1/12)."""
    rng = np.random.default_rng(4)  # fixed seed
    u = rng.random((200_000, 2)).astype(np.float32)
    out = wp.zeros(len(u), dtype=wp.vec3, device="cpu")
    wp.launch(_triangle_points_kernel, dim=len(u), inputs=[wp.array(u, dtype=wp.vec2, device="cpu")], outputs=[out],
              device="cpu")
    p = out.numpy()[:, :2].astype(np.float64)
    assert (p >= -FLOAT32_STORAGE).all() and (p.sum(axis=1) <= 1 + FLOAT32_STORAGE).all()
    tol = MC_SIGMAS * 0.25 / math.sqrt(len(u))  # each coordinate's std is < 0.25
    np.testing.assert_allclose(p.mean(axis=0), [1 / 3, 1 / 3], atol=tol)
    np.testing.assert_allclose([(p[:, 0] ** 2).mean(), (p[:, 0] * p[:, 1]).mean()], [1 / 6, 1 / 12], atol=tol)


@wp.kernel
def _sin_cos_kernel(x: wp.array(dtype=float), out: wp.array(dtype=wp.vec2)):
    i = wp.tid()
    out[i] = sin_cos(x[i])


def test_polynomial_sin_cos_matches_float64_over_many_turns():
    """sin_cos (range reduction + Cephes polynomials, used by the ray generators) against float64, on
    |x| < 100 and at the quarter-turn boundaries where the reduction switches branch."""
    rng = np.random.default_rng(3)  # fixed seed
    quarter = np.pi / 2
    x = np.concatenate([rng.uniform(-100, 100, 20000), np.arange(-64, 65) * quarter,
                        np.arange(-64, 65) * quarter + quarter / 2, [0.0, 1e-30, -1e-30]]).astype(np.float32)
    out = wp.zeros(len(x), dtype=wp.vec2)
    wp.launch(_sin_cos_kernel, dim=len(x), inputs=[wp.array(x, dtype=float), out])
    got = out.numpy()
    exact = np.stack([np.sin(x.astype(np.float64)), np.cos(x.astype(np.float64))], axis=1)
    assert np.abs(got - exact).max() <= POLYNOMIAL_SIN_COS
