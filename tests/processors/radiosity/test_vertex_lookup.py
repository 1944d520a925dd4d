"""radiosity/vertex_lookup: the closest point on a triangle against an independent construction (the plane's
foot when it falls inside, else the nearest of the three edges' clamped feet), and a search that finds a
huge triangle whose centroid is far behind many small ones."""

import numpy as np
import pytest
from tolerances import FLOAT64_AMPLIFIED

from usdbake.core.errors import UsageError
from usdbake.processors.radiosity.vertex_lookup import closest_on_triangles, surface_values_at


def closest_by_construction(p, a, b, c):
    """The closest point of triangle abc to p, float64, without Voronoi regions."""
    n = np.cross(b - a, c - a)
    foot = p - np.dot(p - a, n) / np.dot(n, n) * n
    inside = all(np.dot(np.cross(v1 - v0, foot - v0), n) >= 0 for v0, v1 in ((a, b), (b, c), (c, a)))
    if inside:
        return foot
    feet = [v0 + np.clip(np.dot(p - v0, v1 - v0) / np.dot(v1 - v0, v1 - v0), 0, 1) * (v1 - v0)
            for v0, v1 in ((a, b), (b, c), (c, a))]
    return min(feet, key=lambda q: np.linalg.norm(p - q))


def test_closest_point_matches_the_construction():
    rng = np.random.default_rng(2)  # fixed seed: points in every Voronoi region of random triangles
    a, b, c = (rng.normal(size=(2000, 3)) for _ in range(3))
    p = rng.normal(size=(2000, 3)) * 2.0
    distance, bary = closest_on_triangles(p, a, b, c)
    expected = np.array([closest_by_construction(*rows) for rows in zip(p, a, b, c)])
    np.testing.assert_allclose(bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c, expected,
                               atol=FLOAT64_AMPLIFIED)
    np.testing.assert_allclose(distance, np.linalg.norm(p - expected, axis=1), atol=FLOAT64_AMPLIFIED)
    assert (bary >= -FLOAT64_AMPLIFIED).all()


def test_a_huge_triangle_behind_many_small_centroids_is_found():
    rng = np.random.default_rng(6)  # fixed seed: small triangles scattered 1 to 2 units above the query
    small = rng.uniform(-1, 1, (200, 1, 3)) + rng.uniform(-0.05, 0.05, (200, 3, 3)) + [0.0, 0.0, 1.5]
    huge = np.array([[[-100.0, -100.0, 0.0], [300.0, -100.0, 0.0], [-100.0, 300.0, 0.0]]])  # centroid far off
    corners = np.concatenate([small, huge]).reshape(-1, 3)
    triangles = np.arange(len(corners)).reshape(-1, 3)
    values = np.zeros((len(corners), 1))
    values[-3:] = 7.0  # the huge triangle's points
    got = surface_values_at([[0.0, 0.0, 0.01]], [[0.0, 0.0, 1.0]], corners, triangles, values, max_distance=0.1)
    np.testing.assert_allclose(got, [[7.0]], rtol=FLOAT64_AMPLIFIED)
    with pytest.raises(UsageError, match=r"points\[0\] = \(0, 0, -0.5\) is 0.5 stage units"):
        surface_values_at([[0.0, 0.0, -0.5]], [[0.0, 0.0, 1.0]], corners, triangles, values, max_distance=0.1)
