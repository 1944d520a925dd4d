"""The preview camera: USD's pinhole camera in the Scene's local frame, and the automatic framing.

Camera model (``Camera``): camera space looks along -Z with +Y up; a pixel
centre (x, y) of a W x H image maps to the film point
((x + 0.5) / W - 0.5) * horizontalAperture + horizontalApertureOffset,
(0.5 - (y + 0.5) / H) * verticalAperture + verticalApertureOffset at
distance focalLength: the same projection Gf.Frustum computes. When the
image aspect differs from the aperture's, the aperture is expanded
(CameraUtil's ``expandAperture`` conform policy) so nothing the camera sees
is cropped. Orthographic cameras use the aperture in tenths of a stage unit,
as Gf.Camera does. The clipping range is not applied.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class Camera:
    """A USD-style camera in the Scene's local frame (``world = scene.origin + local``).

    Apertures and focal length in the same unit (USD: mm, i.e. tenths of a stage unit);
    only their ratio matters for a perspective camera.
    """

    camera_to_world: np.ndarray
    """(4, 4) float64 row-vector matrix (as Gf): camera space -> scene-local space."""
    focal_length: float = 50.0
    horizontal_aperture: float = 20.955
    vertical_aperture: float = 15.2908
    horizontal_aperture_offset: float = 0.0
    vertical_aperture_offset: float = 0.0
    projection: str = "perspective"
    """'perspective' or 'orthographic'."""

    @property
    def eye(self) -> np.ndarray:
        return np.asarray(self.camera_to_world, np.float64)[3, :3]

    @property
    def basis(self) -> np.ndarray:
        """(3, 3) float64 with the camera's x, y, z axes (scene space) as columns."""
        return np.asarray(self.camera_to_world, np.float64)[:3, :3].T

    def conformed(self, width: int, height: int) -> "Camera":
        """Expand the aperture so its aspect matches width / height (CameraUtil expandAperture)."""
        aspect = width / height
        h, v = self.horizontal_aperture, self.vertical_aperture
        if v <= 0 or h <= 0:
            raise ValueError(f"camera aperture {h} x {v} must be positive")
        if h / v < aspect:
            h = v * aspect
        else:
            v = h / aspect
        return replace(self, horizontal_aperture=h, vertical_aperture=v)

    def project(self, points: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (x right, y down; pixel centres at .5) and camera depth of scene-local points.

        Uses the camera as given (call ``conformed`` first when the aspect differs).
        Returns ((N, 2) float64, (N,) float64 depth along -Z).
        """
        points = np.asarray(points, np.float64).reshape(-1, 3)
        local = (points - self.eye) @ self.basis  # coordinates along the camera axes
        depth = -local[:, 2]
        if self.projection == "orthographic":
            film = local[:, :2] * 10.0
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                film = local[:, :2] * (self.focal_length / depth)[:, None]
        x = ((film[:, 0] - self.horizontal_aperture_offset) / self.horizontal_aperture + 0.5) * width
        y = (0.5 - (film[:, 1] - self.vertical_aperture_offset) / self.vertical_aperture) * height
        return np.stack([x, y], axis=1), depth


def look_at(eye, target, up) -> np.ndarray:
    """(4, 4) row-vector camera-to-world matrix looking from eye at target (camera -Z forward)."""
    eye, target, up = (np.asarray(a, np.float64) for a in (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    if np.linalg.norm(right) < 1e-9:  # looking along up: pick any perpendicular
        right = np.cross(np.array([1.0, 0.0, 0.0]) if abs(back[0]) < 0.9 else np.array([0.0, 1.0, 0.0]), back)
    right /= np.linalg.norm(right)
    true_up = np.cross(back, right)
    matrix = np.eye(4)
    matrix[0, :3], matrix[1, :3], matrix[2, :3], matrix[3, :3] = right, true_up, back, eye
    return matrix


AUTO_AZIMUTH_DEG = 35.0
"""Auto camera: angle from the stage's front axis (+Z for Y-up, -Y for Z-up) towards +X."""
AUTO_ELEVATION_DEG = 30.0
"""Auto camera: angle above the horizon."""
AUTO_MARGIN = 1.06
"""Auto camera: the bounds fill 1 / 1.06 of the frame."""


def auto_camera(bounds_min, bounds_max, up_axis: str, width: int, height: int, *,
                azimuth_deg: float = AUTO_AZIMUTH_DEG, elevation_deg: float = AUTO_ELEVATION_DEG,
                focal_length: float = 35.0, horizontal_aperture: float = 36.0) -> Camera:
    """A three-quarter perspective view that frames the box [bounds_min, bounds_max] (scene-local).

    The camera looks at the box centre from ``azimuth_deg`` around the up axis and
    ``elevation_deg`` above the horizon, far enough that all eight corners project
    inside the frame (with AUTO_MARGIN).
    """
    lo, hi = np.asarray(bounds_min, np.float64), np.asarray(bounds_max, np.float64)
    center = (lo + hi) / 2
    if up_axis == "Z":
        up, front, side = np.array([0, 0, 1.0]), np.array([0, -1.0, 0]), np.array([1.0, 0, 0])
    else:
        up, front, side = np.array([0, 1.0, 0]), np.array([0, 0, 1.0]), np.array([1.0, 0, 0])
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    toward_eye = math.cos(el) * (math.cos(az) * front + math.sin(az) * side) + math.sin(el) * up
    orientation = look_at(center + toward_eye, center, up)
    camera = Camera(orientation, focal_length=focal_length, horizontal_aperture=horizontal_aperture,
                    vertical_aperture=horizontal_aperture * height / width)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    local = (corners - center) @ orientation[:3, :3].T  # right, up, back components
    tan_h = camera.horizontal_aperture / 2 / focal_length
    tan_v = camera.vertical_aperture / 2 / focal_length
    # A corner at lateral offset x and depth offset b (towards the eye) fits when |x| <= tan * (dist - b).
    needed = np.maximum(np.abs(local[:, 0]) * AUTO_MARGIN / tan_h, np.abs(local[:, 1]) * AUTO_MARGIN / tan_v)
    distance = float(np.max(needed + local[:, 2]))
    distance = max(distance, 1e-6 + float(np.linalg.norm(hi - lo)))
    return replace(camera, camera_to_world=look_at(center + toward_eye * distance, center, up))

