"""Displacement fields: presampled visibility around rigid, repeated prototypes.

Gaitatzes, Chrysanthou & Papaioannou, "Presampled visibility for ambient
occlusion", Journal of WSCG 16 (2008), Algorithm 1. For each prototype that
pays off (see the cost model below):

- its bounding sphere (centre c, radius R, in prototype space);
- n^2 positional samples p_k = c + R * s_k on that sphere, s_k the cell
  centres of Clarberg's equal-area octahedral map (``processors.instancing.sphere_maps``:
  every sample covers exactly 4*pi/n^2 sr, with an O(1) inverse);
- at each p_k an M x M map of inward directions in the concentric-map +
  Malley layout (texel (a, b) -> ``cosine_hemisphere((a+.5)/M, (b+.5)/M)``
  in the tangent frame of the inward normal -s_k), the layout the paper found
  best (its Figure 5);
- per ray, the distance t to the first hit on the prototype, normalised by the
  sphere's diameter: ``uint8`` stores round(254 * t / 2R), 255 = no hit (max
  error 2R/508); ``bit1`` stores only hit / no hit plus one mean hit distance
  per positional sample (the paper's memory mode, its Figure 7).

Rays are cast with a BVH of the prototype alone (the field depends on the
prototype's geometry only, so it is reused across instances, frames and
stages), and the prototype geometry is recovered from one of its instances
in the Scene by the inverse of that instance's transform.

Cost model: a field costs n^2 * M^2 build rays once; it pays off when the
rays expected to meet the prototype's instances, ``instances *
expected_rays_per_instance``, exceed that, and the prototype has at least
``min_instances`` instances. ``force`` and ``forbid`` override it; every
prototype left out is listed in the messages with the reason.

Prototypes are those of PointInstancers and of native instancing (``Scene.instances``: one per USD
prototype, named by what its instances reference); a native prototype's field is authored on every
instance root, its USD prototype being read-only, all naming one texture.

Prototypes of one shape share one field: same topology, and points that a rigid motion (rotation and
translation, no scale or mirror) takes onto the first one's within ``RIGID_MATCH_RELATIVE`` of its size
(``ShapeIndex``, ``processors.instancing.transforms.rigid_alignment``), so copies re-authored in another frame or
rounded differently by their instancers build one field, not one each. The shared field keeps the frame
it was built in; ``DisplacementField.frame`` is the motion from that frame to the prototype's, which
``instance_ao`` composes with each instance's transform. In USD, the prototype's centre is written in its
own space and, when the frame is turned, ``bake:field:orientation`` says how.

USD written (bake layer), per prototype with a field:

=============================== ======== =======================================================
property                        type     value
=============================== ======== =======================================================
apiSchemas                      prepend  DisplacementFieldAPI (on the prototype prim)
bake:field:file                 asset    ./displacement_fields/<prototype path>.png
bake:field:center               point3f  sphere centre, prototype space
bake:field:radius               float    sphere radius, prototype space
bake:field:positionalSamples    int      n^2
bake:field:directionMapSize     int2     (M, M)
bake:field:encoding             token    uint8 | bit1
bake:field:positionMapping      token    octahedralEqualArea
bake:field:directionMapping     token    concentricMalley
bake:field:orientation          quatf    only on a prototype sharing the field of a turned copy: the
                                         rotation (real, i, j, k; as ``xformOp:orient``) from the
                                         texture's frame to the prim's space (fallback: identity)
=============================== ======== =======================================================

The texture (8-bit grey PNG, written with OpenImageIO) is an atlas of n x n
tiles, one per positional sample; the layout, the codes and the lookup are
defined once, in ``processors.instancing.field_kernels``, for this producer and for
its consumer ``instance_ao``.

Parameters: ``usdbake list displacement_fields`` or docs/displacement_fields.md, both generated from ``Params`` below.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import re
import time
from dataclasses import dataclass

import numpy as np
import warp as wp

from ...core import Attribute, Context, ParamError, Params, Prim, Processor, Result, Texture, param
from .products import DisplacementField, DisplacementFieldSet
from ...core.scene import Scene
from .transforms import invertible, rigid_alignment, rotation_quaternion
from .field_kernels import (
    DIRECTION_MAPPING,
    POSITION_MAPPING,
    encode_field,
    field_atlas,
    positional_sample,
    texel_direction,
)
from ...kernels.sampling import tangent_frame
from ...kernels.tracer import Tracer
from ...kernels.traversal import TraceScene, trace_closest

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

SPHERE_INFLATION = 1e-4
"""The bounding sphere is grown by this fraction so no vertex lies on it (rays start strictly outside)."""
MAX_FIELD_TEXELS = 2 ** 28
"""Rays (texels) per field: 256 MiB per 8-bit field, and kernel indices stay far inside int32."""

# ---------------------------------------------------------------------------
# Kernels


@wp.kernel
def field_distances_kernel(
    start: int,
    scene: TraceScene,
    side: int,
    map_size: int,
    radius: float,
    distances: wp.array(dtype=float),
):
    """Algorithm 1 of Gaitatzes et al. 2008 (Section 3.1): ray i = (sample k, texel (a, b)) from
    p_k = R * s_k into the sphere along texel (a, b)'s direction in the frame of the inward normal -s_k
    (layout: ``processors.instancing.field_kernels``); writes t / 2R of the first hit (dimensionless, t and R in
    prototype units), or 2 for a miss.

    The prototype is given relative to the sphere centre c, so p_k = R * s_k; ``radius`` is R.
    """
    i = start + wp.tid()
    texels = map_size * map_size
    k = i // texels
    t = i - k * texels
    a = t % map_size
    b = t // map_size
    s = positional_sample(k, side)
    direction = texel_direction(tangent_frame(-s), a, b, map_size)
    diameter = 2.0 * radius
    distances[i] = 2.0
    q = trace_closest(scene, s * radius, direction, diameter)
    if q.result:
        distances[i] = q.t / diameter


# ---------------------------------------------------------------------------
# Pure functions


def side_for(positional_samples: int) -> int:
    """n with n^2 nearest to ``positional_samples`` (at least 2)."""
    return max(2, int(round(math.sqrt(positional_samples))))


def bounding_sphere(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (box centre) and radius (farthest point, grown by SPHERE_INFLATION) of (P, 3) points."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(3), 0.0
    center = (points.min(axis=0) + points.max(axis=0)) / 2
    radius = float(np.sqrt(((points - center) ** 2).sum(axis=1).max()))
    return center, radius * (1.0 + SPHERE_INFLATION)


RIGID_MATCH_RELATIVE = 1e-5
"""Two prototypes of one topology are one shape when a rigid motion takes one's points onto the other's within
this fraction of its bounding-box size: float rounding of the inverse instance transform, or of points
re-authored in another frame, lies far below it (1e-7 for float32), the field's distance step (2R / 508) far
above it."""


def topology_key(points: np.ndarray, triangles: np.ndarray) -> str:
    """Hash of what a rigid motion leaves exactly as it is: the point count and the triangles (vertex order
    included). Prototypes with one key are compared point by point (``ShapeIndex``)."""
    digest = hashlib.sha256(f"{len(points)}".encode())
    digest.update(np.ascontiguousarray(triangles, np.int32).tobytes())
    return digest.hexdigest()


def spread(points: np.ndarray) -> np.ndarray:
    """(3,) descending RMS extents of centred points along their principal axes (singular values / sqrt(P)):
    unchanged by a rigid motion, and moved by at most 2 d when no point moves more than d (Weyl's inequality
    for singular values), so shapes whose spreads differ by more cannot match within d."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    centred = points - points.mean(axis=0)
    return np.linalg.svd(centred, compute_uv=False) / np.sqrt(max(len(points), 1))


class ShapeIndex:
    """Prototypes seen so far, found again up to a rigid motion and float rounding (``RIGID_MATCH_RELATIVE``).

    Candidates share the topology key and a spread within the tolerance; the match itself is
    ``processors.instancing.transforms.rigid_alignment``, point for point. A prototype costs O(P) for its key and spread,
    one spread comparison per stored prototype of its topology, and O(P) per one whose spread agrees.
    """

    def __init__(self):
        self._shapes: dict[str, list] = {}

    def find(self, points: np.ndarray, triangles: np.ndarray):
        """(value, S) of a stored shape whose points S takes onto ``points`` ([stored, 1] @ S, row vectors), or
        None."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        tolerance = RIGID_MATCH_RELATIVE * (float(np.ptp(points, axis=0).max()) if len(points) else 0.0)
        mine = spread(points)
        for stored, stored_spread, value in self._shapes.get(topology_key(points, triangles), []):
            if np.abs(stored_spread - mine).max() > 2.0 * tolerance:
                continue
            motion = rigid_alignment(stored, points, tolerance=tolerance)
            if motion is not None:
                return value, motion
        return None

    def add(self, points: np.ndarray, triangles: np.ndarray, value) -> None:
        points = np.asarray(points, np.float64).reshape(-1, 3)
        self._shapes.setdefault(topology_key(points, triangles), []).append((points, spread(points), value))


def shared_field(field: DisplacementField, prototype: str, motion: np.ndarray) -> DisplacementField:
    """``field`` (built from another prototype) for ``prototype``, whose points are [built, 1] @ motion: the same
    texels, the frame composed with ``motion`` (instance_ao folds it into the instances' transforms)."""
    return dataclasses.replace(field, prototype=prototype, frame=np.asarray(field.frame, np.float64) @ motion)


def describe_motion(motion: np.ndarray) -> str:
    """'' for the identity, else how far a shared field is turned and moved (for the messages)."""
    rotation, translation = motion[:3, :3], motion[3, :3]
    angle = math.degrees(math.acos(float(np.clip((np.trace(rotation) - 1) / 2, -1.0, 1.0))))
    parts = ([f"rotated {angle:.3g} degrees"] if not np.array_equal(rotation, np.eye(3)) else []) + \
            ([f"moved {float(np.linalg.norm(translation)):.3g}"] if translation.any() else [])
    return ", ".join(parts)


def prototype_geometry(scene: Scene, prototype: int) -> tuple[np.ndarray, np.ndarray, int]:
    """The prototype's triangles in prototype space, recovered from one of its instances.

    Returns
    -------
    points : (P, 3) float64 prototype-space vertices
    triangles : (T, 3) int32
    instance : the instance used (-1 if no instance with a non-singular transform has triangles)
    """
    inst = scene.instances
    mine = np.flatnonzero(inst.instance_prototype == prototype)
    for j in mine[invertible(inst.instance_transforms[mine])]:
        matrix = inst.instance_transforms[j]
        tris = scene.tri_vertices[scene.tri_instance == j]
        if len(tris) == 0:
            continue
        used, local = np.unique(tris, return_inverse=True)
        world = np.c_[scene.points[used].astype(np.float64), np.ones(len(used))]
        points = (world @ np.linalg.inv(matrix))[:, :3]
        return points, local.reshape(-1, 3).astype(np.int32), int(j)
    return np.zeros((0, 3)), np.zeros((0, 3), np.int32), -1


def compute_field_distances(points: np.ndarray, triangles: np.ndarray, *, side: int, map_size: int,
                            device: str = "cpu", threads: int | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Cast a field's rays (Gaitatzes et al. 2008, Algorithm 1, Section 3.1; ``field_distances_kernel``).

    Parameters
    ----------
    points : (P, 3) float64 prototype-space vertices (stage units of the prototype)
    triangles : (T, 3) int32
    side, map_size : n and M (n^2 positional samples, M x M directions each)

    Returns
    -------
    distances : (n*n, M, M) float32 t / 2R of each ray's first hit (dimensionless; 2.0 = miss)
    center : (3,) float64 bounding-sphere centre c, prototype space
    radius : bounding-sphere radius R, prototype space
    """
    center, radius = bounding_sphere(points)
    if radius <= 0.0 or not np.isfinite(radius):
        raise ValueError("prototype has no extent (all vertices coincide)")
    tracer = Tracer((np.asarray(points, np.float64) - center).astype(np.float32), triangles, device=device,
                    threads=threads)
    count = side * side * map_size * map_size
    distances = wp.zeros(count, dtype=float, device=tracer.device)
    tracer.launch(field_distances_kernel, count, [tracer.scene, side, map_size, float(radius), distances])
    return distances.numpy().reshape(side * side, map_size, map_size), center, radius


def build_field(points: np.ndarray, triangles: np.ndarray, *, prototype: str = "", positional_samples: int = 4225,
                map_size: int = 32, encoding: str = "uint8", device: str = "cpu",
                threads: int | None = None) -> DisplacementField:
    """A prototype's displacement field from its prototype-space triangles: Algorithm 1 (Section 3.1), codes
    from ``processors.instancing.field_kernels.encode_field`` (``uint8``, or ``bit1`` after Section 4, "Further
    Memory Optimization")."""
    side = side_for(positional_samples)
    started = time.perf_counter()
    distances, center, radius = compute_field_distances(points, triangles, side=side, map_size=map_size,
                                                        device=device, threads=threads)
    texels, mean_codes = encode_field(distances, encoding)
    return DisplacementField(prototype=prototype, center=center, radius=radius, side=side, map_size=map_size,
                             encoding=encoding, texels=texels, mean_codes=mean_codes, triangles=len(triangles),
                             build_seconds=time.perf_counter() - started,
                             prototype_points=np.asarray(points, np.float32).reshape(-1, 3),
                             prototype_triangles=np.asarray(triangles, np.int32).reshape(-1, 3))


def field_file_name(prototype: str) -> str:
    """Texture path (relative to the bake layer) of a prototype's field: its prim path made file-safe."""
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", prototype.strip("/")) or "prototype"
    return f"displacement_fields/{stem}.png"


def field_records(field: DisplacementField, targets: tuple[str, ...] | None = None, *,
                  shared_from: str | None = None) -> list:
    """The field's texture, and the applied DisplacementFieldAPI with its attributes on each of
    ``targets`` (default: the field's prototype; for a native prototype, every instance root).
    ``shared_from``: the prototype whose texture (in the same outputs) this field reuses."""
    file_name = field_file_name(shared_from or field.prototype)
    records: list = [] if shared_from else [Texture(file_name, field_atlas(field)[:, :, None])]
    frame = np.asarray(field.frame, np.float64)
    center = np.r_[np.asarray(field.center, np.float64), 1.0] @ frame  # in the prim's space
    turned = not np.array_equal(frame[:3, :3], np.eye(3))
    for path in targets or (field.prototype,):
        records += [
            Prim(path, api_schemas=("DisplacementFieldAPI",)),
            Attribute(path, "bake:field:file", f"./{file_name}", "asset"),
            Attribute(path, "bake:field:center", center[:3].astype(np.float32), "point3f"),
            Attribute(path, "bake:field:radius", float(field.radius), "float"),
            Attribute(path, "bake:field:positionalSamples", int(field.side * field.side), "int"),
            Attribute(path, "bake:field:directionMapSize", np.array([field.map_size] * 2, np.int32), "int2"),
            Attribute(path, "bake:field:encoding", field.encoding, "token"),
            Attribute(path, "bake:field:positionMapping", POSITION_MAPPING, "token"),
            Attribute(path, "bake:field:directionMapping", DIRECTION_MAPPING, "token"),
        ]
        if turned:  # the texture is laid out in a turned frame: say how (module docstring)
            records.append(Attribute(path, "bake:field:orientation",
                                     rotation_quaternion(frame[:3, :3]).astype(np.float32), "quatf"))
    return records


def _matches(path: str, names: set[str]) -> bool:
    return path in names or path.rsplit("/", 1)[-1] in names


def _name_set(text: str) -> set[str]:
    return {name.strip() for name in text.split(",") if name.strip()}


def choose_prototypes(scene: Scene, p) -> tuple[list[int], list[str]]:
    """Prototype indices that get a field, and one message per decision (the cost model)."""
    inst = scene.instances
    counts = np.bincount(inst.instance_prototype, minlength=len(inst.prototype_paths))
    build_rays = side_for(p.positional_samples) ** 2 * p.direction_map_size ** 2
    force, forbid = _name_set(p.force), _name_set(p.forbid)
    chosen, messages = [], []
    for index, path in enumerate(inst.prototype_paths):
        expected = counts[index] * p.expected_rays_per_instance
        if _matches(path, forbid):
            messages.append(f"{path}: no field (forbidden)")
        elif _matches(path, force):
            chosen.append(index)
            messages.append(f"{path}: field (forced)")
        elif counts[index] < p.min_instances:
            messages.append(f"{path}: no field ({counts[index]} instance(s) < min_instances={p.min_instances})")
        elif expected < build_rays:
            messages.append(f"{path}: no field ({counts[index]} instances x {p.expected_rays_per_instance:.3g} "
                            f"expected rays = {expected:.3g} < {build_rays:.3g} build rays)")
        else:
            chosen.append(index)
            messages.append(f"{path}: field ({counts[index]} instances x {p.expected_rays_per_instance:.3g} "
                            f"expected rays = {expected:.3g} >= {build_rays:.3g} build rays)")
    return chosen, messages


# ---------------------------------------------------------------------------
# Processor


class DisplacementFields(Processor):
    name = "displacement_fields"
    version = "2"
    summary = "Per-prototype presampled visibility (displacement fields) for instance_ao."
    facets = ("geometry", "instancers")
    writes = ("bake:field:",)
    provides = (DisplacementFieldSet,)

    @dataclass(frozen=True)
    class Params(Params):
        positional_samples: int = param(4225, "samples on the bounding sphere, rounded to a square n^2 "
                                              "(equal-area octahedral grid; paper: 1090-4226)", low=4, high=66049)
        direction_map_size: int = param(32, "M: each sample's direction map is M x M (paper: 32-64)",
                                        low=4, high=256)
        encoding: str = param("uint8", "uint8 (8-bit distance) or bit1 (hit bit + mean distance per sample)",
                              choices=("uint8", "bit1"))
        min_instances: int = param(2, "prototypes with fewer instances get no field (unless forced)", low=1)
        expected_rays_per_instance: float = param(1e6, "rays expected to meet one instance over the field's "
                                                       "lifetime (cost model)", low=0.0)
        force: str = param("", "comma-separated prototype paths or names that always get a field")
        forbid: str = param("", "comma-separated prototype paths or names that never get a field")

        def __post_init__(self) -> None:
            super().__post_init__()
            texels = side_for(self.positional_samples) ** 2 * self.direction_map_size ** 2
            if texels > MAX_FIELD_TEXELS:
                raise ParamError(f"positional_samples={self.positional_samples} x direction_map_size="
                                 f"{self.direction_map_size}^2 = {texels} rays per prototype is above the "
                                 f"maximum {MAX_FIELD_TEXELS} ({MAX_FIELD_TEXELS // 2**20} MiB per 8-bit field)")
            if self.encoding == "bit1" and self.direction_map_size % 8:
                raise ParamError(f"direction_map_size={self.direction_map_size} must be a multiple of 8 "
                                 f"with encoding=bit1 (8 texels per byte)")

    def applies(self, ctx: Context) -> tuple[bool, str]:
        scene = ctx.scene
        if len(scene.instances) == 0:
            return False, "no instanced prototypes"
        chosen, _ = choose_prototypes(scene, self.params)
        if not chosen:
            return False, "no prototype pays off (cost model: instances x expected rays < build rays)"
        names = ", ".join(scene.instances.prototype_paths[index].rsplit("/", 1)[-1] for index in chosen)
        return True, f"pays off for {names} (cost model)"

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        chosen, messages = choose_prototypes(scene, p)
        device = ctx.device
        result = Result(products={DisplacementFieldSet: DisplacementFieldSet({})}, messages=messages)
        rays = 0
        built = ShapeIndex()
        for step, index in enumerate(chosen):
            path = scene.instances.prototype_paths[index]
            points, triangles, instance = prototype_geometry(scene, index)
            if instance < 0:
                result.messages.append(f"{path}: no field (no instance with triangles and an invertible transform)")
                continue
            match = built.find(points, triangles)
            if match is not None:  # the same shape as a prototype already done, maybe moved: share its field
                source, motion = match
                field = shared_field(source, path, motion)
                result.products[DisplacementFieldSet].fields[path] = field
                result.outputs.extend(field_records(field, scene.instances.targets(index),
                                                    shared_from=source.prototype))
                how = describe_motion(motion)
                result.messages.append(f"{path}: shares the field of {source.prototype} (same shape"
                                       f"{', ' + how if how else ''})")
                continue
            try:
                field = build_field(points, triangles, prototype=path, positional_samples=p.positional_samples,
                                    map_size=p.direction_map_size, encoding=p.encoding, device=str(device),
                                    threads=ctx.threads)
            except ValueError as error:
                result.messages.append(f"{path}: no field ({error})")
                continue
            rays += field.side ** 2 * field.map_size ** 2
            built.add(points, triangles, field)
            result.products[DisplacementFieldSet].fields[path] = field
            result.outputs.extend(field_records(field, scene.instances.targets(index)))
            result.stats[f"bytes:{path}"] = float(field.nbytes)
            ctx.progress((step + 1) / max(1, len(chosen)))
        result.stats["rays"] = float(rays)
        result.stats["fields"] = float(len(result.products[DisplacementFieldSet].fields))
        return result
