"""The gradient-ascent step of light-probe placement, one probe per thread (Sukys 3.1.2).

Each probe fits the gradient of the lighting-variation measure V to its Delaunay neighbours by weighted
least squares, (sum_j w dx dx^T) g = sum_j w (V_j - V_i) dx with dx = x_j - x_i and w = 1 / |dx|^2 (a
small ridge of 1e-9 of the trace keeps flat neighbourhoods solvable), and reports its mean edge length,
which scales its step.
"""

from __future__ import annotations

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False, "fuse_fp": False})


@wp.kernel
def variation_gradient_kernel(
    start: int,
    positions: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.float64),
    offsets: wp.array(dtype=int),
    neighbours: wp.array(dtype=int),
    gradient: wp.array(dtype=wp.vec3d),
    mean_edge: wp.array(dtype=wp.float64),
):
    """Probe i: g = (sum w dx dx^T + ridge I)^-1 sum w (V_j - V_i) dx over its neighbours (module docstring)."""
    i = start + wp.tid()
    x = positions[i]
    a = wp.mat33d()
    rhs = wp.vec3d()
    length = wp.float64(0.0)
    for k in range(offsets[i], offsets[i + 1]):
        j = neighbours[k]
        dx = positions[j] - x
        d2 = wp.max(wp.dot(dx, dx), wp.float64(1e-30))
        w = wp.float64(1.0) / d2
        a += w * wp.outer(dx, dx)
        rhs += (w * (v[j] - v[i])) * dx
        length += wp.sqrt(d2)
    degree = offsets[i + 1] - offsets[i]
    ridge = wp.float64(1e-9) * wp.max(a[0, 0] + a[1, 1] + a[2, 2], wp.float64(1e-30))
    a += ridge * wp.identity(n=3, dtype=wp.float64)
    gradient[i] = wp.inverse(a) * rhs
    mean_edge[i] = length / wp.float64(wp.max(degree, 1))


def variation_gradient(tracer, positions: np.ndarray, v: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares gradient of V per probe from its edge neighbours (P, 3), and mean edge length (P,),
    on the tracer's device (its threads)."""
    positions = np.asarray(positions, np.float64).reshape(-1, 3)
    p = len(positions)
    both = np.concatenate([edges, edges[:, ::-1]]) if len(edges) else np.zeros((0, 2), np.int64)
    both = both[np.lexsort((both[:, 1], both[:, 0]))]
    offsets = np.zeros(p + 1, np.int32)
    np.cumsum(np.bincount(both[:, 0], minlength=p), out=offsets[1:])
    gradient = wp.zeros(p, dtype=wp.vec3d, device=tracer.device)
    mean_edge = wp.zeros(p, dtype=wp.float64, device=tracer.device)
    tracer.launch(variation_gradient_kernel, p, [
        tracer.array(positions, wp.vec3d), tracer.array(np.asarray(v, np.float64), wp.float64),
        tracer.array(offsets, int), tracer.array(both[:, 1].astype(np.int32), int), gradient, mean_edge])
    return gradient.numpy(), mean_edge.numpy()
