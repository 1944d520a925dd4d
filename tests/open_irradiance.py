"""Direct irradiance at free points by the one light model, for the sky and dome tests.

A plain module (not a conftest). No ``from __future__ import annotations`` here: Warp reads the
kernel's annotations as objects.
"""

import numpy as np
import warp as wp

from usdbake.kernels.light_bundles import light_bundle
from usdbake.kernels.lights import Lights, direct_irradiance
from usdbake.kernels.tracer import Tracer
from usdbake.kernels.traversal import TraceScene


@wp.kernel
def irradiance_kernel(scene: TraceScene, lights: Lights, points: wp.array(dtype=wp.vec3),
                      normals: wp.array(dtype=wp.vec3), strata: int, sky_strata: int, epsilon: float,
                      seed: int, out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = direct_irradiance(scene, lights, points[i], normals[i], strata, sky_strata, epsilon,
                               wp.rand_init(seed, i))


def direct_irradiance_at(scene, points, normals, *, strata: int = 1, sky_strata: int = 64,
                         seed: int = 7) -> np.ndarray:
    """(N, 3) direct irradiance (``kernels.lights.direct_irradiance``) at points in the scene frame with unit
    normals, e.g. an open face under the scene's sky."""
    tracer = Tracer.from_scene(scene)
    points = np.asarray(points, np.float32).reshape(-1, 3)
    out = wp.zeros(len(points), dtype=wp.vec3, device=tracer.device)
    wp.launch(irradiance_kernel, dim=len(points), device=tracer.device,
              inputs=[tracer.scene, light_bundle(scene, tracer.device), tracer.array(points, wp.vec3),
                      tracer.array(np.asarray(normals, np.float32).reshape(-1, 3), wp.vec3), strata, sky_strata,
                      tracer.epsilon, seed, out])
    return out.numpy()
