"""numpy twins (float64) of the Warp sampling maps and sphere layouts in kernels/.

References for the tests: each map is checked here against closed forms and
property tests, and the Warp function against its twin. The library runs the
Warp functions only.
"""

from __future__ import annotations

import numpy as np


def concentric_disk_np(u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """numpy twin of concentric_disk: (N,) x (N,) -> (N, 2)."""
    a = 2.0 * np.asarray(u1, np.float64) - 1.0
    b = 2.0 * np.asarray(u2, np.float64) - 1.0
    use_a = a * a > b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(use_a, a, b)
        phi = np.where(use_a, np.pi / 4 * (b / a), np.pi / 2 - np.pi / 4 * (a / b))
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    r = np.where((a == 0) & (b == 0), 0.0, r)
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)


def cosine_hemisphere_np(u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """numpy twin of cosine_hemisphere: (N,) x (N,) -> (N, 3) unit vectors with z >= 0."""
    d = concentric_disk_np(u1, u2)
    z = np.sqrt(np.maximum(0.0, 1.0 - (d * d).sum(axis=-1)))
    return np.concatenate([d, z[:, None]], axis=-1)


def equal_area_square_to_sphere_np(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """numpy twin of equal_area_square_to_sphere: (N,) x (N,) in [0,1] -> (N, 3) unit vectors."""
    a = 2.0 * np.asarray(u, np.float64) - 1.0
    b = 2.0 * np.asarray(v, np.float64) - 1.0
    ap, bp = np.abs(a), np.abs(b)
    signed_distance = 1.0 - (ap + bp)
    r = 1.0 - np.abs(signed_distance)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(r > 0, ((bp - ap) / np.where(r > 0, r, 1.0) + 1.0) * np.pi / 4, np.pi / 4)
    z = np.where(signed_distance >= 0, 1.0 - r * r, -(1.0 - r * r))
    cos_phi = np.where(a >= 0, np.cos(phi), -np.cos(phi))
    sin_phi = np.where(b >= 0, np.sin(phi), -np.sin(phi))
    s = r * np.sqrt(np.maximum(0.0, 2.0 - r * r))
    return np.stack([cos_phi * s, sin_phi * s, z], axis=-1)


def equal_area_sphere_to_square_np(d: np.ndarray) -> np.ndarray:
    """numpy twin of equal_area_sphere_to_square: (N, 3) unit vectors -> (N, 2) in [0,1]."""
    d = np.asarray(d, np.float64).reshape(-1, 3)
    x, y, z = np.abs(d[:, 0]), np.abs(d[:, 1]), np.abs(d[:, 2])
    r = np.sqrt(np.maximum(0.0, 1.0 - z))
    phi = np.arctan2(y, x) * (2.0 / np.pi)
    v = phi * r
    u = r - v
    lower = d[:, 2] < 0
    u, v = np.where(lower, 1.0 - v, u), np.where(lower, 1.0 - u, v)
    u = np.where(d[:, 0] >= 0, u, -u)
    v = np.where(d[:, 1] >= 0, v, -v)
    return np.stack([0.5 * (u + 1.0), 0.5 * (v + 1.0)], axis=-1)


def octahedral_wrap_np(i: np.ndarray, j: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """numpy twin of octahedral_wrap (for cells at most one step outside the grid)."""
    i, j = np.asarray(i).copy(), np.asarray(j).copy()
    out = (i < 0) | (i >= n)
    j = np.where(out, n - 1 - j, j)
    i = np.clip(i, 0, n - 1)
    out = (j < 0) | (j >= n)
    i = np.where(out, n - 1 - i, i)
    j = np.clip(j, 0, n - 1)
    return np.clip(i, 0, n - 1), j


def grid_cell_centers_np(n: int) -> np.ndarray:
    """(n*n, 3) float64 unit vectors: the positional samples, sample k = (row k // n, column k % n)."""
    centers = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(centers, centers)  # u varies along columns, v along rows
    return equal_area_square_to_sphere_np(u.ravel(), v.ravel())


def concentric_disk_to_square_np(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """numpy twin of concentric_disk_to_square: (N,) x (N,) on the unit disk -> (N, 2) in [0,1]."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    r = np.hypot(x, y)
    phi = np.arctan2(y, x)
    phi = np.where(phi < -np.pi / 4, phi + 2 * np.pi, phi)
    quarter = np.pi / 4
    a = np.select([phi < quarter, phi < 3 * quarter, phi < 5 * quarter],
                  [r, -(phi - np.pi / 2) * r / quarter, -r], -(phi - 1.5 * np.pi) * -r / quarter)
    b = np.select([phi < quarter, phi < 3 * quarter, phi < 5 * quarter],
                  [phi * r / quarter, r, (phi - np.pi) * -r / quarter], -r)
    return np.clip(np.stack([0.5 * (a + 1), 0.5 * (b + 1)], axis=-1), 0.0, 1.0)


def malley_direction_to_square_np(d: np.ndarray) -> np.ndarray:
    """numpy twin of malley_direction_to_square: (N, 3) with z >= 0 -> (N, 2) in [0,1]."""
    d = np.asarray(d, np.float64).reshape(-1, 3)
    r2 = d[:, 0] ** 2 + d[:, 1] ** 2
    scale = np.where(r2 > 1.0, 1.0 / np.sqrt(np.maximum(r2, 1e-300)), 1.0)
    return concentric_disk_to_square_np(d[:, 0] * scale, d[:, 1] * scale)


def cell_spacing_ratio_np(n: int) -> float:
    """Largest / smallest nearest-neighbour angle between the n*n cell centres (1 = perfectly even)."""
    from scipy.spatial import cKDTree

    centers = grid_cell_centers_np(n)
    distance, _ = cKDTree(centers).query(centers, k=2)
    chord = distance[:, 1]
    return float(chord.max() / chord.min())
