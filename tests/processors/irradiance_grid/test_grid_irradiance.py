"""processors.irradiance_grid.grid_irradiance: the kernel-side irradiance of a vector grid against a
plain float64 trilinear reconstruction of Pacanowski et al. 2008, section 3.2, eq. 2."""

import numpy as np
import warp as wp
from tolerances import FLOAT32_STORAGE
from usdbake.processors.irradiance_grid.grid_irradiance import GridVectors, grid_irradiance, grid_vectors

RESOLUTION = (3, 2, 4)
ORIGIN = np.array([-1.0, 0.5, 2.0])
CELL = np.array([0.5, 1.0, 0.25])


@wp.kernel
def irradiance_kernel(grid: GridVectors, points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                      out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = grid_irradiance(grid, points[i], normals[i])


def reference(vectors, p, n):
    """max(0, sum_a n_a^2 (I_a . n)) per channel, I_a trilinear in the hemisphere of sign(n_a)."""
    res = np.array(RESOLUTION)
    g = np.clip((p - ORIGIN) / CELL, 0, res - 1)
    lo = np.minimum(np.floor(g).astype(int), np.maximum(res - 2, 0))
    t = g - lo
    e = np.zeros(3)
    for a in range(3):
        h = 2 * a + (1 if n[a] < 0 else 0)
        interp = np.zeros((3, 3))
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    c = np.minimum(lo + [dx, dy, dz], res - 1)
                    w = np.prod([t[k] if d else 1 - t[k] for k, d in enumerate((dx, dy, dz))])
                    interp += w * vectors[c[0], c[1], c[2], h]
        e += n[a] ** 2 * (interp @ n)
    return np.maximum(e, 0.0)


def test_irradiance_matches_a_plain_trilinear_reconstruction():
    rng = np.random.default_rng(28)  # fixed seed: random vectors, points (some outside the grid), normals
    nx, ny, nz = RESOLUTION
    vectors = rng.normal(size=(nx, ny, nz, 6, 3, 3))  # [x, y, z, hemisphere, channel (row), axis]
    stored = vectors.transpose(2, 1, 0, 3, 4, 5).reshape(-1, 6, 3, 3)  # vertices x fastest
    lo, hi = ORIGIN, ORIGIN + CELL * (np.array(RESOLUTION) - 1)
    points = rng.uniform(lo - 0.3, hi + 0.3, size=(200, 3))
    normals = rng.normal(size=(200, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    grid = grid_vectors(stored, RESOLUTION, ORIGIN, CELL, "cpu")
    out = wp.zeros(200, dtype=wp.vec3, device="cpu")
    wp.launch(irradiance_kernel, 200, [grid, wp.array(points.astype(np.float32), dtype=wp.vec3, device="cpu"),
                                       wp.array(normals.astype(np.float32), dtype=wp.vec3, device="cpu"), out],
              device="cpu")
    expected = np.array([reference(vectors, p, n) for p, n in zip(points.astype(np.float32).astype(np.float64),
                                                                  normals.astype(np.float32).astype(np.float64))])
    assert (expected == 0).any() and (expected > 0).any()  # the clamp at zero is exercised
    np.testing.assert_allclose(out.numpy(), expected, atol=8 * FLOAT32_STORAGE * np.abs(vectors).max())


def test_a_constant_field_gives_the_cosine_law():
    # The same vector I = E0 * (0, 0, 1) in every hemisphere of every vertex: E = E0 * n_z (n_x^2 + n_y^2 + n_z^2).
    vectors = np.zeros((np.prod(RESOLUTION), 6, 3, 3))
    vectors[..., :, 2] = 2.0
    grid = grid_vectors(vectors, RESOLUTION, ORIGIN, CELL, "cpu")
    normals = np.array([[0, 0, 1], [0.6, 0, 0.8], [0, -0.8, 0.6], [0, 0, -1]], np.float32)
    points = np.tile(np.float32(ORIGIN + 0.3), (4, 1))
    out = wp.zeros(4, dtype=wp.vec3, device="cpu")
    wp.launch(irradiance_kernel, 4, [grid, wp.array(points, dtype=wp.vec3, device="cpu"),
                                     wp.array(normals, dtype=wp.vec3, device="cpu"), out], device="cpu")
    np.testing.assert_allclose(out.numpy(), np.repeat([[2.0], [1.6], [1.2], [0.0]], 3, axis=1), atol=FLOAT32_STORAGE)
