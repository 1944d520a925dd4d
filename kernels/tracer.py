"""One BVH per scene and run, shared by every processor.

``Tracer`` builds the Scene's triangles into the ray core (``bvh_build``, traversed by the device
functions of ``traversal``; docs/ray_core.md) and offers batched closest-hit and any-hit queries for
tests and tools; kernels trace through ``Tracer.scene``. ``Tracer.from_scene`` is the tracer factory a
run hands its ``core.runtime.Runtime``, which calls it once per scene. Large CPU launches are split into
chunks, one Python thread per core: Warp releases the GIL while a CPU kernel
runs, so the chunks run in parallel.

Ray origins (``surface_origin``, the one rule every processor uses): a point
on a surface is pushed ``epsilon`` along its normal, then ``epsilon`` in front
of any other face that still passes within ``epsilon`` of it, so a ray never
meets a face through its own point at t = 0 (the perpendicular face at an
unwelded crease of a flat-shaded box, the floor a box's vertex rests on). The
Scene stores points relative to its own centre (Scene.origin), so
coordinates never exceed the scene's own size and one epsilon proportional
to the scene diagonal is safe at 1e-3 scale and 1e6 units from the world
origin alike. A scene far from unit size (outside TRACE_SCALE_RANGE) is
stored in the ray core scaled by a power of two (``trace_scale``), an exact
operation, so its rays meet what the unscaled scene's rays meet.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np
import warp as wp

from .bvh_build import CHILD_OFFSET, TraceArrays, build_triangle_bvh, single_level, two_level
from .trace_instances import instanced_arrays
from .traversal import TraceScene, surface_origin, trace_any, trace_closest

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

RAY_EPSILON_RELATIVE = 1e-5
"""Ray origin offset as a fraction of the scene diagonal: far above float32
rounding of recentred coordinates (~1e-7 of the diagonal) and far below any
feature a baker resolves."""

CPU_BLOCK_DIM = 1
"""Warp's CPU launch block size; stated so preloading and launching agree."""

FAR = 3.0e38
"""Ray length that means "no limit" in float32 kernels (float32 max is 3.4e38)."""

TRACE_SCALE_RANGE = (2.0 ** -20, 2.0 ** 20)
"""Scene diagonals (stage units) traced as they are: a scene outside this is traced scaled by a power of
two (``trace_scale``) to a diagonal near 1. Within it the watertight test's products of three coordinates
stay far inside float32 (2^60 and 2^-60 against 2^128 and 2^-126); outside it they overflow past ~7e12
units and lose precision in denormals below ~2e-13 (a 1e12-scaled Cornell box baked AO = 1 everywhere)."""

MIN_CHUNK = 4096
"""Smallest work item per thread: below this, thread overhead beats the gain."""


def default_threads() -> int:
    return max(1, os.cpu_count() or 1)


def launch_chunked(kernel, dim: int, inputs: list, *, device, threads: int, offset: int = 0,
                   min_chunk: int | None = None) -> None:
    """Launch ``kernel(start, *inputs)`` over items offset .. offset + dim - 1, chunked across CPU threads.

    The kernel's first argument is the chunk's first item; it must compute its
    item as ``start + wp.tid()`` and write only that item's outputs. Warp
    releases the GIL during a CPU launch, so the chunks run in parallel.
    ``min_chunk`` is the smallest chunk worth a thread (default MIN_CHUNK, read at
    call time so tests can force chunking of small launches; lower it for heavy items).
    """
    if dim <= 0:
        return
    min_chunk = MIN_CHUNK if min_chunk is None else min_chunk
    device = wp.get_device(device)
    if device.is_cuda or threads <= 1 or dim < 2 * min_chunk:
        wp.launch(kernel, dim=dim, inputs=[offset, *inputs], device=device)
        wp.synchronize_device(device)
        return
    # Compile/load once on this thread (concurrent first loads would race);
    # the same explicit CPU block_dim keeps the threads on this build.
    kernel.module.load(device, CPU_BLOCK_DIM)
    chunks = min(threads * 4, max(1, dim // min_chunk))
    bounds = np.linspace(0, dim, chunks + 1).astype(np.int64)

    def run(chunk: int) -> None:
        lo, hi = int(bounds[chunk]), int(bounds[chunk + 1])
        if hi > lo:
            wp.launch(kernel, dim=hi - lo, inputs=[offset + lo, *inputs], device=device, block_dim=CPU_BLOCK_DIM)

    pool = ThreadPoolExecutor(max_workers=threads)
    try:
        list(pool.map(run, range(chunks)))
    finally:  # on Ctrl-C, drop the chunks not started: stop after the ones running, not the whole launch
        pool.shutdown(wait=True, cancel_futures=True)


@dataclass(frozen=True)
class Hits:
    """Closest-hit results, one row per ray."""

    hit_t: np.ndarray
    """(N,) float32 distance along the unit direction, inf for a miss."""
    hit_triangle: np.ndarray
    """(N,) int32 triangle index, -1 for a miss."""
    hit_uv: np.ndarray
    """(N, 2) float32 barycentrics (u, v) of the hit; the point is u*v0 + v*v1 + (1-u-v)*v2."""
    hit_front: np.ndarray
    """(N,) bool: the ray met the front side (winding) of the triangle."""


@wp.func
def triangle_origin(scene: TraceScene, a: wp.vec3, b: wp.vec3, c: wp.vec3, x: wp.vec3, n: wp.vec3,
                    epsilon: float) -> wp.vec3:
    """Ray origin for point x of triangle abc (unit normal n): x + epsilon n when x lies more than 2 epsilon
    from every edge (another face can pass through it only where geometry interpenetrates), else
    ``surface_origin`` with the tangent towards the triangle's centroid as ``inward``. Stage units; the
    edge test runs in the ray core's scaled space (``TraceScene.scale``), where its products of two
    lengths neither overflow nor fall into denormals (exactly as before for a scene of ordinary size)."""
    near_edge = False
    s = scene.scale
    for k in range(3):
        start = wp.where(k == 0, a, wp.where(k == 1, b, c)) * s
        edge = wp.where(k == 0, b, wp.where(k == 1, c, a)) * s - start
        length = wp.length(edge)
        if length <= 0.0 or wp.length(wp.cross(edge, x * s - start)) < 2.0 * (epsilon * s) * length:
            near_edge = True
    if not near_edge:
        return x + n * epsilon
    inward = (a + b + c) / 3.0 - x
    inward = inward - n * wp.dot(inward, n)
    if wp.length(inward) > 0.0:
        inward = wp.normalize(inward)
    return surface_origin(scene, x, n, inward, epsilon)


@wp.kernel
def closest_hit_kernel(
    start: int,
    scene: TraceScene,
    origins: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    max_t: float,
    hit_t: wp.array(dtype=float),
    hit_triangle: wp.array(dtype=int),
    hit_uv: wp.array(dtype=wp.vec2),
    hit_front: wp.array(dtype=wp.int8),
):
    """Closest hit of ray i within max_t (``trace_closest``): distance t along the unit direction, triangle,
    barycentrics and side; a miss leaves t = inf and triangle -1."""
    i = start + wp.tid()
    d = directions[i]
    length = wp.length(d)
    hit_t[i] = wp.inf
    hit_triangle[i] = -1
    if length > 0.0:
        q = trace_closest(scene, origins[i], d / length, max_t)
        if q.result:
            hit_t[i] = q.t
            hit_triangle[i] = q.face
            hit_uv[i] = wp.vec2(q.u, q.v)
            hit_front[i] = wp.int8(wp.where(q.sign > 0.0, 1, 0))


@wp.kernel
def any_hit_kernel(
    start: int,
    scene: TraceScene,
    origins: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    max_t: float,
    occluded: wp.array(dtype=wp.int8),
):
    """1 if anything lies along ray i within max_t (``trace_any``: stops at the first hit)."""
    i = start + wp.tid()
    d = directions[i]
    length = wp.length(d)
    blocked = 0
    if length > 0.0:
        if trace_any(scene, origins[i], d / length, max_t):
            blocked = 1
    occluded[i] = wp.int8(blocked)


class Tracer:
    """The scene's triangles in the ray core (``kernels.traversal``), with batched ray queries.

    Kernels trace through ``tracer.scene`` (a ``TraceScene``) with ``trace_closest``/``trace_any``;
    ``closest_hit``/``occluded`` are the batched host API for tests and tools.

    Parameters
    ----------
    points : (P, 3) float32
    tri_vertices : (T, 3) int32
    device : str
        "cpu" (default) or "cuda:N".
    threads : int, optional
        CPU threads for chunked launches (default: one per core).
    arrays : TraceArrays, optional
        A prebuilt (e.g. instanced) scene for these triangles; by default one tree over them is built.
    """

    def __init__(self, points: np.ndarray, tri_vertices: np.ndarray, *, device: str = "cpu",
                 threads: int | None = None, arrays: TraceArrays | None = None):
        points = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
        tri_vertices = np.ascontiguousarray(tri_vertices, np.int32).reshape(-1, 3)
        if not np.isfinite(points).all():
            raise ValueError("Tracer: points contain NaN or inf")
        self.device = wp.get_device(device)
        self.threads = threads or default_threads()
        self.num_triangles = len(tri_vertices)
        if arrays is None:
            arrays = single_level(build_triangle_bvh(*_nonempty(points, tri_vertices)))
        self.arrays = arrays
        extent = points.max(axis=0).astype(np.float64) - points.min(axis=0) if len(points) else np.zeros(3)
        self.scale = trace_scale(float(np.linalg.norm(extent)))
        """The power of two the traced arrays are stored multiplied by (TraceScene.scale; 1 for most scenes)."""
        self.scene = self._upload(scaled_arrays(arrays, self.scale))
        self.epsilon = max(RAY_EPSILON_RELATIVE * float(np.linalg.norm(extent)), 1e-30)
        self.rays_cast = 0

    @classmethod
    def from_scene(cls, scene, *, device: str = "cpu", threads: int | None = None,
                   instancing: str = "auto") -> "Tracer":
        """The scene's tracer; instanced prototypes are traced once each under a top-level tree
        (``instancing``: "auto" when it saves memory, "always", or "never": every triangle flat)."""
        arrays = instanced_arrays(scene, instancing)
        return cls(scene.points, scene.tri_vertices, device=device, threads=threads, arrays=arrays)

    @classmethod
    def of_meshes(cls, meshes: list[tuple[np.ndarray, np.ndarray]], *, device: str = "cpu",
                  threads: int | None = None) -> "Tracer":
        """Separate meshes ((points, triangles) each, in their own space) as instances 0, 1, ... of one
        scene, to be traced one at a time with ``trace_any_in_instance`` (they may overlap in space)."""
        bottoms = [build_triangle_bvh(*_nonempty(points, triangles)) for points, triangles in meshes] or \
            [build_triangle_bvh(*_nonempty(np.zeros((0, 3)), np.zeros((0, 3))))]
        count = len(bottoms)
        arrays = two_level(bottoms, np.arange(count), np.repeat(np.eye(3, 4)[None], count, axis=0),
                           np.zeros(count, np.int32), np.zeros(count, np.int32))
        points = np.concatenate([np.asarray(p, np.float32).reshape(-1, 3) for p, _ in meshes] + [np.zeros((0, 3))])
        return cls(points, np.zeros((0, 3), np.int32), device=device, threads=threads, arrays=arrays)

    def _upload(self, arrays: TraceArrays) -> TraceScene:
        """Device copies of the arrays (kept alive here) and the struct of their addresses."""
        self._device_arrays = {}
        scene = TraceScene()
        for name in arrays.array_names():
            values = np.ascontiguousarray(getattr(arrays, name)).ravel()
            array = wp.array(values, dtype=wp.float32 if values.dtype == np.float32 else wp.int32, device=self.device)
            self._device_arrays[name] = array
            setattr(scene, name, array.ptr)
        scene.top_root = arrays.top_root
        scene.scale = self.scale
        return scene

    @property
    def nbytes(self) -> int:
        """Bytes of the traced scene (nodes, triangle packets, instances)."""
        return self.arrays.nbytes

    # -- launching ---------------------------------------------------------

    def launch(self, kernel, dim: int, inputs: list, *, threads: int | None = None,
               min_chunk: int | None = None) -> None:
        """Launch ``kernel(start, *inputs)`` over ``dim`` items on this tracer's device (see launch_chunked)."""
        launch_chunked(kernel, dim, inputs, device=self.device, threads=threads or self.threads, min_chunk=min_chunk)

    def array(self, values: np.ndarray, dtype) -> wp.array:
        return wp.array(np.ascontiguousarray(values), dtype=dtype, device=self.device)

    # -- queries -------------------------------------------------------------

    def closest_hit(self, origins: np.ndarray, directions: np.ndarray, max_t: float = np.inf) -> Hits:
        """Closest hit along each ray; directions need not be normalized (t is a distance)."""
        origins_wp, directions_wp, n = self._rays(origins, directions)
        hit_t = wp.empty(n, dtype=float, device=self.device)
        hit_triangle = wp.empty(n, dtype=int, device=self.device)
        hit_uv = wp.zeros(n, dtype=wp.vec2, device=self.device)
        hit_front = wp.zeros(n, dtype=wp.int8, device=self.device)
        self.launch(closest_hit_kernel, n,
                    [self.scene, origins_wp, directions_wp, finite_distance(max_t), hit_t, hit_triangle, hit_uv, hit_front])
        self.rays_cast += n
        return Hits(hit_t.numpy(), hit_triangle.numpy(), hit_uv.numpy(), hit_front.numpy().astype(bool))

    def occluded(self, origins: np.ndarray, directions: np.ndarray, max_t: float = np.inf) -> np.ndarray:
        """(N,) bool: something lies along the ray within max_t."""
        origins_wp, directions_wp, n = self._rays(origins, directions)
        occluded = wp.zeros(n, dtype=wp.int8, device=self.device)
        self.launch(any_hit_kernel, n, [self.scene, origins_wp, directions_wp, finite_distance(max_t), occluded])
        self.rays_cast += n
        return occluded.numpy().astype(bool)

    def _rays(self, origins: np.ndarray, directions: np.ndarray):
        origins = np.ascontiguousarray(origins, np.float32).reshape(-1, 3)
        directions = np.ascontiguousarray(directions, np.float32).reshape(-1, 3)
        if origins.shape != directions.shape:
            raise ValueError(f"origins {origins.shape} and directions {directions.shape} differ")
        return self.array(origins, wp.vec3), self.array(directions, wp.vec3), len(origins)


def trace_scale(diagonal: float) -> float:
    """1 for a scene diagonal within TRACE_SCALE_RANGE (or none), else the power of two that brings it
    near 1: multiplying float32 coordinates by it is exact, so hits scale back exactly."""
    low, high = TRACE_SCALE_RANGE
    if not np.isfinite(diagonal) or diagonal <= 0.0 or low <= diagonal <= high:
        return 1.0
    return float(2.0 ** -round(np.log2(diagonal)))


def scaled_arrays(arrays: TraceArrays, scale: float) -> TraceArrays:
    """``arrays`` with every coordinate multiplied by ``scale`` (a power of two): node bounds, triangle
    packets and the instances' translations (their linear parts map scaled space to scaled space)."""
    if scale == 1.0:
        return arrays
    nodes = arrays.nodes.copy()
    nodes[:, :CHILD_OFFSET] *= np.float32(scale)  # the bounds; children and counts are ints in float slots
    to_object, to_world = arrays.instance_to_object.copy(), arrays.instance_to_world.copy()
    to_object[..., 3] *= np.float32(scale)
    to_world[..., 3] *= np.float32(scale)
    return replace(arrays, nodes=nodes, packets=arrays.packets * np.float32(scale),
                   instance_to_object=to_object, instance_to_world=to_world)


def _nonempty(points: np.ndarray, tri_vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The core needs one triangle: an empty mesh becomes one zero-area triangle, which is never hit."""
    if len(tri_vertices) == 0:
        return np.zeros((3, 3), np.float32), np.zeros((1, 3), np.int32)
    return points, tri_vertices


def finite_distance(max_t: float) -> float:
    """A ray length for a float32 kernel argument: ``max_t`` clamped to FAR (inf means no limit)."""
    return float(min(max_t, FAR))
