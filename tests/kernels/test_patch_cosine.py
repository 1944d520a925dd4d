"""The exact cosine-weighted share of a sky patch (kernels/sky.patch_mean_cosine, patch_above)."""

import numpy as np
import warp as wp

from tolerances import FLOAT32_ACCUMULATED, FLOAT32_WARP_MAPS
from usdbake.kernels.sky import patch_above, patch_layout, patch_mean_cosine


@wp.kernel
def patch_cosine_kernel(bounds: wp.array(dtype=wp.vec4), normals: wp.array(dtype=wp.vec3),
                        mean: wp.array(dtype=float), above: wp.array(dtype=int)):
    i = wp.tid()
    mean[i] = patch_mean_cosine(bounds[i], normals[i])
    above[i] = wp.where(patch_above(bounds[i], normals[i]), 1, 0)


def quadrature(bounds: np.ndarray, normal: np.ndarray, steps: int = 400) -> float:
    """Mean of max(0, n . w) over the patch by the midpoint rule in (z, azimuth), float64: equal solid angle."""
    t = (np.arange(steps) + 0.5) / steps
    z = bounds[0] + t[:, None] * (bounds[1] - bounds[0])
    az = bounds[2] + t[None, :] * (bounds[3] - bounds[2])
    r = np.sqrt(np.maximum(0.0, 1 - z * z))
    w = np.stack(np.broadcast_arrays(r * np.sin(az), r * np.cos(az), z), axis=-1)
    return float(np.maximum(w @ normal, 0.0).mean())


def test_the_exact_mean_cosine_matches_quadrature_where_the_patch_is_above():
    patches = patch_layout("uniform", count=64)
    rng = np.random.default_rng(4)  # fixed: arbitrary normals, the horizontal one among them
    normals = np.vstack([[0.0, 0.0, 1.0], rng.normal(size=(7, 3))])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    bounds = np.repeat(patches.patch_bounds.astype(np.float32), len(normals), axis=0)
    ns = np.tile(normals, (len(patches), 1)).astype(np.float32)
    mean, above = wp.zeros(len(ns), dtype=float, device="cpu"), wp.zeros(len(ns), dtype=int, device="cpu")
    wp.launch(patch_cosine_kernel, dim=len(ns), inputs=[wp.array(bounds, dtype=wp.vec4, device="cpu"),
              wp.array(ns, dtype=wp.vec3, device="cpu"), mean, above], device="cpu")
    mean, above = mean.numpy(), above.numpy().astype(bool)
    assert above[::len(normals)].all()  # every patch lies above a horizontal face
    assert 0 < above.sum() < len(above)  # tilted faces cut some patches
    for i in np.flatnonzero(above):
        assert abs(mean[i] - quadrature(bounds[i].astype(np.float64), ns[i].astype(np.float64))) < FLOAT32_WARP_MAPS
    # Over the whole sky, a horizontal face's mean cosines weighted by solid angle add up to pi.
    horizontal = mean[::len(normals)]
    np.testing.assert_allclose((horizontal * patches.patch_solid_angles).sum(), np.pi, rtol=FLOAT32_ACCUMULATED)
