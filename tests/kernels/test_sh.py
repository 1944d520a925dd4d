"""L2 spherical harmonics (processors/kernels/sh.py): orthonormality by exact quadrature, the Warp
basis against its numpy twin, projections with closed forms (constant, cosine lobe, a single
direction via the addition theorem), the irradiance convolution (uniform radiance -> pi L, the
clamped-cosine kernel's ringing bound for non-negative radiance), and rotation."""

import math

import numpy as np
import pytest
import warp as wp

from tolerances import (DERING_STRENGTH, FIBONACCI_MEAN, FLOAT32_ACCUMULATED, FLOAT32_WARP_MATH, FLOAT64_AMPLIFIED,
                        FLOAT64_CONSTANT, FLOAT64_ROUNDING, GRID_MINIMUM, QUOTED_6_DECIMALS, SH_L2_TRUNCATION,
                        SH_ROTATION)
from usdbake.kernels import sh

wp.set_module_options({"enable_backward": False})

def gauss_sphere(n_z: int = 12, n_phi: int = 24, z_range=(-1.0, 1.0)):
    """Product quadrature on (a z-band of) the sphere: Gauss-Legendre in z, uniform in phi.

    Exact for polynomials in (x, y, z) of degree < min(2 n_z, n_phi) on the band (L2 products are
    degree 4), so sums below are exact up to rounding.
    """
    nodes, weights = np.polynomial.legendre.leggauss(n_z)
    lo, hi = z_range
    z = 0.5 * (hi - lo) * nodes + 0.5 * (hi + lo)
    wz = 0.5 * (hi - lo) * weights
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - zz ** 2)
    dirs = np.stack([r * np.cos(pp), r * np.sin(pp), zz], axis=-1).reshape(-1, 3)
    w = (wz[:, None] * np.full(n_phi, 2 * np.pi / n_phi)[None, :]).reshape(-1)
    return dirs, w


def legendre(l: int, x):
    return [np.ones_like(x), x, 0.5 * (3 * x * x - 1)][l]


def clamped_cosine_kernel(x):
    """L2 irradiance of a unit delta light at angle acos(x): sum_l A_l (2l+1)/(4 pi) P_l(x)
    (addition theorem; Ramamoorthi & Hanrahan 2001)."""
    a = [math.pi, 2 * math.pi / 3, math.pi / 4]
    return sum(a[l] * (2 * l + 1) / (4 * math.pi) * legendre(l, x) for l in range(3))


def random_directions(n: int, seed: int) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def random_rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_basis_is_orthonormal_by_quadrature():
    dirs, w = gauss_sphere()
    y = sh.sh_basis_np(dirs)
    gram = np.einsum("nk,n,nj->kj", y, w, y)
    np.testing.assert_allclose(gram, np.eye(9), atol=FLOAT64_ROUNDING)


def test_basis_constants_match_closed_forms():
    expected = [0.5 / math.sqrt(math.pi), math.sqrt(3 / (4 * math.pi)), math.sqrt(15 / (4 * math.pi)),
                math.sqrt(5 / (16 * math.pi)), math.sqrt(15 / (16 * math.pi))]
    np.testing.assert_allclose([sh.C0, sh.C1, sh.C2, sh.C3, sh.C4], expected, rtol=FLOAT64_CONSTANT)


@wp.kernel
def _basis_kernel(dirs: wp.array(dtype=wp.vec3), out: wp.array2d(dtype=float)):
    i = wp.tid()
    v = sh.sh_basis(dirs[i])
    for k in range(9):
        out[i, k] = v[k]


@wp.kernel
def _sphere_kernel(u: wp.array(dtype=wp.vec2), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = sh.uniform_sphere(u[i][0], u[i][1])


def test_warp_basis_matches_numpy_twin():
    d = random_directions(200, seed=5).astype(np.float32)  # fixed seed
    out = wp.zeros((200, 9), dtype=float, device="cpu")
    wp.launch(_basis_kernel, dim=200, inputs=[wp.array(d, dtype=wp.vec3, device="cpu"), out], device="cpu")
    np.testing.assert_allclose(out.numpy(), sh.sh_basis_np(d), atol=FLOAT32_WARP_MATH)


def test_warp_uniform_sphere_matches_twin_and_is_unit():
    u = np.random.default_rng(7).random((300, 2)).astype(np.float32)  # fixed seed
    out = wp.zeros(300, dtype=wp.vec3, device="cpu")
    wp.launch(_sphere_kernel, dim=300, inputs=[wp.array(u, dtype=wp.vec2, device="cpu"), out], device="cpu")
    np.testing.assert_allclose(out.numpy(), sh.uniform_sphere_np(u[:, 0], u[:, 1]), atol=FLOAT32_WARP_MATH)
    np.testing.assert_allclose(np.linalg.norm(out.numpy(), axis=1), 1.0, atol=FLOAT32_WARP_MATH)


def test_project_kernel_matches_numpy_projection():
    n, samples = 3, 64
    d = random_directions(n * samples, seed=11).astype(np.float32)  # fixed seed
    radiance = np.random.default_rng(12).random((n * samples, 3)).astype(np.float32)
    out = wp.zeros((n, 27), dtype=float, device="cpu")
    wp.launch(sh.project_kernel, dim=n, inputs=[0, wp.array(d, dtype=wp.vec3, device="cpu"),
                                                wp.array(radiance, dtype=wp.vec3, device="cpu"), samples, out],
              device="cpu")
    for i in range(n):
        rows = slice(i * samples, (i + 1) * samples)
        expected = sh.project_np(d[rows], radiance[rows])
        np.testing.assert_allclose(out.numpy()[i].reshape(9, 3), expected, rtol=FLOAT32_ACCUMULATED,
                                   atol=FLOAT32_ACCUMULATED)


def test_projection_of_a_constant():
    dirs, w = gauss_sphere()
    c = sh.project_np(dirs, np.full(len(dirs), 2.5), w)
    expected = np.zeros(9)
    expected[0] = 2.5 * math.sqrt(4 * math.pi)
    np.testing.assert_allclose(c, expected, atol=FLOAT64_ROUNDING)


def test_projection_of_a_cosine_lobe():
    """max(z, 0): integral Y_k max(z,0) = (pi Y00, 0, 2 pi/3 C1, 0, 0, 0, pi/2 C3, 0, 0)."""
    dirs, w = gauss_sphere(z_range=(0.0, 1.0))  # the lobe is a polynomial on the upper half
    c = sh.project_np(dirs, dirs[:, 2], w)
    expected = np.zeros(9)
    expected[0] = math.pi * sh.C0
    expected[2] = 2 * math.pi / 3 * sh.C1
    expected[6] = math.pi / 2 * sh.C3
    np.testing.assert_allclose(c, expected, atol=FLOAT64_ROUNDING)
    # ... which is the irradiance SH of a unit delta light from +z: A_l Y_l0(z).
    np.testing.assert_allclose(c, sh.irradiance_sh_np(sh.sh_basis_np([[0, 0, 1]])[0]), atol=FLOAT64_ROUNDING)


def test_projection_of_a_single_direction_and_the_addition_theorem():
    """A delta of unit power at w has coefficients Y_k(w); its L2 irradiance at n is the kernel
    sum_l A_l (2l+1)/(4 pi) P_l(n . w)."""
    w_dir = random_directions(1, seed=21)[0]  # fixed seed
    coefficients = sh.project_np(w_dir[None], np.ones(1), np.ones(1))
    np.testing.assert_allclose(coefficients, sh.sh_basis_np(w_dir[None])[0], atol=FLOAT64_ROUNDING)
    normals = random_directions(500, seed=22)
    e = sh.evaluate_np(sh.irradiance_sh_np(coefficients)[:, None], normals)[:, 0]
    np.testing.assert_allclose(e, clamped_cosine_kernel(normals @ w_dir), atol=FLOAT64_ROUNDING)


def test_irradiance_of_uniform_radiance_is_pi_l_for_every_normal():
    dirs, w = gauss_sphere()
    radiance = np.array([0.3, 1.0, 7.5])
    coefficients = sh.project_np(dirs, np.tile(radiance, (len(dirs), 1)), w)
    normals = random_directions(1000, seed=31)  # fixed seed
    e = sh.evaluate_np(sh.irradiance_sh_np(coefficients), normals)
    np.testing.assert_allclose(e, np.tile(math.pi * radiance, (1000, 1)), rtol=FLOAT64_ROUNDING)


def test_irradiance_of_a_cosine_power_environment_matches_closed_form():
    """L(w) = max(w.z, 0): the exact E(+z) is the integral of cos^2 over the hemisphere, 2 pi / 3;
    L2 gives pi/4 + pi/3 + 5 pi/64 (bands 0..2), 0.8 % low: R&H's truncation error."""
    dirs, w = gauss_sphere(z_range=(0.0, 1.0))
    coefficients = sh.project_np(dirs, dirs[:, 2], w)
    e_up = sh.evaluate_np(sh.irradiance_sh_np(coefficients)[:, None], np.array([[0.0, 0.0, 1.0]]))[0, 0]
    l2 = sum(sh.COSINE_LOBE[k] * coefficients[k] * sh.sh_basis_np([[0, 0, 1]])[0, k] for k in (0, 2, 6))
    np.testing.assert_allclose(e_up, l2, rtol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(e_up, math.pi / 4 + math.pi / 3 + 5 * math.pi / 64, rtol=FLOAT64_ROUNDING)
    assert abs(e_up - 2 * math.pi / 3) / (2 * math.pi / 3) < SH_L2_TRUNCATION


KERNEL_MIN = float(clamped_cosine_kernel(np.array([-8.0 / 15.0]))[0])
"""Minimum of the L2 clamped-cosine kernel (at n.w = -8/15): -0.0396. L2 truncation rings, so a
non-negative radiance of total power Phi = integral L dw can give E(n) down to KERNEL_MIN * Phi,
and a single delta light reaches that bound."""


def test_kernel_minimum_closed_form():
    x = np.linspace(-1, 1, 200001)
    assert KERNEL_MIN == pytest.approx(clamped_cosine_kernel(x).min(), abs=GRID_MINIMUM)
    assert KERNEL_MIN == pytest.approx(-0.039583, abs=QUOTED_6_DECIMALS)


@pytest.mark.parametrize("seed", range(8))
def test_non_negative_radiance_gives_irradiance_above_the_ringing_bound(seed):
    """Stress: random non-negative radiance (deltas, lobes, a sky) -> E(n) >= KERNEL_MIN * Phi."""
    rng = np.random.default_rng(seed)  # fixed seeds
    dirs, w = gauss_sphere(24, 48)
    count = rng.integers(1, 6)
    centres = random_directions(count, seed=100 + seed)
    power = rng.random(count) * 10 ** rng.uniform(-3, 3, count)
    sharpness = rng.choice([1.0, 10.0, 100.0], count)
    radiance = (power[None] * np.exp(sharpness[None] * (dirs @ centres.T - 1))).sum(axis=1)
    radiance += rng.random() * (dirs[:, 2] > 0)  # plus a sky
    coefficients = sh.project_np(dirs, radiance, w)
    deltas = random_directions(3, seed=200 + seed)
    delta_power = rng.random(3) * 5
    coefficients += (sh.sh_basis_np(deltas) * delta_power[:, None]).sum(axis=0)
    phi = float((radiance * w).sum() + delta_power.sum())
    e = sh.evaluate_np(sh.irradiance_sh_np(coefficients)[:, None], random_directions(4000, seed=300 + seed))[:, 0]
    assert e.min() >= KERNEL_MIN * phi - FLOAT64_AMPLIFIED * phi
    # the mean irradiance over all normals is exactly Phi / 4 (band 0 only)
    assert sh.irradiance_sh_np(coefficients)[0] * sh.C0 == pytest.approx(phi / 4, rel=FLOAT64_AMPLIFIED)


def test_delta_light_attains_the_ringing_bound():
    w_dir = np.array([0.0, 0.0, 1.0])
    c = sh.irradiance_sh_np(sh.sh_basis_np(w_dir[None])[0])
    n = np.array([[math.sqrt(1 - (8 / 15) ** 2), 0.0, -8.0 / 15.0]])
    assert sh.evaluate_np(c[:, None], n)[0, 0] == pytest.approx(KERNEL_MIN, abs=FLOAT64_ROUNDING)


@pytest.mark.parametrize("seed", range(4))
def test_rotation_matches_projecting_the_rotated_function(seed):
    rotation = random_rotation(seed)  # fixed seeds
    dirs, w = gauss_sphere()
    centre = random_directions(1, seed=50 + seed)[0]

    def f(d):
        return np.exp(3 * (d @ centre - 1)) + 0.2 * d[:, 0] * d[:, 1]

    c = sh.project_np(dirs, f(dirs), w)
    rotated_function = sh.project_np(dirs, f(dirs @ rotation), w)  # g(w) = f(R^T w): rows d @ R = R^T d
    np.testing.assert_allclose(sh.rotate_np(c, rotation), rotated_function, atol=SH_ROTATION)


@pytest.mark.parametrize("seed", range(4))
def test_irradiance_is_rotation_invariant(seed):
    """E_g(R n) = E_f(n) for g = f rotated by R; the rotation is orthogonal, block-diagonal by band."""
    rotation = random_rotation(seed)
    rng = np.random.default_rng(60 + seed)
    c = rng.normal(size=(9, 3))
    matrix = sh.rotation_matrix_np(rotation)
    np.testing.assert_allclose(matrix @ matrix.T, np.eye(9), atol=SH_ROTATION)
    off_band = sh.BAND[:, None] != sh.BAND[None, :]
    np.testing.assert_allclose(matrix[off_band], 0.0, atol=SH_ROTATION)
    normals = random_directions(300, seed=70 + seed)
    e = sh.evaluate_np(sh.irradiance_sh_np(c), normals)
    e_rotated = sh.evaluate_np(sh.irradiance_sh_np(sh.rotate_np(c, rotation)), normals @ rotation.T)
    np.testing.assert_allclose(e_rotated, e, atol=SH_ROTATION)


def test_fibonacci_sphere_is_unit_and_balanced():
    d = sh.fibonacci_sphere_np(1000)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=FLOAT64_ROUNDING)
    assert np.abs(d.mean(axis=0)).max() < FIBONACCI_MEAN


def test_dering_window_removes_the_negative_lobe_of_a_directional_light():
    """One directional light's L2 irradiance dips below zero opposite the light; the Gaussian window from
    DERING_NON_NEGATIVE on makes it non-negative everywhere, a weaker one does not."""
    from usdbake.kernels.sh import DERING_NON_NEGATIVE, dering_window, evaluate_np, irradiance_sh_np, sh_basis_np

    light = np.array([0.3, -0.5, 0.81])
    light /= np.linalg.norm(light)
    irradiance = irradiance_sh_np(sh_basis_np(light[None])[0])[:, None]  # (9, 1): a unit delta of radiance
    directions = np.random.default_rng(4).normal(size=(200000, 3))  # fixed seed
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    peak = evaluate_np(irradiance, light[None])[0, 0]

    def lowest(window):
        return evaluate_np(irradiance * window[:, None], directions).min() / peak

    assert lowest(np.ones(9)) < -0.03
    assert lowest(dering_window(0.8 * DERING_NON_NEGATIVE)) < 0.0
    assert lowest(dering_window(DERING_NON_NEGATIVE)) >= -1e-4
    np.testing.assert_array_equal(dering_window(0.0), np.ones(9))


def test_dering_windows_only_the_probes_that_ring_and_only_as_much_as_needed():
    """A probe lit by one directional light rings and is windowed at about DERING_NON_NEGATIVE (its
    irradiance then >= 0 everywhere); a probe under a uniform sky plus a soft gradient does not ring and
    keeps its SH bit for bit; a black probe is left alone."""
    from usdbake.kernels.sh import DERING_NON_NEGATIVE, dering, evaluate_np, fibonacci_sphere_np, irradiance_sh_np, sh_basis_np

    light = np.array([0.0, 0.6, 0.8])
    ringing = irradiance_sh_np(sh_basis_np(light[None])[0])[:, None].repeat(3, axis=1)
    smooth = np.zeros((9, 3))
    smooth[0], smooth[2] = 1.0, 0.3  # constant plus a gentle linear term: positive everywhere
    black = np.zeros((9, 3))
    windowed, strengths = dering(np.stack([ringing, smooth, black]))
    assert abs(strengths[0] - DERING_NON_NEGATIVE) < DERING_STRENGTH
    assert strengths[1] == 0.0 and strengths[2] == 0.0
    np.testing.assert_array_equal(windowed[1], smooth)
    np.testing.assert_array_equal(windowed[2], black)
    directions = fibonacci_sphere_np(20000)
    assert evaluate_np(ringing, directions).min() < 0.0
    assert evaluate_np(windowed[0], directions).min() >= -1e-4
