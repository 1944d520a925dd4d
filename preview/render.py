"""Preview rendering of baked data: a Warp ray caster through the shared Tracer's BVH.

Pure compute (no pxr): ``usdbake.stages.preview`` reads the stage, the camera
and the baked primvars, and hands this module arrays.

Pipeline, one pixel = one primary ray through the pixel centre:

1. ``primary_kernel`` casts the ray into ``Tracer.mesh`` (closest hit).
   Back faces of single-sided triangles are skipped (the ray continues
   behind them), as a rasterizer culls them: a closed room of inward-facing
   walls seen from outside becomes a cutaway.
2. ``shade_kernel`` interpolates per-corner values with the hit's
   barycentrics (vertex-interpolated data varies smoothly, uniform data is
   constant per face because its three corners hold the same value), the
   headlight cosine |n . d| and the wireframe mask: a pixel is on an edge of
   an authored polygon when its distance to that edge, ``b_k * h_k``
   (barycentric coordinate times the triangle height over the edge), is
   below ``wire_width`` pixels at the hit distance. Diagonals that only
   split a polygon into triangles are not drawn.
3. Optional ``sphere_kernel``: analytic ray-sphere intersections for probe
   or grid points, binned into 16 x 16 pixel tiles so each pixel tests only
   the spheres that can cover it.
4. numpy: false colour (scalar channels) or shading + tone mapping (colour
   channels), legend, wire overlay.

Camera model (``Camera``): USD's pinhole camera. Camera space looks along
-Z with +Y up; a pixel centre (x, y) of a W x H image maps to the film point
((x + 0.5) / W - 0.5) * horizontalAperture + horizontalApertureOffset,
(0.5 - (y + 0.5) / H) * verticalAperture + verticalApertureOffset at
distance focalLength: the same projection Gf.Frustum computes. When the
image aspect differs from the aperture's, the aperture is expanded
(CameraUtil's ``expandAperture`` conform policy) so nothing the camera sees
is cropped. Orthographic cameras use the aperture in tenths of a stage unit,
as Gf.Camera does. The clipping range is not applied.

Tone mapping (colour channels): ``linear * 2^EV`` then the ACES filmic fit
of Narkowicz (2015), f(x) = x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14)
clamped to [0, 1], then the sRGB transfer function. With ``exposure=None``
the exposure is automatic: the median luminance of the shaded pixels maps
to 0.18 (middle grey) before the curve.

False colour (scalar channels): ``VIRIDIS``, 33 knots of the viridis map
(van der Walt & Smith, matplotlib), linearly interpolated; within 2.5/255 of
matplotlib's 256-entry table (checked in tests when matplotlib is present).
The map's output is display (sRGB) colour: no tone mapping. A legend bar
with tick labels is drawn with a built-in 3 x 5 bitmap font, so no font
files are needed.

References
----------
Narkowicz, K. (2015). ACES Filmic Tone Mapping Curve.
https://knarkowicz.wordpress.com/2016/01/06/aces-filmic-tone-mapping-curve/
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})

MAX_CULLED_LAYERS = wp.constant(32)
"""Back faces a primary ray may pass through before it gives up (a miss)."""

TILE = wp.constant(16)
"""Screen tile side (pixels) for binning spheres."""

BACKGROUND = np.array([0.16, 0.16, 0.17], np.float32)
"""Display colour of pixels that hit nothing."""

NO_DATA_GREY = 0.55
"""Display grey of surfaces that carry no value of the channel (times the headlight cosine)."""

WIRE_COLOR = np.array([0.02, 0.02, 0.02], np.float32)
WIRE_OPACITY = 0.85

DIFF_GAIN = 4.0
"""The difference panel of ``compare_images`` shows |A - B| * 4: an 8-bit step of 1/255 stays invisible,
a 0.05 difference reads as 20% grey."""

MIDDLE_GREY = 0.18

# Viridis at 33 evenly spaced knots (matplotlib's table rounded to 4 decimals).
VIRIDIS_KNOTS = np.array([
    (0.2670, 0.0049, 0.3294), (0.2770, 0.0503, 0.3757), (0.2823, 0.0950, 0.4173), (0.2829, 0.1359, 0.4534),
    (0.2788, 0.1755, 0.4834), (0.2706, 0.2141, 0.5071), (0.2590, 0.2515, 0.5247), (0.2450, 0.2877, 0.5373),
    (0.2297, 0.3224, 0.5457), (0.2143, 0.3556, 0.5512), (0.1994, 0.3876, 0.5546), (0.1856, 0.4186, 0.5568),
    (0.1727, 0.4488, 0.5579), (0.1607, 0.4785, 0.5581), (0.1490, 0.5081, 0.5572), (0.1378, 0.5375, 0.5549),
    (0.1276, 0.5669, 0.5506), (0.1206, 0.5964, 0.5436), (0.1206, 0.6258, 0.5335), (0.1323, 0.6550, 0.5197),
    (0.1579, 0.6838, 0.5017), (0.1966, 0.7118, 0.4792), (0.2461, 0.7389, 0.4520), (0.3041, 0.7647, 0.4199),
    (0.3692, 0.7889, 0.3829), (0.4401, 0.8111, 0.3410), (0.5160, 0.8312, 0.2943), (0.5958, 0.8487, 0.2433),
    (0.6785, 0.8637, 0.1895), (0.7624, 0.8764, 0.1371), (0.8456, 0.8873, 0.0997), (0.9261, 0.8973, 0.1041),
    (0.9932, 0.9062, 0.1439),
], np.float32)


def _viridis_table() -> np.ndarray:
    t = np.linspace(0.0, 1.0, 256)
    knots = np.linspace(0.0, 1.0, len(VIRIDIS_KNOTS))
    return np.stack([np.interp(t, knots, VIRIDIS_KNOTS[:, c]) for c in range(3)], axis=1).astype(np.float32)


VIRIDIS = _viridis_table()
"""(256, 3) float32 sRGB viridis table."""


# ---------------------------------------------------------------------------
# Kernels


@wp.kernel
def primary_kernel(
    start: int,
    mesh: wp.uint64,
    width: int,
    height: int,
    basis: wp.mat33,
    eye: wp.vec3,
    film: wp.vec4,
    focal_length: float,
    orthographic: int,
    tri_cull: wp.array(dtype=wp.int8),
    epsilon: float,
    hit_triangle: wp.array(dtype=int),
    hit_uv: wp.array(dtype=wp.vec2),
    hit_t: wp.array(dtype=float),
    ray_direction: wp.array(dtype=wp.vec3),
):
    """Closest front (or double-sided) hit of the ray through each pixel centre.

    film = (horizontal aperture, vertical aperture, horizontal offset, vertical offset);
    basis columns are the camera's x, y, z axes in scene space.
    """
    i = start + wp.tid()
    px = i % width
    py = i // width
    sx = ((float(px) + 0.5) / float(width) - 0.5) * film[0] + film[2]
    sy = (0.5 - (float(py) + 0.5) / float(height)) * film[1] + film[3]
    origin = eye
    direction = wp.vec3(0.0)
    if orthographic == 1:
        origin = eye + basis * wp.vec3(sx * 0.1, sy * 0.1, 0.0)
        direction = basis * wp.vec3(0.0, 0.0, -1.0)
    else:
        direction = wp.normalize(basis * wp.vec3(sx, sy, -focal_length))
    ray_direction[i] = direction
    hit_triangle[i] = -1
    hit_t[i] = wp.inf
    travelled = float(0.0)
    for layer in range(MAX_CULLED_LAYERS):
        q = wp.mesh_query_ray(mesh, origin, direction, 1.0e30)
        if not q.result:
            return
        if q.sign > 0.0 or tri_cull[q.face] == 0:
            hit_triangle[i] = q.face
            hit_uv[i] = wp.vec2(q.u, q.v)
            hit_t[i] = travelled + q.t
            return
        step = q.t + epsilon
        origin = origin + direction * step
        travelled = travelled + step


@wp.kernel
def shade_kernel(
    start: int,
    hit_triangle: wp.array(dtype=int),
    hit_uv: wp.array(dtype=wp.vec2),
    hit_t: wp.array(dtype=float),
    ray_direction: wp.array(dtype=wp.vec3),
    corner_values: wp.array(dtype=wp.vec3),
    tri_normals: wp.array(dtype=wp.vec3),
    tri_edge_heights: wp.array(dtype=wp.vec3),
    tri_edge_mask: wp.array(dtype=int),
    wire_world: float,
    wire_per_distance: float,
    value: wp.array(dtype=wp.vec3),
    facing: wp.array(dtype=float),
    wire: wp.array(dtype=wp.int8),
):
    """Barycentric interpolation of corner values, headlight cosine and polygon-edge mask per pixel.

    The hit point is u * v0 + v * v1 + (1 - u - v) * v2 (wp.mesh_query_ray's convention), so
    the barycentric weight of corner 0 is u, of corner 1 v, of corner 2 1 - u - v. The distance
    to the edge opposite corner k is b_k * h_k; a pixel's footprint at distance t is
    wire_world + wire_per_distance * t (orthographic: constant, perspective: proportional to t).
    """
    i = start + wp.tid()
    f = hit_triangle[i]
    wire[i] = wp.int8(0)
    if f < 0:
        value[i] = wp.vec3(0.0)
        facing[i] = 0.0
        return
    uv = hit_uv[i]
    b = wp.vec3(uv[0], uv[1], 1.0 - uv[0] - uv[1])
    value[i] = corner_values[3 * f] * b[0] + corner_values[3 * f + 1] * b[1] + corner_values[3 * f + 2] * b[2]
    facing[i] = wp.abs(wp.dot(tri_normals[f], ray_direction[i]))
    mask = tri_edge_mask[f]
    if mask != 0:
        footprint = wire_world + wire_per_distance * hit_t[i]
        h = tri_edge_heights[f]
        for k in range(3):
            if (mask >> k) & 1 == 1:
                if b[k] * h[k] < footprint:
                    wire[i] = wp.int8(1)


@wp.kernel
def sphere_kernel(
    start: int,
    width: int,
    tiles_x: int,
    eye: wp.vec3,
    ray_direction: wp.array(dtype=wp.vec3),
    tile_start: wp.array(dtype=int),
    tile_items: wp.array(dtype=int),
    centers: wp.array(dtype=wp.vec3),
    radius: float,
    depth: wp.array(dtype=float),
    sphere_hit: wp.array(dtype=int),
    sphere_normal: wp.array(dtype=wp.vec3),
    facing: wp.array(dtype=float),
):
    """Nearest sphere in front of the mesh hit (``depth``) along each pixel's perspective ray.

    Analytic ray-sphere: |o + t d - c|^2 = r^2 with |d| = 1 gives t = -b - sqrt(b^2 - q),
    b = (o - c) . d, q = |o - c|^2 - r^2. Writes sphere index (-1: none), normal, depth, |n . d|.
    """
    i = start + wp.tid()
    px = i % width
    py = i // width
    tile = (py // TILE) * tiles_x + px // TILE
    d = ray_direction[i]
    best = depth[i]
    found = int(-1)
    for k in range(tile_start[tile], tile_start[tile + 1]):
        s = tile_items[k]
        oc = eye - centers[s]
        bq = wp.dot(oc, d)
        cq = wp.dot(oc, oc) - radius * radius
        disc = bq * bq - cq
        if disc >= 0.0:
            t = -bq - wp.sqrt(disc)
            if t > 0.0 and t < best:
                best = t
                found = s
    sphere_hit[i] = found
    if found >= 0:
        n = wp.normalize(eye + d * best - centers[found])
        depth[i] = best
        sphere_normal[i] = n
        facing[i] = wp.abs(wp.dot(n, d))


# ---------------------------------------------------------------------------
# Camera


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


AUTO_AZIMUTHS_DEG = (AUTO_AZIMUTH_DEG, AUTO_AZIMUTH_DEG + 180.0, AUTO_AZIMUTH_DEG + 90.0, AUTO_AZIMUTH_DEG - 90.0)
"""Auto camera candidates: the front three-quarter view first, then the back and the two sides."""
AUTO_COVERAGE_PREFERENCE = 1.1
"""Another candidate replaces the front view only when it sees 10% more surface: with back faces
culled, a box open on one side (the Cornell box) is seen from its open side."""
AUTO_PROBE_SIZE = (64, 48)


def choose_auto_camera(tracer, scene, width: int, height: int) -> Camera:
    """The auto_camera candidate (front, back, sides) whose low-resolution render covers the most pixels."""
    lo, hi = scene.bounds
    best, best_coverage = None, -1.0
    for k, azimuth in enumerate(AUTO_AZIMUTHS_DEG):
        camera = auto_camera(lo, hi, scene.up_axis, width, height, azimuth_deg=azimuth)
        if scene.num_triangles == 0:
            return camera.conformed(width, height)
        probe_w, probe_h = AUTO_PROBE_SIZE
        probe_h = max(8, int(round(probe_w * height / width)))
        frame = trace_frame(tracer, scene, camera.conformed(probe_w, probe_h), probe_w, probe_h)
        coverage = float((frame.hit_triangle >= 0).mean())
        if best is None or coverage > best_coverage * AUTO_COVERAGE_PREFERENCE:
            best, best_coverage = camera, coverage
    return best.conformed(width, height)


# ---------------------------------------------------------------------------
# Colour


def aces_fitted(x: np.ndarray) -> np.ndarray:
    """Narkowicz's ACES filmic fit, clamped to [0, 1]."""
    x = np.maximum(np.asarray(x, np.float32), 0.0)
    return np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """sRGB transfer function of linear values in [0, 1]."""
    linear = np.clip(np.asarray(linear, np.float32), 0.0, 1.0)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    encoded = np.clip(np.asarray(encoded, np.float32), 0.0, 1.0)
    return np.where(encoded <= 0.04045, encoded / 12.92, np.power((encoded + 0.055) / 1.055, 2.4))


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance of linear RGB (..., 3)."""
    return np.asarray(rgb, np.float32) @ np.array([0.2126, 0.7152, 0.0722], np.float32)


def auto_exposure(linear: np.ndarray) -> float:
    """EV that maps the median luminance of ``linear`` ((N, 3)) to middle grey; 0 when all dark."""
    lum = luminance(linear)
    lum = lum[np.isfinite(lum) & (lum > 0)]
    if len(lum) == 0:
        return 0.0
    return float(np.log2(MIDDLE_GREY / np.median(lum)))


def tone_map(linear: np.ndarray, exposure: float) -> np.ndarray:
    """Display sRGB in [0, 1] from linear RGB: scale by 2^EV, ACES fit, sRGB encode."""
    return srgb_encode(aces_fitted(np.asarray(linear, np.float32) * np.float32(2.0 ** exposure)))


def false_color(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(..., 3) sRGB viridis colours of ``values`` normalized to [lo, hi] (NaN -> lo)."""
    span = hi - lo if hi > lo else 1.0
    t = np.nan_to_num((np.asarray(values, np.float64) - lo) / span, nan=0.0)
    index = np.clip(np.rint(t * 255.0), 0, 255).astype(np.int64)
    return VIRIDIS[index]


# ---------------------------------------------------------------------------
# A 3 x 5 bitmap font (rows top to bottom, 3 bits each, most significant bit left).

_GLYPHS = {
    "0": "111 101 101 101 111", "1": "010 110 010 010 111", "2": "111 001 111 100 111",
    "3": "111 001 111 001 111", "4": "101 101 111 001 001", "5": "111 100 111 001 111",
    "6": "111 100 111 101 111", "7": "111 001 001 001 001", "8": "111 101 111 101 111",
    "9": "111 101 111 001 111", ".": "000 000 000 000 010", "-": "000 000 111 000 000",
    "+": "000 010 111 010 000", ":": "000 010 000 010 000", "/": "001 001 010 100 100",
    "(": "010 100 100 100 010", ")": "010 001 001 001 010", " ": "000 000 000 000 000",
    "_": "000 000 000 000 111", "[": "110 100 100 100 110", "]": "011 001 001 001 011",
    "=": "000 111 000 111 000", "%": "101 001 010 100 101",
    "A": "010 101 111 101 101", "B": "110 101 110 101 110", "C": "011 100 100 100 011",
    "D": "110 101 101 101 110", "E": "111 100 110 100 111", "F": "111 100 110 100 100",
    "G": "011 100 101 101 011", "H": "101 101 111 101 101", "I": "111 010 010 010 111",
    "J": "001 001 001 101 010", "K": "101 101 110 101 101", "L": "100 100 100 100 111",
    "M": "101 111 111 101 101", "N": "110 101 101 101 101", "O": "010 101 101 101 010",
    "P": "110 101 110 100 100", "Q": "010 101 101 111 011", "R": "110 101 110 101 101",
    "S": "011 100 010 001 110", "T": "111 010 010 010 010", "U": "101 101 101 101 111",
    "V": "101 101 101 010 010", "W": "101 101 111 111 101", "X": "101 101 010 101 101",
    "Y": "101 101 010 010 010", "Z": "111 001 010 100 111",
}
_GLYPH_BITS = {ch: np.array([[c == "1" for c in row] for row in rows.split()], bool)
               for ch, rows in _GLYPHS.items()}


def text_mask(text: str, scale: int = 1) -> np.ndarray:
    """(5 s, 4 s * len - s) bool mask of ``text`` in the built-in font (lower case drawn as upper case)."""
    if not text:
        return np.zeros((5 * scale, 0), bool)
    glyphs = [_GLYPH_BITS.get(ch.upper(), _GLYPH_BITS["-"] & False) for ch in text]
    row = np.zeros((5, 4 * len(glyphs) - 1), bool)
    for k, glyph in enumerate(glyphs):
        row[:, 4 * k:4 * k + 3] = glyph
    return np.kron(row, np.ones((scale, scale), bool)).astype(bool)


def draw_text(image: np.ndarray, text: str, x: int, y: int, color, scale: int = 1) -> None:
    """Draw ``text`` into ``image`` ((H, W, 3) float) with its top-left corner at (x, y), clipped."""
    mask = text_mask(text, scale)
    h, w = mask.shape
    y0, x0 = max(y, 0), max(x, 0)
    y1, x1 = min(y + h, image.shape[0]), min(x + w, image.shape[1])
    if y1 <= y0 or x1 <= x0:
        return
    region = mask[y0 - y:y1 - y, x0 - x:x1 - x]
    image[y0:y1, x0:x1][region] = np.asarray(color, np.float32)


def format_tick(value: float) -> str:
    return f"{value:.3g}".upper().replace("E+0", "E").replace("E-0", "E-")


# ---------------------------------------------------------------------------
# Legend


@dataclass(frozen=True)
class Legend:
    """The false-colour scale drawn beside the image."""

    lo: float
    hi: float
    label: str
    ticks: tuple[float, ...]
    bar_top: int
    """Row of the legend bar's top (value hi) in the composed image."""
    bar_bottom: int
    """Row of the legend bar's bottom (value lo), inclusive."""
    bar_x: tuple[int, int]
    """Columns [x0, x1) of the bar in the composed image."""


def legend_scale(height: int) -> int:
    """Font scale: 1 below 240 rows, then one more per 240 rows."""
    return max(1, height // 240)


def legend_width(lo: float, hi: float, height: int) -> int:
    s = legend_scale(height)
    chars = max(len(format_tick(v)) for v in np.linspace(lo, hi, 5))
    return 6 * s + 8 * s + 3 * s + 4 * s * chars + 4 * s


def draw_legend(panel: np.ndarray, lo: float, hi: float, label: str, x_offset: int) -> Legend:
    """Draw a vertical viridis bar (hi at the top) with 5 tick labels into ``panel`` ((H, w, 3) float)."""
    height = panel.shape[0]
    s = legend_scale(height)
    panel[:] = BACKGROUND
    top, bottom = 6 * s + 5 * s + 6 * s, height - 1 - 8 * s
    if bottom - top < 4:  # too small an image for a bar: keep the labels out, still draw a bar
        top, bottom = 1, max(2, height - 2)
    x0, x1 = 6 * s, 6 * s + 8 * s
    rows = np.arange(top, bottom + 1)
    t = (bottom - rows) / max(bottom - top, 1)
    panel[top:bottom + 1, x0:x1] = false_color(lo + t * (hi - lo), lo, hi)[:, None, :]
    draw_text(panel, label[: max(1, (panel.shape[1] - 2 * s) // (4 * s))], 2 * s, 4 * s, (0.9, 0.9, 0.9), s)
    ticks = tuple(float(v) for v in np.linspace(lo, hi, 5))
    for value in ticks:
        frac = 0.0 if hi == lo else (value - lo) / (hi - lo)
        row = int(round(bottom - frac * (bottom - top)))
        panel[row:row + s, x1 - 2 * s:x1] = (0.95, 0.95, 0.95) if frac < 0.5 else (0.05, 0.05, 0.05)
        draw_text(panel, format_tick(value), x1 + 3 * s, row - (5 * s) // 2, (0.9, 0.9, 0.9), s)
    return Legend(lo, hi, label, ticks, top, bottom, (x_offset + x0, x_offset + x1))


# ---------------------------------------------------------------------------
# Rendering


@dataclass(frozen=True)
class Frame:
    """Per-pixel results of the primary rays, all (H, W) or (H, W, 3)."""

    hit_triangle: np.ndarray
    """(H, W) int32, -1 for background."""
    hit_t: np.ndarray
    """(H, W) float32 distance from the eye (inf for background)."""
    value: np.ndarray
    """(H, W, 3) float32 interpolated channel value (scalars in component 0)."""
    facing: np.ndarray
    """(H, W) float32 |cos| between the ray and the geometric normal."""
    wire: np.ndarray
    """(H, W) bool: on an authored polygon edge (when wire was asked for)."""
    sphere: np.ndarray
    """(H, W) int32 index of the visible sphere, -1 where none."""
    sphere_normal: np.ndarray
    """(H, W, 3) float32 unit normal of the visible sphere."""


def polygon_edges(tri_vertices: np.ndarray, tri_prim: np.ndarray, tri_face: np.ndarray) -> np.ndarray:
    """(T,) int32 bit mask: bit k set when the edge opposite corner k is an edge of the authored polygon.

    An edge shared by two triangles of the same polygon is a triangulation diagonal, not drawn.
    """
    tri_vertices = np.asarray(tri_vertices, np.int64).reshape(-1, 3)
    n = len(tri_vertices)
    if n == 0:
        return np.zeros(0, np.int32)
    # edge opposite corner k joins corners (k+1)%3 and (k+2)%3
    a = np.stack([tri_vertices[:, 1], tri_vertices[:, 2], tri_vertices[:, 0]], axis=1)
    b = np.stack([tri_vertices[:, 2], tri_vertices[:, 0], tri_vertices[:, 1]], axis=1)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    polygon = np.repeat((np.asarray(tri_prim, np.int64) << 32) | np.asarray(tri_face, np.int64), 3)
    keys = np.stack([polygon, lo.ravel(), hi.ravel()], axis=1)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    boundary = (counts[inverse.ravel()] == 1).reshape(n, 3)
    return (boundary * np.array([1, 2, 4])).sum(axis=1).astype(np.int32)


def edge_heights(points: np.ndarray, tri_vertices: np.ndarray) -> np.ndarray:
    """(T, 3) float32 triangle height over the edge opposite each corner (0 for degenerate triangles)."""
    corners = np.asarray(points, np.float64)[np.asarray(tri_vertices, np.int64)]
    double_area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    lengths = np.stack([np.linalg.norm(corners[:, (k + 2) % 3] - corners[:, (k + 1) % 3], axis=1)
                        for k in range(3)], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        heights = np.where(lengths > 0, double_area[:, None] / lengths, 0.0)
    return heights.astype(np.float32)


def _film(camera: Camera) -> wp.vec4:
    return wp.vec4(camera.horizontal_aperture, camera.vertical_aperture,
                   camera.horizontal_aperture_offset, camera.vertical_aperture_offset)


def _mat33(m: np.ndarray) -> wp.mat33:
    return wp.mat33(*np.asarray(m, np.float32).ravel().tolist())


def trace_frame(tracer, scene, camera: Camera, width: int, height: int, *,
                corner_values: np.ndarray | None = None, cull_back_faces: bool = True,
                wire: bool = False, wire_width: float = 1.0,
                spheres: np.ndarray | None = None, sphere_radius: float = 0.0) -> Frame:
    """Cast one primary ray per pixel and interpolate ``corner_values`` at the hits.

    Parameters
    ----------
    tracer : Tracer over ``scene``'s triangles.
    scene : Scene (reads points, tri_vertices, tri_normals, tri_double_sided, tri_prim, tri_face).
    camera : Camera, already conformed to width / height.
    corner_values : (T, 3, 3) float32 channel value at each triangle corner (scalars in component 0),
        or None (zeros).
    wire : mark pixels within ``wire_width`` pixels of an authored polygon edge.
    spheres : (S, 3) float32 sphere centres (scene-local) drawn with ``sphere_radius``, or None.
    """
    if width < 1 or height < 1:
        raise ValueError(f"image size {width} x {height} must be at least 1 x 1")
    n = width * height
    num_tris = scene.num_triangles
    device = tracer.device
    basis = camera.basis
    eye = wp.vec3(*camera.eye.astype(np.float32).tolist())
    ortho = 1 if camera.projection == "orthographic" else 0
    if num_tris:
        cull = (~np.asarray(scene.tri_double_sided, bool)) if cull_back_faces else np.zeros(num_tris, bool)
    else:
        cull = np.zeros(max(tracer.num_triangles, 1), bool)
    hit_triangle = wp.empty(n, dtype=int, device=device)
    hit_uv = wp.zeros(n, dtype=wp.vec2, device=device)
    hit_t = wp.empty(n, dtype=float, device=device)
    directions = wp.empty(n, dtype=wp.vec3, device=device)
    tracer.launch(primary_kernel, n, [
        tracer.mesh.id, width, height, _mat33(basis), eye, _film(camera), float(camera.focal_length), ortho,
        tracer.array(cull.astype(np.int8), wp.int8), float(tracer.epsilon),
        hit_triangle, hit_uv, hit_t, directions,
    ])
    tracer.rays_cast += n

    if corner_values is None or num_tris == 0:
        corners = np.zeros((max(num_tris, 1) * 3, 3), np.float32)
    else:
        corners = np.ascontiguousarray(corner_values, np.float32).reshape(-1, 3)
        if len(corners) != 3 * num_tris:
            raise ValueError(f"corner_values has {len(corners)} rows, expected 3 x {num_tris} triangles")
        corners = np.nan_to_num(corners, nan=0.0, posinf=0.0, neginf=0.0)
    if wire and num_tris:
        mask = polygon_edges(scene.tri_vertices, scene.tri_prim, scene.tri_face)
        heights = edge_heights(scene.points, scene.tri_vertices)
    else:
        mask = np.zeros(max(num_tris, 1), np.int32)
        heights = np.zeros((max(num_tris, 1), 3), np.float32)
    normals = scene.tri_normals if num_tris else np.zeros((1, 3), np.float32)
    # Footprint of wire_width pixels: perspective grows with distance, orthographic is constant.
    pixel_film = camera.horizontal_aperture / width
    if ortho:
        wire_world, wire_per_distance = wire_width * pixel_film * 0.1, 0.0
    else:
        wire_world, wire_per_distance = 0.0, wire_width * pixel_film / camera.focal_length
    value = wp.empty(n, dtype=wp.vec3, device=device)
    facing = wp.empty(n, dtype=float, device=device)
    wire_out = wp.empty(n, dtype=wp.int8, device=device)
    tracer.launch(shade_kernel, n, [
        hit_triangle, hit_uv, hit_t, directions, tracer.array(corners, wp.vec3), tracer.array(normals, wp.vec3),
        tracer.array(heights, wp.vec3), tracer.array(mask, wp.int32), float(wire_world), float(wire_per_distance),
        value, facing, wire_out,
    ])

    sphere_hit = np.full(n, -1, np.int32)
    sphere_normal = np.zeros((n, 3), np.float32)
    depth_np = hit_t.numpy()
    facing_np = facing.numpy()
    if spheres is not None and len(spheres) and sphere_radius > 0:
        sphere_hit, sphere_normal, depth_np, facing_np = _trace_spheres(
            tracer, camera, width, height, directions, hit_t, facing, np.asarray(spheres, np.float32),
            float(sphere_radius))
    triangles = hit_triangle.numpy()
    return Frame(
        hit_triangle=triangles.reshape(height, width) if num_tris else np.full((height, width), -1, np.int32),
        hit_t=depth_np.reshape(height, width),
        value=value.numpy().reshape(height, width, 3),
        facing=facing_np.reshape(height, width),
        wire=wire_out.numpy().astype(bool).reshape(height, width),
        sphere=sphere_hit.reshape(height, width),
        sphere_normal=sphere_normal.reshape(height, width, 3),
    )


def _trace_spheres(tracer, camera: Camera, width: int, height: int, directions, hit_t, facing,
                   centers: np.ndarray, radius: float):
    """Bin spheres into screen tiles by their (conservative) projected bounds, then intersect per pixel."""
    if camera.projection == "orthographic":
        return _spheres_orthographic(camera, width, height, centers, radius, hit_t.numpy(), facing.numpy())
    tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
    pixels, depth = camera.project(centers, width, height)
    with np.errstate(divide="ignore", invalid="ignore"):
        # Off-axis spheres project to ellipses up to 1/cos^2 larger; 2x covers fields of view up to 90 deg.
        pixel_radius = 2.0 * radius * camera.focal_length / (np.maximum(depth - radius, 1e-12)
                                                             * camera.horizontal_aperture) * width
    x0 = np.floor((pixels[:, 0] - pixel_radius - 1) / TILE)
    x1 = np.floor((pixels[:, 0] + pixel_radius + 1) / TILE)
    y0 = np.floor((pixels[:, 1] - pixel_radius - 1) / TILE)
    y1 = np.floor((pixels[:, 1] + pixel_radius + 1) / TILE)
    visible = (depth > radius) & np.isfinite(pixel_radius) & (x1 >= 0) & (y1 >= 0) & (x0 < tiles_x) & (y0 < tiles_y)
    items: list[list[int]] = [[] for _ in range(tiles_x * tiles_y)]
    for s in np.flatnonzero(visible):
        for ty in range(int(max(y0[s], 0)), int(min(y1[s], tiles_y - 1)) + 1):
            for tx in range(int(max(x0[s], 0)), int(min(x1[s], tiles_x - 1)) + 1):
                items[ty * tiles_x + tx].append(int(s))
    tile_start = np.zeros(len(items) + 1, np.int32)
    tile_start[1:] = np.cumsum([len(i) for i in items])
    tile_items = np.array([s for i in items for s in i] or [0], np.int32)
    n = width * height
    sphere_hit = wp.empty(n, dtype=int, device=tracer.device)
    sphere_normal = wp.zeros(n, dtype=wp.vec3, device=tracer.device)
    depth_wp = wp.clone(hit_t)
    facing_wp = wp.clone(facing)
    tracer.launch(sphere_kernel, n, [
        width, tiles_x, wp.vec3(*camera.eye.astype(np.float32).tolist()), directions,
        tracer.array(tile_start, wp.int32), tracer.array(tile_items, wp.int32), tracer.array(centers, wp.vec3),
        radius, depth_wp, sphere_hit, sphere_normal, facing_wp,
    ])
    return sphere_hit.numpy(), sphere_normal.numpy(), depth_wp.numpy(), facing_wp.numpy()


def _spheres_orthographic(camera: Camera, width: int, height: int, centers, radius, depth, facing):
    """Orthographic spheres: each covers a disc of pixels; depth test against the mesh (numpy)."""
    n = width * height
    hit = np.full(n, -1, np.int32)
    normal = np.zeros((n, 3), np.float32)
    depth, facing = depth.copy(), facing.copy()
    pixels, center_depth = camera.project(centers, width, height)
    pixel_radius = radius * 10.0 / camera.horizontal_aperture * width
    ys, xs = np.mgrid[0:height, 0:width]
    for s in range(len(centers)):
        dx, dy = (xs + 0.5 - pixels[s, 0]).ravel(), (ys + 0.5 - pixels[s, 1]).ravel()
        r2 = (dx * dx + dy * dy) / (pixel_radius * pixel_radius)
        z = np.sqrt(np.maximum(1 - r2, 0))
        t = center_depth[s] - radius * z
        take = (r2 <= 1) & (t < depth) & (t > 0)
        depth[take], hit[take], facing[take] = t[take], s, z[take]
        local = np.stack([dx / pixel_radius, -dy / pixel_radius, z], axis=1)
        normal[take] = (local @ camera.basis.T)[take]
    return hit, normal, depth, facing


# ---------------------------------------------------------------------------
# Composition


@dataclass(frozen=True)
class Image:
    """A finished preview."""

    display: np.ndarray
    """(H, W_total, 3) float32 display (sRGB) colour in [0, 1], legend included."""
    linear: np.ndarray
    """(H, W_view, 3) float32 linear colour of the 3D view after exposure, before the curve."""
    value: np.ndarray
    """(H, W_view, C) float32 raw channel value per pixel (0 where no data), C = 1 or 3."""
    coverage: np.ndarray
    """(H, W_view) float32: 1 where a surface or sphere was hit."""
    view_width: int
    exposure: float
    legend: Legend | None = None


def shade(frame: Frame, tri_albedo: np.ndarray, *, tri_has_value: np.ndarray | None, channels: int,
          style: str, value_range: tuple[float, float] | None = None, label: str = "",
          exposure: float | None = None, irradiance: bool = False, legend: bool = True,
          legend_panel: int | None = None, sphere_colors: np.ndarray | None = None) -> Image:
    """Turn a Frame into display colour.

    style : 'falsecolor' (scalar channel through VIRIDIS with a legend), 'shaded' (channel times
        albedo, tone mapped; irradiance channels are divided by pi: Lambertian radiance
        L = albedo * E / pi) or 'albedo' (no channel: albedo under a headlight).
    tri_has_value : (T,) bool, triangles that carry the channel (others are drawn grey).
    value_range : (lo, hi) of the false-colour scale; required for 'falsecolor'.
    legend_panel : width reserved for the legend (the frame is the view only).
    sphere_colors : (S, 3) float32 linear colours, or (H, W, 3) per-pixel colours of sphere hits.
    """
    height, width = frame.hit_triangle.shape
    tri = frame.hit_triangle
    surface = tri >= 0
    safe = np.where(surface, tri, 0)
    has_value = surface & (tri_has_value[safe] if tri_has_value is not None else surface)
    albedo = np.asarray(tri_albedo, np.float32)[safe] if len(tri_albedo) else np.zeros((height, width, 3), np.float32)
    facing = frame.facing[..., None]
    value = frame.value[..., :channels]
    headlight = 0.25 + 0.75 * facing  # keeps grazing faces readable

    linear = np.zeros((height, width, 3), np.float32)
    if style == "falsecolor":
        lo, hi = value_range if value_range is not None else (0.0, 1.0)
        display = np.where(has_value[..., None], false_color(frame.value[..., 0], lo, hi),
                           NO_DATA_GREY * headlight).astype(np.float32)
        display = np.where(surface[..., None], display, BACKGROUND)
        linear = np.where(surface[..., None], srgb_decode(display), 0.0).astype(np.float32)
        used_exposure = 0.0
    else:
        if style == "shaded":
            lighting = value if channels == 3 else np.repeat(value, 3, axis=2)
            lighting = np.maximum(lighting, 0.0) / (np.pi if irradiance else 1.0)
            linear = np.where(has_value[..., None], albedo * lighting, albedo * headlight * 0.5)
        else:
            linear = albedo * headlight
        linear = np.where(surface[..., None], linear, 0.0).astype(np.float32)
        used_exposure = auto_exposure(linear[has_value if style == "shaded" else surface]) \
            if exposure is None else float(exposure)
        linear = linear * np.float32(2.0 ** used_exposure)
        display = np.where(surface[..., None], srgb_encode(aces_fitted(linear)), BACKGROUND).astype(np.float32)
        lo = hi = 0.0

    if sphere_colors is not None and (frame.sphere >= 0).any():
        on_sphere = frame.sphere >= 0
        colors = np.asarray(sphere_colors, np.float32)
        if colors.ndim == 3:  # per-pixel lighting (e.g. SH irradiance at the sphere normal): no headlight
            sphere_linear = colors
        else:
            sphere_linear = colors[np.where(on_sphere, frame.sphere, 0)] * headlight
        sphere_linear = (sphere_linear * np.float32(2.0 ** used_exposure)).astype(np.float32)
        display = np.where(on_sphere[..., None], srgb_encode(aces_fitted(sphere_linear)), display)
        linear = np.where(on_sphere[..., None], sphere_linear, linear)
        surface = surface | on_sphere

    if frame.wire.any():
        wire = frame.wire[..., None] & (frame.sphere < 0)[..., None]
        display = np.where(wire, display * (1 - WIRE_OPACITY) + WIRE_COLOR * WIRE_OPACITY, display)

    raw = np.where((has_value & (frame.sphere < 0))[..., None], value, 0.0).astype(np.float32)
    drawn_legend = None
    if style == "falsecolor" and legend:
        panel_width = legend_panel if legend_panel is not None else legend_width(lo, hi, height)
        panel = np.zeros((height, panel_width, 3), np.float32)
        drawn_legend = draw_legend(panel, lo, hi, label, width)
        display = np.concatenate([display, panel], axis=1)
    return Image(display=np.clip(display, 0, 1).astype(np.float32), linear=linear, value=raw,
                 coverage=surface.astype(np.float32), view_width=width, exposure=used_exposure,
                 legend=drawn_legend)


def to_uint8(display: np.ndarray) -> np.ndarray:
    """Display colour in [0, 1] -> uint8 with rounding."""
    return np.clip(np.rint(np.asarray(display, np.float64) * 255.0), 0, 255).astype(np.uint8)


def compare_images(reference: np.ndarray, image: np.ndarray) -> tuple[np.ndarray, float]:
    """Side-by-side [reference | image | difference] and the RMS difference.

    Both (H, W, 3) display colour in [0, 1] (use the 8-bit values / 255 of what was written).
    RMS = sqrt(mean over pixels and channels of (a - b)^2), in display units [0, 1].
    The difference panel shows |a - b| * DIFF_GAIN, clamped.
    """
    a = np.asarray(reference, np.float32)[..., :3]
    b = np.asarray(image, np.float32)[..., :3]
    if a.shape != b.shape:
        raise ValueError(f"images differ in size: {a.shape[1]} x {a.shape[0]} vs {b.shape[1]} x {b.shape[0]}")
    diff = a.astype(np.float64) - b
    rms = float(np.sqrt(np.mean(diff * diff))) if diff.size else 0.0
    panel = np.clip(np.abs(diff) * DIFF_GAIN, 0, 1).astype(np.float32)
    return np.concatenate([a, b, panel], axis=1), rms
