"""processors.daylight.gather on its own: ``trace_gather`` between faces placed by hand.

- two parallel facing unit squares at distance d: the mean row sum of G over one square's faces is the
  closed-form form factor between parallel squares (Howell's catalog, C-11), within Monte Carlo noise; the
  downward square's rows and ground view add up to 1 face by face, the upward one's ground view is 0;
- an open upward plane lands nothing and sees no ground; a lone vertical face sees the ground with half
  its view; a face above whose back the rays meet lands nothing (one-sided surfaces);
- ``landing`` maps the tracer's triangles to faces (a tracer of a subset, in another order);
- chunked launches, progress, ``rays_cast`` and the seed;
- a pane of glass between the squares: G is the form factor weighted by Radiance's falloff, against a
  float64 Gauss-Legendre integral written here.
"""

from __future__ import annotations

import numpy as np
import pytest

from glass_reference import slab_transmittance
from patch_scenes import quad
from tolerances import CATALOG_FORM_FACTOR, FLOAT32_STORAGE, FLOAT64_ROUNDING, GRAZING_RAY_FLIPS, MC_SIGMAS
from usdbake.kernels.tracer import Tracer
from usdbake.processors.daylight import gather
from usdbake.processors.daylight.gather import trace_gather
from usdbake.processors.daylight.glazing import Glazing

UP = np.array([0.0, 0.0, 1.0])
RAYS = 1024
"""Gather rays per face: 32 faces x 1024 rays put 4 sigma of a form factor near 0.2 at 0.009."""


def parallel_squares_form_factor(side: float, distance: float) -> float:
    """Howell's C-11, directly opposed parallel rectangles a x b at distance c, with a = b = side."""
    x = y = side / distance
    return float(2.0 / (np.pi * x * y) * (
        0.5 * np.log((1 + x * x) * (1 + y * y) / (1 + x * x + y * y))
        + x * np.sqrt(1 + y * y) * np.arctan(x / np.sqrt(1 + y * y))
        + y * np.sqrt(1 + x * x) * np.arctan(y / np.sqrt(1 + x * x))
        - x * np.arctan(x) - y * np.arctan(y)))


def faces_of(*parts):
    """(F, 3, 3) corners and (F, 3) unit normals of quad() parts, in order."""
    corners = np.concatenate([points[tris] for points, tris in parts]).astype(np.float64)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(cross, axis=1, keepdims=True)
    normals = np.where(length > 0, cross / np.where(length > 0, length, 1.0), 0.0)
    return corners, normals


def facing_squares(distance: float, grid: int = 4):
    """Square A = [0, 1]^2 at z = 0 facing up, square B above it at z = distance facing down."""
    lower = quad([0, 0, 0], [1, 0, 0], [0, 1, 0], grid)
    upper = quad([0, 0, distance], [0, 1, 0], [1, 0, 0], grid)
    return faces_of(lower, upper)


def tracer_of(corners, triangles=None) -> Tracer:
    """A tracer over the faces ``triangles`` (all by default) of ``corners``: tracer triangle t is that face."""
    count = len(corners)
    triangles = np.arange(count) if triangles is None else np.asarray(triangles)
    return Tracer(corners.reshape(-1, 3), (3 * triangles[:, None] + np.arange(3)).astype(np.int32))


def bernoulli_bound(p: float, rays: int) -> float:
    """MC_SIGMAS standard deviations of a mean of ``rays`` variables in [0, 1] with mean p."""
    return MC_SIGMAS * np.sqrt(max(p * (1 - p), 1.0 / rays) / rays)


def test_closed_form_reproduces_howells_catalog():
    assert abs(parallel_squares_form_factor(1.0, 1.0) - 0.19982) < CATALOG_FORM_FACTOR


@pytest.mark.parametrize("distance", [0.5, 1.0, 2.0])
def test_facing_squares_exchange_the_closed_form_form_factor(distance):
    corners, normals = facing_squares(distance)
    half = len(corners) // 2
    result = trace_gather(tracer_of(corners), corners, normals, rays=RAYS, up=UP, landing=np.arange(len(corners)))
    g = result.matrix.toarray().astype(np.float64)
    assert g.shape == (2 * half, 2 * half) and result.rays == RAYS
    expected = parallel_squares_form_factor(1.0, distance)
    for rows in (slice(0, half), slice(half, None)):  # equal faces: the row mean is the area-weighted one
        assert g[rows].sum(axis=1).mean() == pytest.approx(expected, abs=bernoulli_bound(expected, half * RAYS))
    # the rays of a square land on the other square only (a plane never sees itself)
    assert not g[:half, :half].any() and not g[half:, half:].any()
    # without glass every landing weighs 1: entries are whole numbers of rays over RAYS
    np.testing.assert_allclose(g * RAYS, np.rint(g * RAYS), atol=FLOAT32_STORAGE * RAYS)
    # A looks up, so none of its rays goes below the horizon; every ray of B that misses A does
    assert not result.ground_view[:half].any()
    np.testing.assert_allclose(g[half:].sum(axis=1) + result.ground_view[half:], 1.0, atol=FLOAT32_STORAGE)


def test_an_open_upward_plane_lands_nothing_and_sees_no_ground():
    corners, normals = faces_of(quad([0, 0, 0], [1, 0, 0], [0, 1, 0], 3))
    result = trace_gather(tracer_of(corners), corners, normals, rays=64, up=UP, landing=np.arange(len(corners)))
    assert result.matrix.nnz == 0
    assert result.ground_view.shape == (len(corners),) and result.ground_view.dtype == np.float32
    assert not result.ground_view.any()


def test_a_lone_vertical_face_sees_the_ground_with_half_its_view():
    corners, normals = faces_of(quad([0, 0, 0], [0, 0, 1], [1, 0, 0], 2))  # normal +y
    rays = 512
    result = trace_gather(tracer_of(corners), corners, normals, rays=rays, up=UP, landing=np.arange(len(corners)))
    assert result.matrix.nnz == 0
    bound = bernoulli_bound(0.5, len(corners) * rays)
    assert result.ground_view.mean() == pytest.approx(0.5, abs=bound)
    # the same face with the scene's up along its normal: nothing below the horizon
    sideways = trace_gather(tracer_of(corners), corners, normals, rays=rays, up=np.array([0.0, 1.0, 0.0]),
                            landing=np.arange(len(corners)))
    assert not sideways.ground_view.any()


def test_rays_that_meet_the_back_of_a_face_land_nowhere():
    """Both squares face up: A's rays meet B's back (blocked: one-sided faces reflect from the front only),
    B's rays escape to the sky. No landing, no ground."""
    lower = quad([0, 0, 0], [1, 0, 0], [0, 1, 0], 2)
    upper = quad([0, 0, 1], [1, 0, 0], [0, 1, 0], 2)
    corners, normals = faces_of(lower, upper)
    assert (normals[:, 2] > 0).all()
    result = trace_gather(tracer_of(corners), corners, normals, rays=256, up=UP, landing=np.arange(len(corners)))
    assert result.matrix.nnz == 0 and not result.ground_view.any()


def test_landing_maps_tracer_triangles_to_faces():
    """A tracer of B's faces only, in reverse order, with ``landing`` naming each one's face: A's rows are
    those of the tracer over every face (up to rays that graze B's inner edges); B's rays, with A gone,
    all leave below the horizon."""
    corners, normals = facing_squares(1.0, grid=2)
    half = len(corners) // 2
    upper = np.arange(half, 2 * half)[::-1]
    rays = 256
    full = trace_gather(tracer_of(corners), corners, normals, rays=rays, up=UP, landing=np.arange(len(corners)))
    part = trace_gather(tracer_of(corners, upper), corners, normals, rays=rays, up=UP, landing=upper)
    np.testing.assert_allclose(part.matrix.toarray()[:half], full.matrix.toarray()[:half],
                               atol=GRAZING_RAY_FLIPS / rays)
    assert full.matrix.toarray()[:half, half:].sum() > 0  # the comparison is not of two empty blocks
    assert part.matrix[half:].nnz == 0
    np.testing.assert_allclose(part.ground_view[half:], 1.0, atol=FLOAT32_STORAGE)


def test_chunked_launches_progress_and_ray_count(monkeypatch):
    """Launches of 5 faces draw the same rays as one launch (each face seeds its own stream)."""
    corners, normals = facing_squares(1.0, grid=2)
    rays = 64
    whole = trace_gather(tracer_of(corners), corners, normals, rays=rays, up=UP, landing=np.arange(len(corners)))
    monkeypatch.setattr(gather, "FACES_PER_LAUNCH", 5)
    tracer, steps = tracer_of(corners), []
    chunked = trace_gather(tracer, corners, normals, rays=rays, up=UP, landing=np.arange(len(corners)),
                           progress=steps.append)
    np.testing.assert_array_equal(chunked.matrix.toarray(), whole.matrix.toarray())
    np.testing.assert_array_equal(chunked.ground_view, whole.ground_view)
    assert len(steps) == -(-len(corners) // 5) and np.all(np.diff(steps) > 0) and steps[-1] == 1.0
    assert tracer.rays_cast == len(corners) * rays
    degenerate = np.concatenate([normals, np.zeros((1, 3), np.float32)])
    counted = tracer_of(corners)
    trace_gather(counted, np.concatenate([corners, corners[:1]]), degenerate, rays=rays, up=UP,
                 landing=np.arange(len(corners)))
    assert counted.rays_cast == len(corners) * rays  # the zero-normal face casts none


def test_the_seed_changes_the_rays_and_repeats_them():
    corners, normals = facing_squares(1.0, grid=2)
    landing = np.arange(len(corners))
    run = lambda seed: trace_gather(tracer_of(corners), corners, normals, rays=64, up=UP, landing=landing,  # noqa: E731
                                    seed=seed).matrix.toarray()
    np.testing.assert_array_equal(run(3), run(3))
    assert not np.array_equal(run(3), run(4))


def test_a_degenerate_face_casts_nothing():
    corners, normals = facing_squares(1.0, grid=1)
    corners = np.concatenate([corners, np.zeros((1, 3, 3))])  # a face of zero area and zero normal
    normals = np.concatenate([normals, np.zeros((1, 3))])
    result = trace_gather(tracer_of(corners[:-1]), corners, normals, rays=64, up=UP,
                          landing=np.arange(len(corners) - 1))
    assert result.matrix.shape == (len(corners), len(corners))
    assert result.matrix[-1].nnz == 0 and result.ground_view[-1] == 0.0
    assert result.matrix[:2].sum() > 0


def glazed_form_factor(distance: float, vlt: float, nodes: int = 48) -> float:
    """(1 / A) int_A int_B T(cos) cos^2 / (pi r^2) dB dA between the facing unit squares, a pane parallel to
    them crossed at the angle of incidence cos = distance / r. With u the offset between the two points,
    the double area integral is int_{[-1,1]^2} (1 - |u_x|)(1 - |u_y|) g(u) du, and g is even in u_x, u_y."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    x, w = 0.5 * (x + 1.0), 0.5 * w  # [0, 1]
    ux, uy = np.meshgrid(x, x, indexing="ij")
    r2 = ux ** 2 + uy ** 2 + distance ** 2
    cos = distance / np.sqrt(r2)
    integrand = (1 - ux) * (1 - uy) * slab_transmittance(cos, vlt) * distance ** 2 / (np.pi * r2 ** 2)
    return float(4.0 * w @ integrand @ w)


def test_a_pane_between_the_squares_weighs_each_landing_by_its_transmittance():
    distance, vlt = 1.0, 0.6
    # the quadrature reproduces the closed form with the pane taken away (VLT 1 above the clear pane's is
    # its falloff scaled, not 1, so compare a transmittance of exactly 1 through the integrand's other parts)
    x, w = np.polynomial.legendre.leggauss(48)
    x, w = 0.5 * (x + 1.0), 0.5 * w
    ux, uy = np.meshgrid(x, x, indexing="ij")
    r2 = ux ** 2 + uy ** 2 + distance ** 2
    open_value = 4.0 * w @ ((1 - ux) * (1 - uy) * distance ** 2 / (np.pi * r2 ** 2)) @ w
    assert open_value == pytest.approx(parallel_squares_form_factor(1.0, distance), abs=FLOAT64_ROUNDING)

    corners, normals = facing_squares(distance)
    pane, _ = faces_of(quad([-1, -1, distance / 2], [3, 0, 0], [0, 3, 0], 1))
    faces = len(corners)
    everything = np.concatenate([corners, pane])
    transmittance = np.concatenate([np.zeros(faces), np.full(len(pane), vlt)])
    pane_normals = np.tile([0.0, 0.0, 1.0], (len(pane), 1))
    glazing = Glazing(everything.reshape(-1, 3), np.arange(3 * len(everything)).reshape(-1, 3),
                      np.concatenate([normals, pane_normals]), transmittance)
    result = trace_gather(tracer_of(corners), corners, normals, rays=RAYS, up=UP, landing=np.arange(faces),
                          glazing=glazing)
    g = result.matrix.toarray().astype(np.float64)
    expected = glazed_form_factor(distance, vlt)
    assert expected < vlt * parallel_squares_form_factor(1.0, distance)  # oblique rays lose more than VLT
    half = faces // 2
    for rows in (slice(0, half), slice(half, None)):
        assert g[rows].sum(axis=1).mean() == pytest.approx(expected, abs=bernoulli_bound(expected, half * RAYS))
    # the same rays without the pane land on the same faces; each landing crossed the pane once, at an
    # incidence between the normal (VLT) and the squares' farthest corners' (cos = d / sqrt(2 + d^2))
    open_g = trace_gather(tracer_of(corners), corners, normals, rays=RAYS, up=UP,
                          landing=np.arange(faces)).matrix.toarray().astype(np.float64)
    np.testing.assert_array_equal(g > 0, open_g > 0)
    steepest = float(slab_transmittance(distance / np.sqrt(2 + distance ** 2), vlt))
    assert (g <= vlt * open_g * (1 + FLOAT32_STORAGE)).all()
    assert (g >= steepest * open_g * (1 - FLOAT32_STORAGE)).all()
