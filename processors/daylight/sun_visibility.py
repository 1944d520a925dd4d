"""Sun visibility: the share of the solar disk each face sees, by shadow rays (Warp).

Shared by ``daylight`` (one sun position per time, or a table of sun bins for interactive relighting)
and ``annual_daylight`` (one per sun bin).
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ...kernels.daylight_relight import sun_levels
from ...kernels.sampling import tangent_frame, triangle_point
from ...kernels.sky import SUN_ANGULAR_DIAMETER, reinhart_patches
from ...kernels.tracer import FAR, triangle_origin
from ...kernels.traversal import TraceScene, trace_any
from .glazing import glass_arguments, segment_transmittance

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

PAIRS_PER_LAUNCH = 16_000_000
"""(sun bin, face) pairs per launch of ``sun_bins_kernel``: bounds the byte array of one launch."""


@wp.func
def disk_share(scene: TraceScene, a: wp.vec3, b: wp.vec3, c: wp.vec3, n: wp.vec3, sun: wp.vec3,
               cos_half_angle: float, samples: int, epsilon: float, state: wp.uint32, has_glass: int,
               glass: TraceScene, glass_tn: wp.array(dtype=float), glass_normal: wp.array(dtype=wp.vec3)) -> float:
    """Share of ``samples`` rays from random points of face abc (normal n) toward random points of the solar
    disk that escape.

    The sun's visibility S_i of Bosch, Besuievsky & Martin, Sec. 5 (they use a
    shadow map; here rays): directions uniform in solid angle over the cone of
    half-angle acos(``cos_half_angle``) about ``sun`` (the 0.53 degree disk;
    uniform cone sampling, Pharr, Jakob & Humphreys, "Physically Based
    Rendering" (3rd ed.), sec. 13.6.4), origins uniform on the face.
    Dimensionless in [0, 1]; rays below the face's horizon count as blocked. With glazing (``has_glass``:
    ``scene`` the opaque triangles) a ray that escapes counts its transmittance through the panes.
    """
    frame = tangent_frame(sun)
    hits = float(0.0)
    for k in range(samples):
        cos_t = 1.0 - wp.randf(state) * (1.0 - cos_half_angle)
        sin_t = wp.sqrt(wp.max(0.0, 1.0 - cos_t * cos_t))
        phi = 2.0 * wp.pi * wp.randf(state)
        d = frame * wp.vec3(sin_t * wp.cos(phi), sin_t * wp.sin(phi), cos_t)
        x = triangle_point(a, b, c, wp.randf(state), wp.randf(state))
        if wp.dot(n, d) > 0.0:
            origin = triangle_origin(scene, a, b, c, x, n, epsilon)
            if not trace_any(scene, origin, d, FAR):
                through = float(1.0)
                if has_glass != 0:
                    through = segment_transmittance(glass, glass_tn, glass_normal, origin, d, FAR, epsilon)
                hits += through
    return hits / float(samples)


@wp.kernel
def sun_visibility_kernel(
    start: int,
    scene: TraceScene,
    faces: wp.array(dtype=int),
    corners: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    sun: wp.vec3,
    cos_half_angle: float,
    samples: int,
    epsilon: float,
    seed: int,
    has_glass: int,
    glass: TraceScene,
    glass_tn: wp.array(dtype=float),
    glass_normal: wp.array(dtype=wp.vec3),
    visible: wp.array(dtype=float),
):
    """``disk_share`` of face faces[i] for one sun direction."""
    i = start + wp.tid()
    f = faces[i]
    visible[i] = disk_share(scene, corners[3 * f], corners[3 * f + 1], corners[3 * f + 2], normals[f], sun,
                            cos_half_angle, samples, epsilon, wp.rand_init(seed, i), has_glass, glass, glass_tn,
                            glass_normal)


@wp.kernel
def sun_bins_kernel(
    start: int,
    scene: TraceScene,
    corners: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    suns: wp.array(dtype=wp.vec3),
    faces: int,
    cos_half_angle: float,
    samples: int,
    levels: float,
    epsilon: float,
    seed: int,
    has_glass: int,
    glass: TraceScene,
    glass_tn: wp.array(dtype=float),
    glass_normal: wp.array(dtype=wp.vec3),
    shares: wp.array(dtype=wp.uint8),
):
    """Pair k = bin * faces + face: ``disk_share`` in steps of 1 / ``levels`` (0 for a face turned away from
    the whole disk), seeded by (seed + bin, face)."""
    k = start + wp.tid()
    which = k // faces
    f = k - which * faces
    n = normals[f]
    sun = suns[which]
    shares[k] = wp.uint8(0)
    if wp.dot(n, sun) <= -wp.sqrt(1.0 - cos_half_angle * cos_half_angle):
        return
    share = disk_share(scene, corners[3 * f], corners[3 * f + 1], corners[3 * f + 2], n, sun, cos_half_angle,
                       samples, epsilon, wp.rand_init(seed + which, f), has_glass, glass, glass_tn, glass_normal)
    shares[k] = wp.uint8(wp.floor(share * levels + 0.5))


class SunFaces:
    """Faces uploaded once for shadow rays toward any number of sun directions."""

    def __init__(self, tracer, corners: np.ndarray, normals: np.ndarray, glazing=None):
        """``glazing`` (``glazing.Glazing``): rays cross its panes, and trace its opaque tracer, not ``tracer``."""
        tracer = glazing.opaque_tracer if glazing is not None else tracer
        self.tracer = tracer
        self.glass = glass_arguments(tracer, glazing)
        self.normals = np.ascontiguousarray(normals, np.float32).reshape(-1, 3)
        self.corners = tracer.array(np.ascontiguousarray(corners, np.float32).reshape(-1, 3), wp.vec3)
        self.normals_device = tracer.array(self.normals, wp.vec3)

    def visibility(self, sun: np.ndarray, *, samples: int, seed: int) -> np.ndarray:
        """(F,) float32 share of the solar disk visible from each face (0 for faces turned away):
        ``sun_visibility_kernel`` on the faces not wholly turned away."""
        sun = np.asarray(sun, np.float64)
        sun = (sun / np.linalg.norm(sun)).astype(np.float32)
        result = np.zeros(len(self.normals), np.float32)
        facing = np.flatnonzero(self.normals @ sun > -math.sin(math.radians(SUN_ANGULAR_DIAMETER / 2)))
        if len(facing) == 0:
            return result
        tracer = self.tracer
        visible = wp.zeros(len(facing), dtype=float, device=tracer.device)
        cos_half = math.cos(math.radians(SUN_ANGULAR_DIAMETER / 2))
        tracer.launch(sun_visibility_kernel, len(facing), [
            tracer.scene, tracer.array(facing.astype(np.int32), wp.int32), self.corners, self.normals_device,
            wp.vec3(*sun.tolist()), cos_half, int(samples), tracer.epsilon, int(seed), *self.glass, visible])
        tracer.rays_cast += len(facing) * samples
        result[facing] = visible.numpy()
        return result


def compute_sun_visibility(tracer, corners: np.ndarray, normals: np.ndarray, sun: np.ndarray, *,
                           samples: int = 4, seed: int = 0, glazing=None) -> np.ndarray:
    """(F,) float32 share of the solar disk visible from each face (0 for faces turned away): S_i of the
    module docstring (Bosch, Besuievsky & Martin, Sec. 5: the sun's visibility from its current position)."""
    return SunFaces(tracer, corners, normals, glazing).visibility(sun, samples=samples, seed=seed)


def sun_bins(suns: np.ndarray, up: np.ndarray, subdivision: int) -> tuple[np.ndarray, np.ndarray]:
    """(bin of each sun position, -1 where ``up`` is false; (B, 3) unit mean direction of each bin).

    Positions are snapped to the nearest patch of Reinhart MF:``subdivision`` (in the frame of ``suns``).
    """
    bins = np.full(len(suns), -1, np.int64)
    if not up.any():
        return bins, np.zeros((0, 3))
    layout = reinhart_patches(subdivision).patch_directions
    nearest = np.argmax(suns[up] @ layout.T, axis=1)
    used, bins[up] = np.unique(nearest, return_inverse=True)
    directions = np.zeros((len(used), 3))
    np.add.at(directions, bins[up], suns[up])
    return bins, directions / np.linalg.norm(directions, axis=1, keepdims=True)


def sun_bin_hits(tracer, corners: np.ndarray, normals: np.ndarray, directions: np.ndarray, *, samples: int,
                 seed: int = 0, glazing=None, progress=lambda f: None) -> np.ndarray:
    """(B, F) uint8 share of the solar disk each face sees, per sun direction (world, (B, 3)), in steps of
    1 / ``sun_levels(samples)`` (``samples`` shadow rays, at most 255): S_i of every bin in a byte each. Exact
    ray counts without glazing; through glass the rays' transmittances summed, to 1/levels. One launch per
    batch of bins (``sun_bins_kernel``)."""
    if not 1 <= samples <= 255:
        raise ValueError(f"sun samples {samples}: a share per face is kept in a byte (1..255 rays)")
    faces = SunFaces(tracer, corners, normals, glazing)  # uploaded once for every bin
    traced = faces.tracer  # the opaque triangles when there is glazing
    directions = np.asarray(directions, np.float64).reshape(-1, 3)
    directions = (directions / np.linalg.norm(directions, axis=1, keepdims=True)).astype(np.float32)
    count = len(faces.normals)
    hits = np.zeros((len(directions), count), np.uint8)
    per_launch = max(1, PAIRS_PER_LAUNCH // max(count, 1))
    cos_half = math.cos(math.radians(SUN_ANGULAR_DIAMETER / 2))
    for lo in range(0, len(directions), per_launch):
        hi = min(len(directions), lo + per_launch)
        shares = wp.empty((hi - lo) * count, dtype=wp.uint8, device=traced.device)
        traced.launch(sun_bins_kernel, (hi - lo) * count, [
            traced.scene, faces.corners, faces.normals_device, traced.array(directions[lo:hi], wp.vec3), count,
            cos_half, int(samples), float(sun_levels(samples)), traced.epsilon, int(seed) + lo, *faces.glass,
            shares])
        hits[lo:hi] = shares.numpy().reshape(hi - lo, count)
        progress(hi / max(1, len(directions)))
    facing = faces.normals @ directions.T > -math.sin(math.radians(SUN_ANGULAR_DIAMETER / 2))
    tracer.rays_cast += int(facing.sum()) * samples
    return hits
