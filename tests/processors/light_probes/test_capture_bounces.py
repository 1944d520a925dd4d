"""light_probes capture: bounces converge from below to the closed form of a glowing closed box.

Every inward wall of a closed box emits radiance L_e and reflects rho (Lambertian), with no other light.
The radiance leaving every wall is then the same everywhere, L = L_e (1 + rho + ... + rho^k) after k
bounces (each bounce multiplies the whole field by rho, since every direction from a wall sees a wall), and
L_e / (1 - rho) with all of them; a probe anywhere inside reads E(n) = pi L for every normal. Written here
from that series, not from the capture code.
"""

import math

import numpy as np
import pytest
from lit_scenes import cube, make_scene
from tolerances import MC_SIGMAS
from usdbake.kernels.sh import sh_basis_np
from usdbake.kernels.tracer import Tracer
from usdbake.processors.light_probes.capture import compute_probe_sh

RHO, EMISSION = 0.5, 2.0
AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)


@pytest.fixture(scope="module")
def glowing_box():
    points, tris = cube([0, 0, 0], [2, 2, 2], inward=True)
    scene = make_scene(points, tris, albedo=RHO, emission=np.full((len(tris), 3), EMISSION, np.float32))
    probes = np.random.default_rng(3).uniform(0.3, 1.7, (16, 3))
    return Tracer.from_scene(scene), scene, probes


@pytest.mark.parametrize("bounces", [1, 2, 3, 6])
def test_probe_irradiance_follows_the_bounce_series(glowing_box, bounces):
    tracer, scene, probes = glowing_box
    sh = compute_probe_sh(tracer, scene, probes, rays=1024, seed=5, bounces=bounces)
    e = np.einsum("dk,pkc->pdc", sh_basis_np(AXES), sh.astype(np.float64))[..., 0]  # (probes, 6 normals)
    expected = math.pi * EMISSION * sum(RHO ** j for j in range(bounces + 1))
    limit = math.pi * EMISSION / (1.0 - RHO)
    # MC_SIGMAS standard errors of the mean over 16 probes x 6 normals (measured 0.07 W/m^2, under the
    # series' next term up to k = 3, so an off-by-one bounce fails there) and float32 rounding.
    standard_error = e.std() / math.sqrt(e.size)
    assert abs(e.mean() - expected) <= MC_SIGMAS * standard_error + 1e-3 * expected, (e.mean(), expected)
    assert e.mean() <= limit * (1.0 + 1e-3)
