"""Dense irradiance reference and uniform-grid baseline for the light-probe benchmark.

Three scenes (``SCENES``): the atrium sample, the furnished room (sky through windows) and the thin wall
(two closed rooms, 5 cm of wall between a bright and a dim one). In each, a fixed ``TestSet`` of points:

* free space: uniform in the scene's region, outside geometry and FREE_CLEARANCE from it, 6 rows each
  (the axis normals);
* near surface: area-uniform points on the surfaces, moved SURFACE_OFFSET along the face normal, one row
  each (normal = the face normal);
* leak band: within LEAK_BAND of a wall on its dark side, 6 rows each (thin wall: room B's side of the
  shared wall; furnished room: inside the four walls where they are solid; atrium: none, it has no
  closed wall with a dark side, only open halls under the sky).

Points keep LIGHT_CLEARANCE from small lights (sphere, rect, disk), whose 1/d^2 peak would otherwise
dominate every RMS. The reference irradiance at the rows is total light with interreflection:
``direct_reference`` (``direct_irradiance``, stratified) plus ``references.path_traced_indirect``,
computed as two independent halves so their difference gives the reference's own noise
(``reference_noise``). The baseline is a uniform lattice read by trilinear interpolation, as engines do,
without validity handling (``grid_positions``, ``grid_weights``). All positions are in the Scene's frame
(world = scene point + scene.origin).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import warp as wp

from . import harness
from usdbake.kernels.light_bundles import scene_lighting
from usdbake.kernels.lights import LUMINANCE, Lights, direct_irradiance
from usdbake.kernels.traversal import TraceScene

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

SCENES = ("atrium", "furnished_room", "thin_wall")
VERSION = "1"
"""Bumped when the test points or the reference change (part of the cache key)."""

FREE, NEAR, LEAK = 0, 1, 2
KIND_NAMES = ("free", "near", "leak")
AXIS_NORMALS = np.array([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)], np.float32)

FREE_CLEARANCE = 0.1
"""Free-space points keep this distance (m) from surfaces (nearest of ``classify_points``' 26 rays)."""
SURFACE_OFFSET = 0.05
"""Near-surface points lie this far (m) along their face normal."""
LEAK_BAND = (0.01, 0.1)
"""Leak points lie this far (m) from the wall, on its dark side."""
WALL_PROBE = 0.15
"""Furnished room: a leak point's ray towards its wall must hit geometry within this (no window there)."""
ROOM_SHRINK = 0.02
"""Room boxes (furnished room, thin wall) are shrunk by this (m): regions and grids stay off the walls."""
LIGHT_CLEARANCE = 0.3
"""Free and near-surface points keep this distance (m) from sphere, rect and disk light centres."""
THIN_WALL_ROOMS = ((np.array([0.0, 0.0, 0.0]), np.array([4.0, 4.0, 3.0])),
                   (np.array([4.05, 0.0, 0.0]), np.array([8.05, 4.0, 3.0])))
"""World boxes of the thin wall's rooms A (2000 W/sr lamp) and B (100 W/sr), ``thin_wall_stage``."""


# ---------------------------------------------------------------------------
# Scenes and test points


def load(name: str):
    """The Scene of one of SCENES."""
    from usdbake.stages.extract import extract_scene

    if name == "atrium":
        return harness.load_scene("atrium")
    if name == "furnished_room":
        from . import furnished_room

        return extract_scene(furnished_room.build())
    if name == "thin_wall":
        return extract_scene(thin_wall_stage())
    raise ValueError(f"unknown scene {name!r}, expected one of {SCENES}")


def thin_wall_stage():
    """Two closed 4 x 4 x 3 m rooms (walls facing in) side by side, 5 cm of wall between them; a 2000 W/sr
    lamp in room A, a 100 W/sr lamp in room B (Z up, metres)."""
    from pxr import Gf, Usd, UsdGeom, UsdLux

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    outward = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    for name, x0, intensity in (("A", 0.0, 2000.0), ("B", 4.05, 100.0)):
        room = UsdGeom.Mesh.Define(stage, f"/World/Room{name}")
        room.CreatePointsAttr([(x, y, z) for z in (0.0, 3.0) for y in (0.0, 4.0) for x in (x0, x0 + 4.0)])
        room.CreateFaceVertexCountsAttr([4] * 6)
        room.CreateFaceVertexIndicesAttr([i for face in outward for i in face[::-1]])
        lamp = UsdLux.SphereLight.Define(stage, f"/World/Lamp{name}")
        lamp.CreateIntensityAttr(intensity)
        lamp.CreateRadiusAttr(0.1)
        UsdGeom.Xformable(lamp).AddTranslateOp().Set(Gf.Vec3d(x0 + 2.0, 2.0, 2.5))
    return stage


def regions(name: str, scene) -> list[tuple[np.ndarray, np.ndarray]]:
    """The boxes (lo, hi) float64, scene frame, that hold the test points: atrium the probe placement box,
    furnished room its room, thin wall its two rooms (rooms shrunk by ROOM_SHRINK)."""
    if name == "atrium":
        from usdbake.processors.light_probes.placement import placement_box

        return [placement_box(scene)]
    if name == "furnished_room":
        from .furnished_room import ROOM_HI, ROOM_LO

        boxes = [(ROOM_LO, ROOM_HI)]
    elif name == "thin_wall":
        boxes = list(THIN_WALL_ROOMS)
    else:
        raise ValueError(f"unknown scene {name!r}, expected one of {SCENES}")
    return [(lo - scene.origin + ROOM_SHRINK, hi - scene.origin - ROOM_SHRINK) for lo, hi in boxes]


def grid_box(name: str, scene) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) of the baseline grid: the bounds of ``regions`` (the thin wall's spans both rooms)."""
    boxes = regions(name, scene)
    return np.min([lo for lo, _ in boxes], axis=0), np.max([hi for _, hi in boxes], axis=0)


def in_regions(boxes, points: np.ndarray) -> np.ndarray:
    """(N,) bool: inside one of the boxes."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    return np.any([np.all((points >= lo) & (points <= hi), axis=1) for lo, hi in boxes], axis=0)


@dataclass(frozen=True)
class TestSet:
    """Rows of (position, normal) at which irradiance is compared; several rows share a test point."""

    positions: np.ndarray
    """(R, 3) float32, scene frame."""
    normals: np.ndarray
    """(R, 3) float32 unit."""
    point: np.ndarray
    """(R,) int64 index of the test point of each row (0 .. points - 1)."""
    kind: np.ndarray
    """(R,) uint8: FREE (0), NEAR (1, near a surface) or LEAK (2, leak band)."""

    @property
    def points(self) -> int:
        return int(self.point.max()) + 1 if len(self.point) else 0

    @property
    def counts(self) -> dict[str, int]:
        """Test points (not rows) per kind, by KIND_NAMES."""
        first = np.unique(self.point, return_index=True)[1]
        return {n: int((self.kind[first] == k).sum()) for k, n in enumerate(KIND_NAMES)}

    def rows(self, kind: int) -> np.ndarray:
        """(R,) bool mask of the rows of one kind."""
        return self.kind == kind

    def fingerprint(self) -> str:
        return hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in
                                       (self.positions, self.normals, self.point, self.kind))).hexdigest()[:16]


def _far_from_lights(scene, points: np.ndarray) -> np.ndarray:
    small = np.isin(np.asarray(scene.lights.light_kind), (2, 3, 4))  # sphere, rect, disk
    centres = np.asarray(scene.lights.light_position, np.float64)[small]
    if not len(centres):
        return np.ones(len(points), bool)
    return np.linalg.norm(points[:, None] - centres[None], axis=2).min(axis=1) >= LIGHT_CLEARANCE


def free_points(scene, tracer, lighting, boxes, count: int, rng) -> np.ndarray:
    """(count, 3) float32 points uniform in the boxes (by volume), outside geometry, FREE_CLEARANCE from it."""
    from usdbake.processors.light_probes.capture import classify_points

    volumes = np.array([np.prod(hi - lo) for lo, hi in boxes])
    found, total = [], 0
    while total < count:
        box = rng.choice(len(boxes), 4 * count + 64, p=volumes / volumes.sum())
        lo = np.array([boxes[b][0] for b in box])
        hi = np.array([boxes[b][1] for b in box])
        candidates = (lo + rng.random((len(box), 3)) * (hi - lo)).astype(np.float32)
        inside, nearest = classify_points(tracer, lighting, candidates)
        keep = ~inside & (nearest >= FREE_CLEARANCE) & _far_from_lights(scene, candidates)
        found.append(candidates[keep])
        total += int(keep.sum())
    return np.concatenate(found)[:count]


def near_points(scene, tracer, lighting, boxes, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(count, 3) float32 points SURFACE_OFFSET in front of area-uniform surface points, inside the boxes,
    and their face normals; a candidate whose offset segment hits geometry or ends inside it is skipped."""
    from usdbake.processors.light_probes.capture import classify_points

    offset = scene.points[scene.tri_vertices].astype(np.float64) + SURFACE_OFFSET * scene.tri_normals[:, None]
    lo, hi = offset.min(axis=1), offset.max(axis=1)  # triangles whose offset copy meets a box
    triangles = np.any([np.all((lo <= b_hi) & (hi >= b_lo), axis=1) for b_lo, b_hi in boxes], axis=0)
    found, total, attempt, batch = [], 0, 0, 2 * count + 64
    while total < count:
        surface, normals = harness.surface_points(scene, batch, seed=seed + 1000 * attempt, triangles=triangles)
        normals = normals.astype(np.float32)
        ends = (surface + SURFACE_OFFSET * normals).astype(np.float32)
        keep = in_regions(boxes, ends) & _far_from_lights(scene, ends)
        start = surface + 2 * tracer.epsilon * normals
        keep &= ~tracer.occluded(start, normals, SURFACE_OFFSET - 2 * tracer.epsilon)
        keep &= ~classify_points(tracer, lighting, ends)[0]
        found.append((ends[keep], normals[keep]))
        total += int(keep.sum())
        attempt += 1
        batch = int(min(8 * count, (count - total) / max(keep.mean(), 0.05) * 1.2)) + 64
        if attempt > 100:
            raise RuntimeError(f"near_points: only {total} of {count} points after 100 batches")
    return np.concatenate([f[0] for f in found])[:count], np.concatenate([f[1] for f in found])[:count]


def leak_points(name: str, scene, tracer, lighting, count: int, rng) -> np.ndarray:
    """(count, 3) float32 points within LEAK_BAND of a wall on its dark side (module docstring)."""
    from usdbake.processors.light_probes.capture import classify_points

    if name == "atrium" or count == 0:
        return np.zeros((0, 3), np.float32)
    near, far = LEAK_BAND
    if name == "thin_wall":  # room B's side of the shared wall at x = 4.05
        world = np.c_[rng.uniform(4.05 + near, 4.05 + far, count), rng.uniform(0.2, 3.8, count),
                      rng.uniform(0.2, 2.8, count)]
        return (world - scene.origin).astype(np.float32)
    from .furnished_room import ROOM_HI, ROOM_LO

    lo, hi = ROOM_LO - scene.origin + ROOM_SHRINK, ROOM_HI - scene.origin - ROOM_SHRINK
    walls = [(0, -1), (0, 1), (1, -1), (1, 1)]  # (axis, side): the wall at ROOM_LO (-1) or ROOM_HI (+1)
    lengths = np.array([hi[1 - axis] - lo[1 - axis] for axis, _ in walls])  # wall length along x or y
    found, total = [], 0
    while total < count:
        n = 4 * count + 64
        wall = rng.choice(4, n, p=lengths / lengths.sum())
        points = lo + rng.random((n, 3)) * (hi - lo)
        axis = np.array([walls[w][0] for w in wall])
        side = np.array([walls[w][1] for w in wall])
        plane = np.where(side < 0, ROOM_LO[axis] - scene.origin[axis], ROOM_HI[axis] - scene.origin[axis])
        points[np.arange(n), axis] = plane - side * rng.uniform(near, far, n)
        points = points.astype(np.float32)
        outward = np.zeros((n, 3), np.float32)
        outward[np.arange(n), axis] = side
        keep = tracer.occluded(points, outward, WALL_PROBE) & ~classify_points(tracer, lighting, points)[0]
        found.append(points[keep])
        total += int(keep.sum())
    return np.concatenate(found)[:count]


def test_set(name: str, scene, tracer, *, free: int = 6000, near: int = 4000, leak: int = 500,
             seed: int = 2718) -> TestSet:
    """The scene's test rows: ``free`` free-space and ``leak`` leak-band points (6 axis normals each), then
    ``near`` near-surface points (one row each); fixed seeds, so the same set every run."""
    lighting = scene_lighting(scene, tracer.device)
    boxes = regions(name, scene)
    p_free = free_points(scene, tracer, lighting, boxes, free, np.random.default_rng([seed, FREE]))
    p_near, n_near = near_points(scene, tracer, lighting, boxes, near, seed + 1) if near else \
        (np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32))
    p_leak = leak_points(name, scene, tracer, lighting, leak, np.random.default_rng([seed, LEAK]))
    axes = len(AXIS_NORMALS)
    positions = np.concatenate([np.repeat(p_free, axes, axis=0), p_near, np.repeat(p_leak, axes, axis=0)])
    normals = np.concatenate([np.tile(AXIS_NORMALS, (len(p_free), 1)), n_near,
                              np.tile(AXIS_NORMALS, (len(p_leak), 1))])
    point = np.concatenate([np.repeat(np.arange(len(p_free)), axes), len(p_free) + np.arange(len(p_near)),
                            len(p_free) + len(p_near) + np.repeat(np.arange(len(p_leak)), axes)])
    kind = np.concatenate([np.full(axes * len(p_free), FREE), np.full(len(p_near), NEAR),
                           np.full(axes * len(p_leak), LEAK)]).astype(np.uint8)
    return TestSet(np.ascontiguousarray(positions, np.float32), np.ascontiguousarray(normals, np.float32),
                   point.astype(np.int64), kind)


# ---------------------------------------------------------------------------
# Reference irradiance


@wp.kernel
def direct_kernel(start: int, scene: TraceScene, lights: Lights, positions: wp.array(dtype=wp.vec3),
                  normals: wp.array(dtype=wp.vec3), strata: int, sky_strata: int, epsilon: float, seed: int,
                  out: wp.array(dtype=wp.vec3)):
    """Direct irradiance at row i (``direct_irradiance``: strata^2 samples per light, sky_strata^2 per dome)."""
    i = start + wp.tid()
    out[i] = direct_irradiance(scene, lights, positions[i], normals[i], strata, sky_strata, epsilon,
                               wp.rand_init(seed, i))


def direct_reference(tracer, scene, positions: np.ndarray, normals: np.ndarray, *, strata: int = 16,
                     sky_strata: int = 32, seed: int = 11) -> np.ndarray:
    """(R, 3) float64 direct irradiance (W/m^2) at points with unit normals (lights, dome, emitters)."""
    positions = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    out = wp.zeros(len(positions), dtype=wp.vec3, device=tracer.device)
    if len(positions):
        lights = scene_lighting(scene, tracer.device).lights
        tracer.launch(direct_kernel, len(positions), [
            tracer.scene, lights, tracer.array(positions, wp.vec3),
            tracer.array(np.ascontiguousarray(normals, np.float32).reshape(-1, 3), wp.vec3),
            int(strata), int(sky_strata), tracer.epsilon, int(seed), out])
    return out.numpy().astype(np.float64)


def reference_halves(name: str, scene, tracer, tests: TestSet, *, paths: int = 1024, bounces: int = 4,
                     strata: int = 16, sky_strata: int = 32, seed: int = 41) -> tuple[np.ndarray, np.ndarray]:
    """Two independent (R, 3) float64 estimates of the total irradiance at the test rows, each direct
    (full strata) + path-traced indirect (paths / 2), with different seeds; cached on disk."""
    from .references import path_traced_indirect

    settings = {"version": VERSION, "scene": name, "tests": tests.fingerprint(), "rows": len(tests.positions),
                "counts": tests.counts, "paths": paths, "bounces": bounces, "strata": strata,
                "sky_strata": sky_strata, "seed": seed,
                "geometry": hashlib.sha256(np.ascontiguousarray(scene.points).tobytes()).hexdigest()[:16]}

    def compute() -> dict:
        halves = {}
        for h, key in enumerate(("a", "b")):
            direct = direct_reference(tracer, scene, tests.positions, tests.normals, strata=strata,
                                      sky_strata=sky_strata, seed=seed + 2 * h)
            indirect = path_traced_indirect(tracer, scene, tests.positions, tests.normals, paths=max(1, paths // 2),
                                            bounces=bounces, seed=seed + 2 * h + 1)
            halves[key] = direct + np.asarray(indirect, np.float64)
        return halves

    data = harness.cached_reference(f"probe_reference_{name}", settings, compute)
    return data["a"], data["b"]


def reference(name: str, scene, tracer, tests: TestSet, *, paths: int = 1024, bounces: int = 4) -> np.ndarray:
    """(R, 3) float64 total irradiance (W/m^2) at the test rows: direct + ``paths`` paths of indirect light
    with ``bounces`` bounces (the mean of ``reference_halves``)."""
    a, b = reference_halves(name, scene, tracer, tests, paths=paths, bounces=bounces)
    return 0.5 * (a + b)


def half_noise(a: np.ndarray, b: np.ndarray, rows: np.ndarray | None = None) -> float:
    """Relative RMS error (luminance) of the mean of two independent estimates, from their difference:
    the mean's error has RMS |a - b| / 2."""
    rows = slice(None) if rows is None else rows
    la, lb = luminance(a)[rows], luminance(b)[rows]
    return 0.5 * float(np.linalg.norm(la - lb)) / max(float(np.linalg.norm(0.5 * (la + lb))), 1e-300)


def reference_noise(name: str, scene, tracer, tests: TestSet, *, paths: int = 1024, bounces: int = 4,
                    rows: np.ndarray | None = None) -> float:
    """The reference's own relative RMS error (luminance, over ``rows``): the floor under any error
    measured against it (``half_noise`` of the cached halves)."""
    return half_noise(*reference_halves(name, scene, tracer, tests, paths=paths, bounces=bounces), rows)


# ---------------------------------------------------------------------------
# Uniform grid baseline


def grid_positions(lo, hi, count: int) -> tuple[np.ndarray, np.ndarray]:
    """A regular lattice spanning [lo, hi] inclusive with near-cubic cells and at most ``count`` points
    (at least 2 per axis; the cubic spacing that fits, then points added along the longest cells): (G, 3) float32 positions, x slowest (index = (i * ny + j) * nz + k), and
    (3,) int64 dims."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    if count < 8:
        raise ValueError("grid_positions: a lattice needs at least 8 points")
    extent = np.maximum(hi - lo, 1e-12)
    spacing = float(np.prod(extent) / count) ** (1 / 3) * 0.5
    while True:  # the densest spacing (in 1 % steps) that fits the budget
        dims = np.maximum(2, np.floor(extent / spacing + 1e-9).astype(np.int64) + 1)
        if np.prod(dims) <= count:
            break
        spacing *= 1.01
    while True:  # then one more point on the axis of the longest cells, while the budget allows
        grow = int(np.argmax(extent / (dims - 1)))
        if np.prod(dims) // dims[grow] * (dims[grow] + 1) > count:
            break
        dims[grow] += 1
    axes = [np.linspace(lo[a], hi[a], dims[a]) for a in range(3)]
    positions = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return positions.astype(np.float32), dims


def grid_weights(lo, hi, dims, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Trilinear interpolation from the lattice of ``grid_positions``: (N, 8) int64 lattice indices and
    (N, 8) float64 weights (summing to 1); points outside [lo, hi] are clamped to the box."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    dims = np.asarray(dims, np.int64)
    t = (np.clip(np.asarray(points, np.float64).reshape(-1, 3), lo, hi) - lo) / (hi - lo) * (dims - 1)
    base = np.clip(np.floor(t).astype(np.int64), 0, dims - 2)
    f = t - base
    indices, weights = [], []
    for corner in range(8):
        bit = np.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1])
        c = base + bit
        indices.append((c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2])
        weights.append(np.prod(np.where(bit, f, 1.0 - f), axis=1))
    return np.stack(indices, axis=1), np.stack(weights, axis=1)


# ---------------------------------------------------------------------------
# Errors


def luminance(irradiance: np.ndarray) -> np.ndarray:
    """(R,) float64 luminance (Rec. 709 weights) of (R, 3) irradiance."""
    return np.asarray(irradiance, np.float64) @ np.asarray(LUMINANCE, np.float64)


def relative_error(estimate: np.ndarray, reference: np.ndarray, rows: np.ndarray | None = None) -> float:
    """``harness.relative_rms`` of the luminance of (R, 3) irradiances, over the rows of a bool mask."""
    rows = slice(None) if rows is None else rows
    return harness.relative_rms(luminance(estimate)[rows], luminance(reference)[rows])


def median_point_error(estimate: np.ndarray, reference: np.ndarray, point: np.ndarray,
                       rows: np.ndarray | None = None) -> float:
    """Median over test points (``TestSet.point``) of the RMS luminance error of their rows, divided by
    the mean reference luminance of the rows."""
    rows = np.ones(len(point), bool) if rows is None else np.asarray(rows, bool)
    e, r, p = luminance(estimate)[rows], luminance(reference)[rows], np.asarray(point)[rows]
    _, p = np.unique(p, return_inverse=True)
    per_point = np.sqrt(np.bincount(p, (e - r) ** 2) / np.bincount(p))
    return float(np.median(per_point) / max(float(r.mean()), 1e-300))
