"""Sphere and hemisphere maps of the displacement fields: bijectivity, equal area, folds, Warp = numpy."""

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chisquare

from tolerances import (CELL_SPACING_RATIO, CHI2_SIGNIFICANCE, FLOAT32_WARP_MAPS, FLOAT64_AMPLIFIED, FLOAT64_ROUNDING,
                        MALLEY_ROUNDTRIP, WRAP_NEIGHBOUR_SPACING)
from kernel_twins import cell_spacing_ratio_np, concentric_disk_to_square_np, cosine_hemisphere_np, equal_area_sphere_to_square_np, equal_area_square_to_sphere_np, grid_cell_centers_np, malley_direction_to_square_np, octahedral_wrap_np
from usdbake.processors.instancing.sphere_maps import equal_area_sphere_to_square, equal_area_square_to_sphere, malley_direction_to_square, octahedral_wrap

wp.set_module_options({"enable_backward": False})

INTERIOR = st.floats(1e-6, 1 - 1e-6)
"""Square coordinates off the folded border (on it, (1, v) and (1, -v) are one point: two valid inverses)."""


@given(INTERIOR, INTERIOR)
@settings(max_examples=300, deadline=None)
def test_equal_area_square_sphere_square_returns_the_point(u, v):
    d = equal_area_square_to_sphere_np(np.array([u]), np.array([v]))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=FLOAT64_AMPLIFIED)
    np.testing.assert_allclose(equal_area_sphere_to_square_np(d)[0], [u, v], atol=FLOAT64_AMPLIFIED)


def test_equal_area_sphere_square_sphere_returns_the_direction():
    rng = np.random.default_rng(3)  # fixed seed: reproducible directions
    d = rng.normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    uv = equal_area_sphere_to_square_np(d)
    assert (uv >= 0).all() and (uv <= 1).all()
    np.testing.assert_allclose(equal_area_square_to_sphere_np(uv[:, 0], uv[:, 1]), d, atol=FLOAT64_AMPLIFIED)


def test_every_cell_of_the_octahedral_grid_has_the_same_solid_angle():
    """Uniform points on the sphere fall into the n^2 cells with equal probability (chi-square)."""
    rng = np.random.default_rng(5)  # fixed seed: the test is deterministic
    n, count = 16, 1_000_000
    d = rng.normal(size=(count, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cell = np.minimum((equal_area_sphere_to_square_np(d) * n).astype(int), n - 1)
    counts = np.bincount(cell[:, 1] * n + cell[:, 0], minlength=n * n)
    assert chisquare(counts).pvalue > CHI2_SIGNIFICANCE
    # a latitude-longitude grid of the same size fails the same test by far
    lat = np.minimum(((np.arccos(d[:, 2]) / np.pi) * n).astype(int), n - 1)
    lon = np.minimum((((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / (2 * np.pi)) * n).astype(int), n - 1)
    assert chisquare(np.bincount(lat * n + lon, minlength=n * n)).pvalue < 1e-12


@pytest.mark.parametrize("n", [33, 65])
def test_cell_centre_spacing_stays_even_at_any_resolution(n):
    """Largest / smallest nearest-neighbour distance of the positional samples (documented: 1.34)."""
    assert cell_spacing_ratio_np(n) < CELL_SPACING_RATIO


def test_wrapped_neighbours_across_the_folded_border_are_adjacent_on_the_sphere():
    n = 17
    centers = grid_cell_centers_np(n).reshape(n, n, 3)  # [row j, column i]
    spacing = np.arccos(np.clip((centers[:, :-1] * centers[:, 1:]).sum(-1), -1, 1)).max()
    for j in range(n):
        for i in range(n):
            for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                wi, wj = octahedral_wrap_np(np.array(i + di), np.array(j + dj), n)
                assert 0 <= wi < n and 0 <= wj < n
                angle = np.arccos(np.clip(centers[j, i] @ centers[wj, wi], -1, 1))
                assert angle <= WRAP_NEIGHBOUR_SPACING * spacing, (i, j, di, dj)


@given(INTERIOR, INTERIOR)
@settings(max_examples=300, deadline=None)
def test_concentric_malley_map_inverts_cosine_hemisphere(u, v):
    d = cosine_hemisphere_np(np.array([u]), np.array([v]))
    np.testing.assert_allclose(malley_direction_to_square_np(d)[0], [u, v], atol=MALLEY_ROUNDTRIP)


def test_concentric_inverse_of_the_disk_centre_and_rim():
    np.testing.assert_allclose(concentric_disk_to_square_np(np.array([0.0]), np.array([0.0]))[0], [0.5, 0.5])
    rim = concentric_disk_to_square_np(np.array([1.0, 0.0, -1.0, 0.0]), np.array([0.0, 1.0, 0.0, -1.0]))
    np.testing.assert_allclose(rim, [[1, 0.5], [0.5, 1], [0, 0.5], [0.5, 0]], atol=FLOAT64_ROUNDING)


@wp.kernel
def _maps_kernel(uv: wp.array(dtype=wp.vec2), dirs: wp.array(dtype=wp.vec3), hemi: wp.array(dtype=wp.vec3),
                 sphere: wp.array(dtype=wp.vec3), square: wp.array(dtype=wp.vec2), disk: wp.array(dtype=wp.vec2),
                 wrap: wp.array(dtype=wp.vec2i)):
    i = wp.tid()
    sphere[i] = equal_area_square_to_sphere(uv[i][0], uv[i][1])
    square[i] = equal_area_sphere_to_square(dirs[i])
    disk[i] = malley_direction_to_square(hemi[i])
    wrap[i] = octahedral_wrap(i % 11 - 1, i // 11 % 11 - 1, 9)


def test_warp_functions_match_their_numpy_twins():
    rng = np.random.default_rng(7)  # fixed seed
    count = 2000
    uv = rng.random((count, 2))
    dirs = rng.normal(size=(count, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hemi = cosine_hemisphere_np(*rng.random((2, count)))
    out = [wp.zeros(count, dtype=t) for t in (wp.vec3, wp.vec2, wp.vec2, wp.vec2i)]
    wp.launch(_maps_kernel, dim=count, inputs=[wp.array(uv, dtype=wp.vec2), wp.array(dirs, dtype=wp.vec3),
                                               wp.array(hemi, dtype=wp.vec3), *out], device="cpu")
    np.testing.assert_allclose(out[0].numpy(), equal_area_square_to_sphere_np(uv[:, 0], uv[:, 1]),
                               atol=FLOAT32_WARP_MAPS)
    np.testing.assert_allclose(out[1].numpy(), equal_area_sphere_to_square_np(dirs), atol=FLOAT32_WARP_MAPS)
    np.testing.assert_allclose(out[2].numpy(), malley_direction_to_square_np(hemi), atol=FLOAT32_WARP_MAPS)
    k = np.arange(count)
    wi, wj = octahedral_wrap_np(k % 11 - 1, k // 11 % 11 - 1, 9)
    np.testing.assert_array_equal(out[3].numpy(), np.stack([wi, wj], axis=1))
