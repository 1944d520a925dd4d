"""processors.instancing.transforms: the rigid motion between two copies of one shape, and its quaternion."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from instanced_scenes import icosphere
from tolerances import FLOAT64_ROUNDING

from usdbake.processors.instancing.transforms import rigid_alignment, rotation_quaternion


def random_rotation(rng) -> np.ndarray:
    """(3, 3) proper rotation, uniformly random (QR of a Gaussian matrix, signs fixed)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def motion(rotation, translation) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[3, :3] = rotation, translation
    return m


def moved(points, matrix) -> np.ndarray:
    return points @ matrix[:3, :3] + matrix[3, :3]


SHAPE = icosphere(1)[0] * [1.0, 0.6, 0.3] + [0.2, 0.0, 0.0]


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2 ** 32 - 1))
def test_a_rigid_motion_is_recovered(seed):
    rng = np.random.default_rng(seed)  # hypothesis draws the seed: reproducible on failure
    truth = motion(random_rotation(rng), rng.uniform(-10, 10, 3))
    found = rigid_alignment(SHAPE, moved(SHAPE, truth), tolerance=1e-9)
    assert found is not None
    np.testing.assert_allclose(found, truth, atol=FLOAT64_ROUNDING * 100)  # SVD of a 3x3: ~1e-14 each


def test_identity_and_translation_are_exact():
    assert (rigid_alignment(SHAPE, SHAPE, tolerance=0.0) == np.eye(4)).all()
    shifted = rigid_alignment(SHAPE, SHAPE + [1.0, 2.0, 3.0], tolerance=1e-12)
    assert (shifted[:3, :3] == np.eye(3)).all()
    np.testing.assert_allclose(shifted[3, :3], [1.0, 2.0, 3.0], rtol=FLOAT64_ROUNDING)


def test_noise_below_the_tolerance_matches_and_above_it_does_not():
    rng = np.random.default_rng(3)  # fixed seed: reproducible noise
    truth = motion(random_rotation(rng), [0.5, -1.0, 2.0])
    noisy = moved(SHAPE, truth) + rng.normal(size=SHAPE.shape) * 1e-6
    assert rigid_alignment(SHAPE, noisy, tolerance=1e-5) is not None
    assert rigid_alignment(SHAPE, noisy, tolerance=1e-7) is None


@pytest.mark.parametrize("change", ["mirror", "scale", "shape", "count"])
def test_mirrors_scales_and_other_shapes_do_not_match(change):
    other = {"mirror": SHAPE * [-1.0, 1.0, 1.0], "scale": SHAPE * 1.01,
             "shape": SHAPE * [1.0, 0.7, 0.3], "count": SHAPE[:-1]}[change]
    assert rigid_alignment(SHAPE, other, tolerance=1e-6) is None


def test_symmetric_and_planar_shapes_match_whatever_rotation_fits():
    """A cube turned by 90 degrees about z, and a flat square turned in its plane: Kabsch's rotation is not
    unique for them, but the one found must fit point for point."""
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    quarter = motion(np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1]], float), [3, 0, 0])
    found = rigid_alignment(cube, moved(cube, quarter), tolerance=1e-9)
    np.testing.assert_allclose(moved(cube, found), moved(cube, quarter), atol=FLOAT64_ROUNDING)
    square = cube[cube[:, 2] == 0]
    found = rigid_alignment(square, moved(square, quarter), tolerance=1e-9)
    assert found is not None and np.linalg.det(found[:3, :3]) > 0


def test_non_finite_points_do_not_match():
    broken = SHAPE.copy()
    broken[0, 0] = np.nan
    assert rigid_alignment(SHAPE, broken, tolerance=1.0) is None


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2 ** 32 - 1))
def test_quaternion_is_gf_s(seed):
    """The quaternion of a row-vector rotation is the one USD's Gf extracts from the same matrix."""
    from pxr import Gf

    rotation = random_rotation(np.random.default_rng(seed))  # hypothesis draws the seed
    q = rotation_quaternion(rotation)
    gf = Gf.Matrix4d(Gf.Matrix3d(*rotation.ravel().tolist()), Gf.Vec3d(0.0)).ExtractRotationQuat()
    expected = np.array([gf.GetReal(), *gf.GetImaginary()])
    expected = expected if expected[0] >= 0 else -expected
    np.testing.assert_allclose(q, expected, atol=FLOAT64_ROUNDING * 100)  # Gf's own float64 extraction
    # and it turns vectors as the matrix does: v' = v @ R = q v q*
    v = np.array([0.3, -0.4, 0.5])
    turned = Gf.Rotation(Gf.Quatd(*q)).TransformDir(Gf.Vec3d(*v))
    np.testing.assert_allclose(np.array(turned), v @ rotation, atol=FLOAT64_ROUNDING * 100)
