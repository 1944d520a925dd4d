"""processors/light_probes/ascent.py on its own: ``variation_gradient`` against plain float64 numpy.

- a nonlinear V on a random cloud: each probe's gradient is the solution of its weighted normal equations
  (w = 1 / |dx|^2, ridge 1e-9 of the trace), assembled and solved here with numpy, and its mean edge length
  the mean of its edges' lengths (the linear-field case is in test_light_probe_clouds.py);
- the edge list's order and direction do not matter;
- a probe without neighbours gets a zero gradient and a zero mean edge; a probe with collinear neighbours
  (a singular system without the ridge) a finite gradient along their line.
"""

from __future__ import annotations

import numpy as np

from tolerances import FLOAT64_AMPLIFIED, FLOAT64_ROUNDING, LEAST_SQUARES_RIDGE
from usdbake.kernels.tracer import Tracer
from usdbake.processors.light_probes.ascent import variation_gradient


def any_tracer() -> Tracer:
    """The kernel only borrows the tracer's device and threads."""
    return Tracer(np.eye(3), np.array([[0, 1, 2]]))


def plain_gradient(positions, v, edges):
    """(P, 3) gradients and (P,) mean edge lengths, one probe at a time (module docstring)."""
    p = len(positions)
    gradient, mean_edge = np.zeros((p, 3)), np.zeros(p)
    for i in range(p):
        neighbours = [b for a, b in edges if a == i] + [a for a, b in edges if b == i]
        a, rhs, lengths = np.zeros((3, 3)), np.zeros(3), []
        for j in neighbours:
            dx = positions[j] - positions[i]
            w = 1.0 / max(dx @ dx, 1e-30)
            a += w * np.outer(dx, dx)
            rhs += w * (v[j] - v[i]) * dx
            lengths.append(np.linalg.norm(dx))
        a += 1e-9 * max(np.trace(a), 1e-30) * np.eye(3)
        gradient[i] = np.linalg.solve(a, rhs)
        mean_edge[i] = np.mean(lengths) if lengths else 0.0
    return gradient, mean_edge


def test_gradients_solve_each_probes_weighted_normal_equations():
    rng = np.random.default_rng(12)  # a random cloud, each probe joined to its 6 nearest others
    positions = rng.uniform(-1, 1, (60, 3))
    v = np.sin(2 * positions[:, 0]) + positions[:, 1] ** 2 - positions[:, 0] * positions[:, 2]
    distance = np.linalg.norm(positions[:, None] - positions[None], axis=2)
    nearest = np.argsort(distance, axis=1)[:, 1:7]
    edges = np.unique(np.sort(np.stack([np.repeat(np.arange(60), 6), nearest.ravel()], axis=1), axis=1), axis=0)
    gradient, mean_edge = variation_gradient(any_tracer(), positions, v, edges)
    expected, expected_edge = plain_gradient(positions, v, edges)
    assert gradient.shape == (60, 3) and mean_edge.shape == (60,)
    np.testing.assert_allclose(gradient, expected, rtol=FLOAT64_AMPLIFIED, atol=FLOAT64_AMPLIFIED)
    np.testing.assert_allclose(mean_edge, expected_edge, rtol=FLOAT64_ROUNDING)
    # shuffled and reversed edges: the same sums (in another order)
    shuffled = edges[rng.permutation(len(edges))][:, ::-1]
    again, again_edge = variation_gradient(any_tracer(), positions, v, shuffled)
    np.testing.assert_allclose(again, gradient, rtol=FLOAT64_AMPLIFIED, atol=FLOAT64_AMPLIFIED)
    np.testing.assert_allclose(again_edge, mean_edge, rtol=FLOAT64_ROUNDING)


def test_lonely_and_collinear_probes():
    positions = np.array([[0.0, 0, 0], [1.0, 0, 0], [-2.0, 0, 0], [5.0, 5, 5]])
    v = np.array([1.0, 3.0, -3.0, 7.0])
    edges = np.array([[0, 1], [0, 2]])
    gradient, mean_edge = variation_gradient(any_tracer(), positions, v, edges)
    assert np.isfinite(gradient).all()
    np.testing.assert_array_equal(gradient[3], 0.0)  # no neighbours
    assert mean_edge[3] == 0.0
    # probe 0: neighbours along x only; slope 2 both ways, so g = (2, 0, 0) (the ridge shrinks it by ~1e-9)
    np.testing.assert_allclose(gradient[0], [2.0, 0.0, 0.0], rtol=LEAST_SQUARES_RIDGE, atol=LEAST_SQUARES_RIDGE)
    np.testing.assert_allclose(mean_edge[:3], [1.5, 1.0, 2.0], rtol=FLOAT64_ROUNDING)
    # no edges at all
    gradient, mean_edge = variation_gradient(any_tracer(), positions, v, np.zeros((0, 2), np.int64))
    assert not gradient.any() and not mean_edge.any()
