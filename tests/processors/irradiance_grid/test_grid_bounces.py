"""irradiance_grid bounce passes against the integrating-sphere relation of a closed box.

A closed box of single-sided inward faces with uniform albedo rho, lit from inside by a small sphere light
of radiance L and radius r (flux Phi = 4 pi^2 L r^2, all of it landing on the walls): every reflection sends
rho times the flux it received back onto the walls, so after k bounces the area-weighted mean irradiance on
the walls is exactly ``Phi / A (1 + rho + ... + rho^k)`` and converges from below to ``Phi / (A (1 - rho))``
(A: wall area). The grid's ``bounces = k`` carries light reflected k times; its indirect-only grid read on the
walls (as a bounce pass reads it) must follow ``Phi / A (rho + ... + rho^k)``: a pass that double-counted would
add too much, and a pass that read the black or sky-lit vertices beyond the walls would add too little or
too much. The expected values are the analytic sums, not the code under test.
"""

import numpy as np
import pytest
from lit_scenes import cube, make_lights, make_scene, merge, quad
from tolerances import GRID_LIMIT_SHARE, GRID_WALL_OFFSET
from usdbake.core.scene import LIGHT_DOME, LIGHT_SPHERE
from usdbake.kernels.direction24 import AXES
from usdbake.kernels.tracer import Tracer
from usdbake.processors.irradiance_grid import irradiance_grid as ig
from usdbake.processors.irradiance_grid.grid_irradiance import bounce_tail, compute_visible_irradiance
from usdbake.processors.irradiance_grid.vector_grid import grid_layout

SIDE, RHO, RADIANCE, RADIUS = 2.0, 0.5, 50.0, 0.05
LAMP = (0.7, 1.1, 0.9)
"""Off centre, so the first bounce's light is far from uniform."""
BOUNCES = (1, 2, 3, 5)

def wall_points(count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform points on the box's six walls and their inward normals."""
    rng = np.random.default_rng(seed)
    face, uv = rng.integers(0, 6, count), rng.random((count, 2)) * SIDE
    points, normals = np.zeros((count, 3)), np.zeros((count, 3))
    for f in range(6):
        rows, axis, upper = face == f, f // 2, f % 2
        others = [b for b in range(3) if b != axis]
        points[rows, axis] = SIDE * upper
        points[rows, others[0]], points[rows, others[1]] = uv[rows, 0], uv[rows, 1]
        normals[rows, axis] = 1.0 - 2.0 * upper
    return points.astype(np.float32), normals.astype(np.float32)


def lit_box(outside: bool):
    """The box and its lamp; ``outside`` adds a bright world the walls must keep out: a dome of radiance 20
    over a 40 m ground below the box (outside vertices of the grid then see E = rho pi 20 from the lawn)."""
    parts = [cube([0, 0, 0], [SIDE] * 3, inward=True)]
    lights = [(LIGHT_SPHERE, [RADIANCE] * 3, LAMP, [0, 0, -1], [RADIUS, RADIUS])]
    if outside:
        parts.append(quad([-20, -20, -0.01], [40, 0, 0], [0, 40, 0]))
        lights.append((LIGHT_DOME, [20.0] * 3, [0, 0, 0], [0, 0, -1], [0, 0]))
    return make_scene(*merge(parts), albedo=RHO, lights=make_lights(*lights))


@pytest.mark.parametrize("outside, grow, vertices", [(False, 0.0, 3000), (True, 0.3, 3000)])
def test_bounces_converge_from_below_to_the_integrating_sphere_limit(outside, grow, vertices):
    """Mean indirect light on the walls after k bounces: increasing, each partial sum Phi / A (rho + ... +
    rho^k) within GRID_WALL_OFFSET, and direct + indirect within GRID_LIMIT_SHARE of Phi / (A (1 - rho)) at 5
    bounces, never above it by more than the read's offset. With ``outside`` the grid reaches 0.3 m beyond the
    walls into a sky-lit world: none of it may leak in."""
    scene = lit_box(outside)
    tracer = Tracer.from_scene(scene)
    layout = grid_layout(np.full(3, -grow), np.full(3, SIDE + grow), vertices=vertices)
    points, normals = wall_points(2000, seed=1)  # fixed seed: wall sample points
    direct = 4.0 * np.pi ** 2 * RADIANCE * RADIUS ** 2 / (6.0 * SIDE ** 2)  # Phi / A
    limit = direct / (1.0 - RHO)
    means = []
    for bounces in BOUNCES:
        grid = ig.bake_grid(tracer, scene, layout, rays=256, seed=2, bounces=bounces, include_direct=False)
        indirect = compute_visible_irradiance(tracer, layout, grid.vectors, points, normals)
        means.append(float(indirect[:, 0].mean()))  # equal-area walls, area-uniform points: the area mean
        expected = direct * sum(RHO ** j for j in range(1, bounces + 1))
        assert abs(means[-1] / expected - 1.0) <= GRID_WALL_OFFSET, (bounces, means[-1], expected)
    assert all(a < b for a, b in zip(means, means[1:])), means
    totals = direct + np.array(means)
    assert totals.max() <= limit * (1.0 + GRID_WALL_OFFSET * (1.0 - RHO)), (totals, limit)
    assert abs(totals[-1] / limit - 1.0) <= GRID_LIMIT_SHARE, (totals, limit)


def test_three_passes_with_the_bounce_tail_reach_the_limit():
    """``extrapolate``: the last pass reads G_2 + dG_2 r / (1 - r), so bounces = 3 carries all bounces. Three
    passes without the tail hold rho + rho^2 + rho^3 of the series: 1 - rho^4 of the limit Phi / (A (1 - rho)).
    With it the walls' total is within GRID_LIMIT_SHARE of the limit and the tail supplies at least half of the
    missing rho^4 (measured 0.80 of it; the rest is the read's offset, GRID_WALL_OFFSET, in the passes)."""
    scene = lit_box(False)
    tracer = Tracer.from_scene(scene)
    layout = grid_layout(np.zeros(3), np.full(3, SIDE), vertices=3000)
    points, normals = wall_points(2000, seed=1)
    direct = 4.0 * np.pi ** 2 * RADIANCE * RADIUS ** 2 / (6.0 * SIDE ** 2)
    limit = direct / (1.0 - RHO)
    totals = {}
    for extrapolate in (False, True):
        grid = ig.bake_grid(tracer, scene, layout, rays=256, seed=2, bounces=3, extrapolate=extrapolate,
                            include_direct=False)
        totals[extrapolate] = direct + float(
            compute_visible_irradiance(tracer, layout, grid.vectors, points, normals)[:, 0].mean())
    assert abs(totals[True] / limit - 1.0) <= GRID_LIMIT_SHARE, (totals, limit)
    assert (totals[True] - totals[False]) / limit >= 0.5 * RHO ** 4, (totals, limit)
    base = np.broadcast_to(AXES[None, :, None, :], (2, 6, 3, 3)).astype(np.float32)  # light along each axis
    np.testing.assert_allclose(bounce_tail(np.zeros_like(base), base), base)  # one pass: nothing to add
    np.testing.assert_allclose(bounce_tail(np.zeros_like(base), base, 1.5 * base), 2.0 * base)  # r = 1/2
