"""processors/light_probes/capture.py: probe SH against closed forms written here (uniform and half domes,
a delta light's clamped-cosine bands by the addition theorem), the direct-light irradiance against the
sphere light's closed form, the 26-ray inside vote, and chunks that seed as the whole run does."""

import math

import numpy as np
import pytest
from lit_scenes import cube, make_lights, make_scene, merge, quad
from tolerances import DIRECT_TOLERANCE, FLOAT32_LONG_CHAIN, FLOAT32_STORAGE, MC_SIGMAS
from usdbake.core.scene import LIGHT_DISTANT, LIGHT_DOME, LIGHT_SPHERE, Lights
from usdbake.kernels.light_bundles import scene_lighting
from usdbake.kernels.tracer import Tracer
from usdbake.processors.light_probes.capture import (classify_points, compute_probe_sh, direct_light_irradiance,
                                                     probe_sh_chunk)

RAYS = 4096
"""Capture rays per probe (64 x 64 strata)."""

MARKER = quad([40, 40, -40], [0.1, 0, 0], [0, 0.1, 0])
"""A tiny far quad: the ray core needs a triangle, and this one is practically never hit."""

Y0 = 0.5 / math.sqrt(math.pi)
"""The constant real spherical harmonic, 1 / (2 sqrt(pi))."""

BANDS = (slice(0, 1), slice(1, 4), slice(4, 9))


def open_scene(lights: Lights):
    points, tris = merge([MARKER])
    return make_scene(points, tris, lights=lights)


def dome(radiance, texture=None) -> Lights:
    return Lights(light_paths=("/World/Dome",), light_kind=np.array([LIGHT_DOME], np.int32),
                  light_radiance=np.full((1, 3), radiance, np.float32), light_position=np.zeros((1, 3), np.float32),
                  light_direction=np.array([[0, 0, -1]], np.float32), light_size=np.zeros((1, 2), np.float32),
                  dome_source=texture)


def band_norms(sh: np.ndarray) -> np.ndarray:
    """(3,) Euclidean norm of each band's coefficients (channel 0): rotation invariant."""
    return np.array([np.linalg.norm(sh[band, 0]) for band in BANDS])


def test_uniform_dome_gives_pi_l_on_every_plane():
    """L00 = 2 sqrt(pi) L exactly (every ray sees L); E = A0 L00 Y0 = pi L. Higher radiance coefficients are
    Monte Carlo noise: the estimator 4 pi L Y_lm(w) has variance 4 pi L^2 (orthonormal Y) per ray."""
    radiance = 1.5
    scene = open_scene(dome(radiance))
    sh = compute_probe_sh(Tracer.from_scene(scene), scene, np.zeros((1, 3)), rays=RAYS)[0]
    np.testing.assert_allclose(sh[0] * Y0, math.pi * radiance, rtol=FLOAT32_LONG_CHAIN)
    noise = MC_SIGMAS * radiance * math.sqrt(4 * math.pi / RAYS)
    assert np.abs(sh[1:]).max() <= 2 * math.pi / 3 * noise  # A1 = 2 pi / 3 is the largest A_l after band 0


def test_half_dome_bands_match_the_hemisphere_integrals():
    """Radiance L over the dome's upper half (+Y): L00 = sqrt(pi) L, the band-1 vector has length
    C1 pi L (C1 = 0.488603: integral of C1 y over the half sphere), band 2 vanishes (integral of
    3 y^2 - 1 over it is 0). Each ray's estimate 4 pi L V Y_lm has E[X^2] = 4 pi L^2 int_upper Y_lm^2 = 2 pi L^2
    (Y_lm^2 is even in y), so each coefficient has standard deviation at most L sqrt(2 pi / rays), a band's
    error vector about sqrt(2l + 1) times that."""
    radiance = 2.0
    texture = np.zeros((8, 4, 3), np.float32)
    texture[:4] = 1.0
    scene = open_scene(dome(radiance, texture))
    irradiance_sh = compute_probe_sh(Tracer.from_scene(scene), scene, np.zeros((1, 3)), rays=RAYS)[0]
    lobe = np.array([math.pi, 2 * math.pi / 3, math.pi / 4])  # Ramamoorthi & Hanrahan's A_l
    radiance_bands = band_norms(irradiance_sh) / lobe
    c1 = math.sqrt(3 / (4 * math.pi))
    expected = np.array([math.sqrt(math.pi) * radiance, c1 * math.pi * radiance, 0.0])
    noise = MC_SIGMAS * radiance * math.sqrt(2 * math.pi / RAYS) * np.sqrt(2 * np.arange(3) + 1)
    np.testing.assert_array_less(np.abs(radiance_bands - expected), noise)


def test_a_delta_light_projects_as_its_clamped_cosine_bands():
    """A zero-angle distant light of irradiance L seen by a probe: radiance SH L Y_lm(w), so by the addition
    theorem (sum_m Y_lm^2 = (2l + 1) / 4 pi) band l of the irradiance SH has length A_l L sqrt((2l + 1) / 4 pi).
    No capture ray sees it: it comes only from the direct-light pass, and a decoupled cloud leaves it out."""
    radiance = 3.0
    scene = open_scene(make_lights((LIGHT_DISTANT, [radiance] * 3, [0, 0, 0], [0.6, 0.0, -0.8], [0, 0])))
    tracer = Tracer.from_scene(scene)
    sh = compute_probe_sh(tracer, scene, np.zeros((1, 3)), rays=64)[0]
    lobe = np.array([math.pi, 2 * math.pi / 3, math.pi / 4])
    expected = lobe * radiance * np.sqrt((2 * np.arange(3) + 1) / (4 * math.pi))
    np.testing.assert_allclose(band_norms(sh), expected, rtol=FLOAT32_STORAGE)
    assert not compute_probe_sh(tracer, scene, np.zeros((1, 3)), rays=64, direct_lights=False).any()


def test_direct_light_irradiance_of_a_sphere_light_matches_the_closed_form():
    """E = pi L sin^2(alpha) cos(beta) for a sphere wholly above the receiver's plane."""
    centre, radius, radiance = np.array([0.8, -0.3, 2.0]), 0.5, 4.0
    scene = open_scene(make_lights((LIGHT_SPHERE, [radiance] * 3, centre, [0, 0, -1], [radius, radius])))
    normal = np.array([0.0, 0.2, 1.0]) / math.hypot(0.2, 1.0)
    got = direct_light_irradiance(Tracer.from_scene(scene), scene, np.zeros((1, 3)), normal[None], samples=1024)
    distance = np.linalg.norm(centre)
    expected = math.pi * radiance * (radius / distance) ** 2 * (centre @ normal) / distance
    np.testing.assert_allclose(got[0], expected, rtol=DIRECT_TOLERANCE)


def test_inside_vote_and_nearest_hit():
    """A closed unit cube with outward (single-sided) faces: from its centre all 26 rays meet back faces,
    the nearest at 0.5 along an axis; from 1.5 above it, front faces, the nearest 1.0 straight down."""
    points, tris = cube([0, 0, 0], [1, 1, 1])
    scene = make_scene(points, tris)
    tracer = Tracer.from_scene(scene)
    inside, nearest = classify_points(tracer, scene_lighting(scene, tracer.device),
                                      np.array([[0.5, 0.5, 0.5], [0.5, 0.5, 2.0]]))
    assert inside.tolist() == [True, False]
    np.testing.assert_allclose(nearest, [0.5, 1.0], rtol=FLOAT32_STORAGE)


@pytest.mark.parametrize("first", [1, 3])
def test_a_chunk_seeds_its_probes_as_the_whole_run_does(first):
    """Probes first.. of a chunk get the rays they get in one run over all probes: results are identical
    however the work is split (core.chunks, farm)."""
    points, tris = cube([-3, -3, 0], [3, 3, 3], inward=True)
    scene = make_scene(points, tris, lights=make_lights((LIGHT_SPHERE, [5.0] * 3, [0, 0, 2.5], [0, 0, -1],
                                                         [0.3, 0.3])))
    tracer = Tracer.from_scene(scene)
    positions = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1.5], [-1, -1, 0.5], [2, 2, 2]], np.float32)
    whole = compute_probe_sh(tracer, scene, positions, rays=64, seed=4)
    chunk = probe_sh_chunk(tracer, first, positions[first:], scene=scene, rays=64, seed=4)
    np.testing.assert_array_equal(chunk, whole[first:])
    assert np.abs(whole).max() > 0
