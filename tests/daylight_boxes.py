"""Small daylight scenes built from quads (Z-up, metres), for the interreflection and glazing tests."""

from __future__ import annotations

import numpy as np

from usdbake.core.scene import Scene


def grid_quads(origin, u, v, nu: int, nv: int, keep=None) -> list[np.ndarray]:
    """nu x nv quads spanning origin + [0, 1] u + [0, 1] v (normal u x v); ``keep(a, b)`` of the cell
    centre's shares drops cells (openings)."""
    o, u, v = (np.asarray(x, np.float64) for x in (origin, u, v))
    out = []
    for i in range(nu):
        for j in range(nv):
            if keep is not None and not keep((i + 0.5) / nu, (j + 0.5) / nv):
                continue
            p = o + u * i / nu + v * j / nv
            out.append(np.array([p, p + u / nu, p + u / nu + v / nv, p + v / nv]))
    return out


def quad_scene(parts: list[tuple[list[np.ndarray], float, float]]) -> Scene:
    """One prim per part: (quads, grey albedo, transmittance)."""
    points, tris, prim, albedo, transmittance, starts = [], [], [], [], [], [0]
    for m, (quads, rho, tau) in enumerate(parts):
        q = np.asarray(quads, np.float32).reshape(-1, 4, 3)
        base = starts[-1] + 4 * np.arange(len(q))[:, None]
        tris.append(np.concatenate([base + [0, 1, 2], base + [0, 2, 3]]))
        points.append(q.reshape(-1, 3))
        prim += [m] * (2 * len(q))
        albedo += [rho] * (2 * len(q))
        transmittance += [tau] * (2 * len(q))
        starts.append(starts[-1] + 4 * len(q))
    points, tris = np.concatenate(points), np.concatenate(tris).astype(np.int32)
    c = points[tris].astype(np.float64)
    cross = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    double = np.linalg.norm(cross, axis=1)
    n, count = len(parts), len(tris)
    point_prim = np.repeat(np.arange(n), np.diff(starts)).astype(np.int32)
    return Scene(
        points=points, tri_vertices=tris, tri_normals=(cross / double[:, None]).astype(np.float32),
        tri_areas=(double / 2).astype(np.float32), tri_albedo=np.repeat(np.asarray(albedo, np.float32)[:, None], 3, 1),
        tri_emission=np.zeros((count, 3), np.float32), tri_prim=np.asarray(prim, np.int32),
        tri_face=np.zeros(count, np.int32), tri_instance=np.full(count, -1, np.int32),
        tri_double_sided=np.zeros(count, bool), point_prim=point_prim,
        prim_paths=tuple(f"/P{m}" for m in range(n)), prim_point_start=np.array(starts, np.int64),
        prim_face_count=np.array([len(p[0]) for p in parts], np.int32), prim_writable=np.ones(n, bool),
        prim_skip=np.zeros(n, bool), prim_surface=("",) * n, prim_to_world=np.repeat(np.eye(4)[None], n, axis=0),
        up_axis="Z", tri_transmittance=np.asarray(transmittance, np.float32))


def box_with_skylight(albedo: float, n: int = 12, hole: tuple[float, float] = (0.4, 0.6), glass: float = 0.0):
    """A closed unit box, every face inward, with a square skylight in its ceiling (open, or glazed with
    ``glass`` transmittance as a second prim)."""
    opening = lambda a, b: hole[0] < a < hole[1] and hole[0] < b < hole[1]  # noqa: E731
    walls = grid_quads((0, 0, 0), (1, 0, 0), (0, 1, 0), n, n)  # floor, facing up
    walls += grid_quads((0, 0, 1), (0, 1, 0), (1, 0, 0), n, n, lambda a, b: not opening(b, a))  # ceiling, down
    walls += grid_quads((0, 0, 0), (0, 0, 1), (1, 0, 0), n, n)  # y = 0, facing +y
    walls += grid_quads((0, 1, 0), (1, 0, 0), (0, 0, 1), n, n)  # y = 1, facing -y
    walls += grid_quads((0, 0, 0), (0, 1, 0), (0, 0, 1), n, n)  # x = 0, facing +x
    walls += grid_quads((1, 0, 0), (0, 0, 1), (0, 1, 0), n, n)  # x = 1, facing -x
    parts = [(walls, albedo, 0.0)]
    if glass > 0:
        parts.append((grid_quads((0, 0, 1), (0, 1, 0), (1, 0, 0), n, n, lambda a, b: opening(b, a)), 0.0, glass))
    return quad_scene(parts)
