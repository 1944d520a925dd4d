"""Ray casting for the preview: one primary ray per pixel through the shared Tracer's BVH (Warp).

Pure compute (no pxr): ``usdbake.stages.baked_data`` reads the stage and
``preview.compose`` hands this module arrays. Per pixel, one primary ray
through the pixel centre:

1. ``primary_kernel`` casts the ray into ``Tracer.scene`` (closest hit).
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

The result is a ``Frame`` of per-pixel arrays; ``render.shade`` turns it
into colour. The camera is ``camera.Camera``; ``choose_auto_camera`` picks
the automatic view by casting low-resolution frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .camera import AUTO_AZIMUTH_DEG, Camera, auto_camera
from ..kernels.traversal import TraceScene, trace_closest

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

MAX_CULLED_LAYERS = wp.constant(32)
"""Back faces a primary ray may pass through before it gives up (a miss)."""

TILE = wp.constant(16)
"""Screen tile side (pixels) for binning spheres."""

# ---------------------------------------------------------------------------
# Kernels


@wp.kernel
def primary_kernel(
    start: int,
    scene: TraceScene,
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
        q = trace_closest(scene, origin, direction, 1.0e30)
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

    The hit point is u * v0 + v * v1 + (1 - u - v) * v2 (trace_closest's convention), so
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
# Frames


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
        tracer.scene, width, height, _mat33(basis), eye, _film(camera), float(camera.focal_length), ortho,
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
# The automatic view


AUTO_AZIMUTHS_DEG = (AUTO_AZIMUTH_DEG, AUTO_AZIMUTH_DEG + 180.0, AUTO_AZIMUTH_DEG + 90.0, AUTO_AZIMUTH_DEG - 90.0)
"""Auto camera candidates: the front three-quarter view first, then the back and the two sides."""
AUTO_COVERAGE_PREFERENCE = 1.1
"""Another candidate replaces the front view only when it sees 10% more surface: with back faces
culled, a box open on one side (the Cornell box) is seen from its open side."""
AUTO_PROBE_SIZE = (64, 48)
"""Auto camera: size of the low-resolution trial frames (the height follows the image aspect)."""


def choose_auto_camera(tracer, scene, width: int, height: int) -> Camera:
    """The auto_camera candidate (front, back, sides) whose low-resolution render covers the most pixels."""
    lo, hi = scene.bounds
    best, best_coverage = None, -1.0
    for azimuth in AUTO_AZIMUTHS_DEG:
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

