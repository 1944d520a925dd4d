"""preview/camera.py against USD's own camera math (Gf.Camera's frustum, an independent implementation of the
same projection), the aperture conform rule, look_at's frame and the automatic framing's fit."""

import math

import numpy as np
import pytest
from pxr import Gf
from tolerances import FLOAT32_STORAGE, FLOAT64_AMPLIFIED, FLOAT64_ROUNDING
from usdbake.preview.camera import AUTO_MARGIN, Camera, auto_camera, look_at

WIDTH, HEIGHT = 640, 480


def gf_pixels(camera: Camera, points: np.ndarray) -> np.ndarray:
    """Pixel coordinates by Gf: view and projection matrices of Gf.Camera's frustum, NDC -> pixels (y down)."""
    projection = Gf.Camera.Perspective if camera.projection == "perspective" else Gf.Camera.Orthographic
    gf = Gf.Camera(Gf.Matrix4d(camera.camera_to_world.tolist()), projection, camera.horizontal_aperture,
                   camera.vertical_aperture, camera.horizontal_aperture_offset, camera.vertical_aperture_offset,
                   camera.focal_length)
    frustum = gf.frustum
    matrix = frustum.ComputeViewMatrix() * frustum.ComputeProjectionMatrix()
    ndc = np.array([matrix.Transform(Gf.Vec3d(*p)) for p in points.tolist()])
    return np.stack([(ndc[:, 0] + 1) / 2 * WIDTH, (1 - ndc[:, 1]) / 2 * HEIGHT], axis=1)


def random_camera(rng, projection="perspective") -> Camera:
    eye = rng.uniform(-5, 5, 3)
    return Camera(look_at(eye, eye + rng.normal(size=3), [0, 1, 0]), focal_length=rng.uniform(20, 80),
                  horizontal_aperture=36.0, vertical_aperture=27.0, horizontal_aperture_offset=rng.uniform(-2, 2),
                  vertical_aperture_offset=rng.uniform(-2, 2), projection=projection)


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_projection_matches_gf_camera(projection):
    rng = np.random.default_rng(11)  # fixed: five cameras, points in front of each
    for _ in range(5):
        camera = random_camera(rng, projection)
        ahead = camera.eye - camera.basis[:, 2] * rng.uniform(1, 10, (50, 1)) + rng.normal(scale=0.5, size=(50, 3))
        pixels, depth = camera.project(ahead, WIDTH, HEIGHT)
        # Gf.Camera keeps apertures and focal length as float32: pixels agree to its rounding.
        np.testing.assert_allclose(pixels, gf_pixels(camera, ahead), rtol=0, atol=FLOAT32_STORAGE * WIDTH)
        np.testing.assert_allclose(depth, (camera.eye - ahead) @ camera.basis[:, 2], rtol=FLOAT64_ROUNDING)


def test_conform_expands_the_aperture_to_the_image_aspect_and_never_crops():
    camera = Camera(np.eye(4), horizontal_aperture=36.0, vertical_aperture=24.0)
    wide = camera.conformed(1000, 400)  # wider than 3:2: the horizontal aperture grows
    tall = camera.conformed(400, 1000)  # taller: the vertical one grows
    assert (wide.horizontal_aperture, wide.vertical_aperture) == (60.0, 24.0)
    assert (tall.horizontal_aperture, tall.vertical_aperture) == (36.0, 90.0)
    with pytest.raises(ValueError, match="must be positive"):
        Camera(np.eye(4), vertical_aperture=0.0).conformed(10, 10)


@pytest.mark.parametrize("up", [[0, 1, 0], [0, 0, 1]])
def test_look_at_gives_a_right_handed_frame_looking_at_the_target(up):
    eye, target = np.array([3.0, 2.0, 5.0]), np.array([0.5, -1.0, 0.0])
    matrix = look_at(eye, target, up)
    camera = Camera(matrix)
    np.testing.assert_allclose(camera.basis.T @ camera.basis, np.eye(3), atol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(np.linalg.det(camera.basis), 1.0, rtol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(-camera.basis[:, 2], (target - eye) / np.linalg.norm(target - eye),
                               atol=FLOAT64_ROUNDING)
    assert camera.basis[:, 1] @ np.asarray(up, float) > 0  # the image's up leans towards the world's
    pixel, _ = camera.project(target, WIDTH, HEIGHT)
    np.testing.assert_allclose(pixel[0], [WIDTH / 2, HEIGHT / 2], atol=FLOAT64_AMPLIFIED * WIDTH)
    straight_down = Camera(look_at([0, 5, 0], [0, 0, 0], [0, 1, 0]))  # along the up vector: any roll
    np.testing.assert_allclose(-straight_down.basis[:, 2], [0, -1, 0], atol=FLOAT64_ROUNDING)


@pytest.mark.parametrize("up_axis, size", [("Y", [4.0, 1.0, 2.0]), ("Z", [1.0, 1.0, 10.0]), ("Z", [50.0, 0.01, 3.0])])
def test_auto_camera_frames_every_corner_with_the_margin(up_axis, size):
    """All eight corners land inside the frame, and the tightest one at 1 / AUTO_MARGIN of the half-frame:
    the camera stands exactly as far as the framing needs."""
    lo = np.array([-1.0, 2.0, 0.5])
    hi = lo + np.asarray(size)
    camera = auto_camera(lo, hi, up_axis, WIDTH, HEIGHT)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    pixels, depth = camera.project(corners, WIDTH, HEIGHT)
    assert (depth > 0).all()
    reach = np.abs(pixels - [WIDTH / 2, HEIGHT / 2]) / [WIDTH / 2, HEIGHT / 2]
    np.testing.assert_allclose(reach.max(), 1 / AUTO_MARGIN, rtol=FLOAT64_AMPLIFIED)
    up = np.array([0, 1.0, 0]) if up_axis == "Y" else np.array([0, 0, 1.0])
    elevation = math.degrees(math.asin(-camera.basis[:, 2] @ -up))
    np.testing.assert_allclose(elevation, 30.0, atol=FLOAT64_AMPLIFIED)  # looks down at the default 30 degrees
