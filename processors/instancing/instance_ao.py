"""Ambient occlusion of receivers by instanced prototypes through displacement fields.

Gaitatzes, Chrysanthou & Papaioannou, "Presampled visibility for ambient
occlusion", Journal of WSCG 16 (2008), Algorithm 2. The AO estimate is the
one ``ambient_occlusion`` computes (same stratified concentric + Malley
cosine rays, same seeds, same ray offset, so the two are interchangeable and
differ only by the field approximation)::

    AO(x) = 1/pi * integral_{H(n)} V(x, w) cos(theta) dw  ~  mean over rays of V

with V evaluated per ray as

- 0 if the ray hits geometry that has no field (ordinary meshes, instance
  proxies of instanceable prims, instances of prototypes without a field,
  instances with a singular transform), through a BVH of those triangles only;
- else the product over the instances whose bounding sphere the ray meets
  (found through a small BVH over the instances' sphere bounds, refitted per
  frame) of the field's visibility: the ray is mapped into the prototype's
  frame by the inverse instance transform (affine maps keep lines and the
  ray parameter, so rotation, non-uniform scale and shear are exact), its
  entry point on the sphere picks the positional sample(s) through the
  inverse equal-area octahedral map, its direction in each sample's frame
  picks the texel(s) through the inverse concentric map, and the stored
  distance decides the hit: hit when entry distance + stored distance lies in
  [-tolerance, max_distance]. ``nearest`` (default) uses one sample and one
  texel, as in the paper; ``quadrilinear`` blends the hit decisions of the 4
  nearest positional samples x 4 nearest texels (the paper's suggested
  trilinear scheme, extended to the positional grid), so V becomes
  fractional near silhouettes. Measured, the blend smooths but does not
  lower the error (it widens every silhouette to two cells): nearest has
  the lowest RMS on instanced_props.usda, see docs/displacement_fields.md.

A receiver point inside an instance's sphere (a floor next to a vase) uses
the entry point of the ray's line, behind the origin, and counts the stored
hit only if it lies ahead of the origin; if the first hit along the line lies
behind the origin, a further hit ahead is not known (the field stores first
hits only) and the ray counts as unoccluded by that instance.

The field format and its lookup (``field_visibility``) live in
``processors.instancing.field_kernels``, shared with the producer ``displacement_fields``;
the rays, in ``kernels.occlusion``, shared with ``ambient_occlusion``.

Per time sample: with ``frames``, the instance transforms authored at those
time codes (``Scene.instances.instance_transforms_at_times``) are used in
turn; fields and the triangle BVH are built once, only the sphere bounds are
refitted per frame. Geometry without a field stays where it was extracted.

USD written (bake layer):

================ ======= ============= ======================================================
property         type    interpolation when
================ ======= ============= ======================================================
primvars:bake:ao float[] vertex        per receiver prim, one value per authored point;
                                       default value, or one time sample per frame
primvars:bake:ao float[] vertex        ``instances``: on each PointInstancer, one value per
                                       authored instance (vertex = per instance there): the
                                       area-weighted mean AO over the instance's vertices
================ ======= ============= ======================================================

``primvars:bake:ao`` is the property ``ambient_occlusion`` writes: run one
or the other on a stage, not both (the last record authored would win).

Parameters: ``usdbake list instance_ao`` or docs/displacement_fields.md, both generated from ``Params`` below.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ...core import Context, Params, Primvar, Processor, Result, param
from .products import DisplacementFieldSet, InstanceOcclusionProduct
from ...geometry.mesh import missing_receivers, receiver_prims, vertex_inward, vertex_normals
from .transforms import invertible
from .field_kernels import INTERPOLATION_MODES, FieldArrays, FieldSet, field_visibility
from .instance_points import InstancePoints
from ...kernels.occlusion import AORays, ao_direction, ao_point, ao_rays, as_points_and_normals, launch_ao
from ...kernels.sampling import strata_for
from ...kernels.tracer import FAR, Tracer, surface_origin
from ...kernels.traversal import trace_any, trace_any_in_instance

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

FRAME_MATCH = 1e-6
"""Requested frames match authored time codes within this."""


# ---------------------------------------------------------------------------
# Warp kernels


@wp.struct
class InstanceArrays:
    """The instances at one frame, as the kernels take them (filled by ``InstanceSpheres``, rewritten per frame)."""

    instance_bounds: wp.uint64
    """BVH over the instances' bounding-sphere boxes (world space)."""
    instance_field: wp.array(dtype=int)
    """(I,) int32 field of each instance, -1 for none (such instances are traced as triangles)."""
    instance_inverse_linear: wp.array(dtype=wp.mat33)
    """(I,) world -> prototype linear part A (column convention: proto = A @ world + b)."""
    instance_inverse_offset: wp.array(dtype=wp.vec3)
    """(I,) world -> prototype offset b (prototype units)."""


@wp.kernel
def instance_ao_kernel(
    start: int,
    rays: AORays,
    instances: InstanceArrays,
    fields: FieldArrays,
    positions: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    inward: wp.array(dtype=wp.vec3),
    own: wp.array(dtype=int),
    interpolate: int,
    ao: wp.array(dtype=float),
):
    """Algorithm 2 of Gaitatzes et al. 2008: AO(x) = 1/pi * integral V(x, w) cos(theta) dw (their Section 1;
    dimensionless, [0, 1]) at
    point i, estimated with the rays of ``kernels.occlusion`` (the rays of
    ambient_occlusion.vertex_ao_kernel with the same seed). Per ray, V = 0 if it hits a traced triangle
    (``rays.scene``) within ``max_distance`` (stage units), else the product of ``field_visibility``
    (Section 3.2) over the instances whose sphere bounds (``instances.instance_bounds``) it meets.

    A point on an instance (own[i] >= 0) traces its own prototype's triangles for self-occlusion (in
    prototype space, distances scaled back to world) and skips its own field.
    """
    i = start + wp.tid()
    n = normals[i]
    if wp.length(n) < 0.5:
        ao[i] = 1.0
        return
    point = ao_point(rays, n, i)
    origin = surface_origin(rays.scene, positions[i], n, inward[i], rays.epsilon)
    count = rays.strata * rays.strata
    visible = float(0.0)
    next_direction = ao_direction(rays, point, 0)
    for k in range(count):
        direction = next_direction
        next_direction = ao_direction(rays, point, wp.min(k + 1, count - 1))  # made during this ray's trace
        if trace_any(rays.scene, origin, direction, rays.max_distance):
            continue
        self_instance = own[i]
        if self_instance >= 0:
            linear = instances.instance_inverse_linear[self_instance]
            local_direction = linear * direction
            scale = wp.length(local_direction)
            if scale > 0.0:
                if trace_any_in_instance(fields.prototypes, instances.instance_field[self_instance],
                                         linear * origin + instances.instance_inverse_offset[self_instance],
                                         local_direction / scale, rays.max_distance * scale):
                    continue
        v = float(1.0)
        query = wp.bvh_query_ray(instances.instance_bounds, origin, direction)
        item = int(0)
        while wp.bvh_query_next(query, item, rays.max_distance):
            f = instances.instance_field[item]
            if f >= 0 and v > 0.0 and item != self_instance:
                v = v * field_visibility(origin, direction, rays.max_distance,
                                         instances.instance_inverse_linear[item],
                                         instances.instance_inverse_offset[item], fields, f, interpolate)
        visible += v
    ao[i] = visible / float(count)


@wp.kernel
def field_query_kernel(start: int, instances: InstanceArrays, fields: FieldArrays, origins: wp.array(dtype=wp.vec3),
                       directions: wp.array(dtype=wp.vec3), max_distance: float, interpolate: int,
                       visibility: wp.array(dtype=float)):
    """V in [0, 1] of single world rays (unit directions; max_distance in stage units) through instance 0 of
    field 0: the lookup of Gaitatzes et al. 2008, Section 3.2, alone (``field_visibility``), for tests and
    the per-ray benchmark."""
    i = start + wp.tid()
    visibility[i] = field_visibility(origins[i], directions[i], max_distance, instances.instance_inverse_linear[0],
                                     instances.instance_inverse_offset[0], fields, 0, interpolate)


# ---------------------------------------------------------------------------
# Pure functions


class InstanceSpheres:
    """Per-instance inverse transforms and a BVH over the instances' bounding-sphere boxes (refit per frame);
    ``arrays`` is the InstanceArrays the kernels take (the same device arrays, rewritten in place)."""

    def __init__(self, fieldset: FieldSet, instance_field: np.ndarray, transforms: np.ndarray):
        self.fieldset = fieldset
        self.instance_field = np.asarray(instance_field, np.int32)
        device = fieldset.device
        count = max(1, len(self.instance_field))
        field = np.full(count, -1, np.int32)
        field[:len(self.instance_field)] = self.instance_field
        self.field = wp.array(field, dtype=int, device=device)
        self.inverse_linear = wp.zeros(count, dtype=wp.mat33, device=device)
        self.inverse_offset = wp.zeros(count, dtype=wp.vec3, device=device)
        self.lowers = wp.zeros(count, dtype=wp.vec3, device=device)
        self.uppers = wp.zeros(count, dtype=wp.vec3, device=device)
        self.bvh = None
        self.arrays = InstanceArrays()
        self.arrays.instance_field = self.field
        self.arrays.instance_inverse_linear = self.inverse_linear
        self.arrays.instance_inverse_offset = self.inverse_offset
        self.update(transforms)

    def update(self, transforms: np.ndarray) -> None:
        """Point the instances at new (I, 4, 4) field-to-world matrices (row vectors: prototype-to-world ones
        after the field's ``frame``, ``field_slots``): arrays rewritten, BVH refitted."""
        transforms = np.asarray(transforms, np.float64).reshape(-1, 4, 4)
        count = max(1, len(self.instance_field))
        linear = np.zeros((count, 3, 3), np.float32)
        offset = np.zeros((count, 3), np.float32)
        lowers = np.full((count, 3), FAR / 4, np.float32)  # unused slots: a box no ray reaches
        uppers = np.full((count, 3), FAR / 4, np.float32)
        usable = (self.instance_field >= 0) & invertible(transforms)
        fields = self.fieldset.fields
        for j in np.flatnonzero(usable):
            matrix = transforms[j]
            inverse = np.linalg.inv(matrix)
            linear[j] = inverse[:3, :3].T  # column convention: proto = A @ world + b
            offset[j] = inverse[3, :3]
            field = fields[self.instance_field[j]]
            center = np.r_[field.center, 1.0] @ matrix
            half = field.radius * np.linalg.norm(matrix[:3, :3], axis=0) * (1 + 1e-5)
            lowers[j] = center[:3] - half
            uppers[j] = center[:3] + half
        if not np.isfinite(lowers).all() or not np.isfinite(uppers).all():
            raise ValueError("instance bounds are not finite")
        self.usable = usable
        self.inverse_linear.assign(wp.array(linear, dtype=wp.mat33, device=self.fieldset.device))
        self.inverse_offset.assign(wp.array(offset, dtype=wp.vec3, device=self.fieldset.device))
        self.lowers.assign(wp.array(lowers, dtype=wp.vec3, device=self.fieldset.device))
        self.uppers.assign(wp.array(uppers, dtype=wp.vec3, device=self.fieldset.device))
        if self.bvh is None:
            self.bvh = wp.Bvh(self.lowers, self.uppers)
            self.arrays.instance_bounds = self.bvh.id
        else:
            self.bvh.refit()


def compute_instance_ao(tracer: Tracer, spheres: InstanceSpheres, positions: np.ndarray, normals: np.ndarray, *,
                        samples: int, epsilon: float, max_distance: float = math.inf, seed: int = 0,
                        interpolation: str = "nearest", own: np.ndarray | None = None,
                        inward: np.ndarray | None = None) -> np.ndarray:
    """AO at points with unit normals by Algorithm 2 of Gaitatzes et al. 2008 (``instance_ao_kernel``; the
    AO integral of their Section 1): geometry without a field through ``tracer``, instances through
    their fields (Section 3.2).

    Parameters
    ----------
    tracer : Tracer over the triangles without a field
    spheres : InstanceSpheres at the wanted frame
    positions, normals : (N, 3) float32, stage units and unit vectors
    epsilon : ray origin offset along the normal, stage units
    max_distance : stage units; farther hits do not occlude
    own : (N,) int32, optional
        Instance each point belongs to (-1: a receiver); such points trace their own prototype for
        self-occlusion and skip their own field.
    inward : (N, 3) float32 unit tangents into each point's own surface (``vertex_inward``); None: zero

    Returns
    -------
    (N,) float32 in [0, 1]; 1 where the normal is zero.
    """
    positions, normals = as_points_and_normals(positions, normals)
    own = np.full(len(positions), -1, np.int32) if own is None else np.ascontiguousarray(own, np.int32)
    if own.shape != (len(positions),):
        raise ValueError(f"own {own.shape} does not match {len(positions)} positions")
    inward = np.zeros_like(positions) if inward is None else np.ascontiguousarray(inward, np.float32).reshape(-1, 3)
    rays = ao_rays(tracer.scene, samples=samples, max_distance=max_distance, epsilon=epsilon, seed=seed,
                   device=tracer.device)
    return launch_ao(tracer, instance_ao_kernel, len(positions), rays, [
        spheres.arrays, spheres.fieldset.arrays, tracer.array(positions, wp.vec3), tracer.array(normals, wp.vec3),
        tracer.array(inward, wp.vec3), tracer.array(own, wp.int32), INTERPOLATION_MODES[interpolation],
    ])


def field_slots(prototype_paths, fields_by_path: dict) -> tuple[list, np.ndarray, np.ndarray]:
    """The distinct fields, and where each prototype finds its own.

    Prototypes that share a field (``displacement_fields.ShapeIndex``: one shape, perhaps moved) share one
    slot, so its texels and its prototype BVH are on the device once.

    Returns
    -------
    fields : the DisplacementFields of the slots, in first-use order
    proto_field : (K,) int32 slot of each prototype, -1 without a field
    proto_frame : (K, 4, 4) float64 row-vector motion from the slot's frame to the prototype's space
        (``DisplacementField.frame``): [x_slot, 1] @ frame @ instance transform is the world position
    """
    fields, slot_of = [], {}
    proto_field = np.full(len(prototype_paths), -1, np.int32)
    proto_frame = np.tile(np.eye(4), (len(prototype_paths), 1, 1))
    for k, path in enumerate(prototype_paths):
        field = fields_by_path.get(path)
        if field is None:
            continue
        key = id(field.texels)  # shared fields hold the very texels of the field they share
        if key not in slot_of:
            slot_of[key] = len(fields)
            fields.append(field)
        slot = fields[slot_of[key]]
        proto_field[k] = slot_of[key]
        # Both frames start where the texels were built: the slot's frame back to there, then this one's.
        proto_frame[k] = np.linalg.inv(np.asarray(slot.frame, np.float64)) @ np.asarray(field.frame, np.float64)
    return fields, proto_field, proto_frame


def query_field(field, transform: np.ndarray, origins: np.ndarray, directions: np.ndarray, *,
                max_distance: float = math.inf, interpolation: str = "nearest", device: str = "cpu",
                tracer: Tracer | None = None) -> np.ndarray:
    """(N,) float32 visibility in [0, 1] of world rays (unit directions) through one instance of ``field``
    (Gaitatzes et al. 2008, Section 3.2; ``field_query_kernel``).

    ``transform`` is the (4, 4) prototype-to-world matrix (row-vector convention), composed here with the
    field's ``frame``; ``max_distance`` in stage units.
    """
    fieldset = FieldSet([field], device)
    to_world = np.asarray(field.frame, np.float64) @ np.asarray(transform, np.float64)
    spheres = InstanceSpheres(fieldset, np.zeros(1, np.int32), to_world[None])
    origins = np.ascontiguousarray(origins, np.float32).reshape(-1, 3)
    directions = np.ascontiguousarray(directions, np.float32).reshape(-1, 3)
    visibility = wp.zeros(len(origins), dtype=float, device=device)
    inputs = [spheres.arrays, fieldset.arrays, wp.array(origins, dtype=wp.vec3, device=device),
              wp.array(directions, dtype=wp.vec3, device=device), float(min(max_distance, FAR)),
              INTERPOLATION_MODES[interpolation], visibility]
    if tracer is not None:
        tracer.launch(field_query_kernel, len(origins), inputs)
    else:
        wp.launch(field_query_kernel, dim=len(origins), inputs=[0, *inputs], device=device)
    return visibility.numpy()


def parse_frames(text: str, available: np.ndarray) -> list[float] | None:
    """Time codes selected by ``frames`` ('' -> None: the extraction time); each must be an authored one."""
    text = text.strip()
    if not text:
        return None
    available = np.asarray(available, np.float64)
    if text == "all":
        wanted = list(available)
    elif ":" in text:
        parts = [float(x) for x in text.split(":")]
        if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2] <= 0):
            raise ValueError(f"frames={text!r}: expected 'start:stop' or 'start:stop:step' with step > 0")
        step = parts[2] if len(parts) == 3 else 1.0
        wanted = list(np.arange(parts[0], parts[1] + step * 0.5, step))
    else:
        wanted = [float(x) for x in text.split(",") if x.strip()]
    if not wanted:
        raise ValueError(f"frames={text!r} selects no time codes")
    missing = [t for t in wanted if not len(available) or np.abs(available - t).min() > FRAME_MATCH]
    if missing:
        shown = ", ".join(f"{t:g}" for t in available) or "none"
        raise ValueError(f"frames={text!r}: time code(s) {', '.join(f'{t:g}' for t in missing)} have no authored "
                         f"instance transforms (authored: {shown})")
    return [float(available[np.abs(available - t).argmin()]) for t in wanted]


class InstanceAO(Processor):
    name = "instance_ao"
    version = "2"
    summary = "Per-vertex AO with instanced prototypes looked up in displacement fields (per frame, no BVH rebuild)."
    facets = ("geometry", "instancers")
    follows_refinement = True
    writes = ("primvars:bake:ao",)
    requires = (DisplacementFieldSet,)
    provides = (InstanceOcclusionProduct,)

    @dataclass(frozen=True)
    class Params(Params):
        samples: int = param(256, "rays per point (rounded to a square for stratification)", low=1, high=65536)
        max_distance: float = param(math.inf, "hits farther than this (stage units) do not occlude", low=0.0)
        interpolation: str = param("nearest", "nearest (1 sample x 1 texel, the paper), position, direction "
                                              "or quadrilinear (bilinear blends of 4 samples and/or 4 texels)",
                                   choices=tuple(INTERPOLATION_MODES))
        frames: str = param("", "'' (extraction time), 'all', 'a:b[:step]' or 'f1,f2,...': time codes to bake")
        instances: bool = param(False, "also AO at the instances' vertices (self + mutual occlusion); writes the "
                                       "area-weighted mean per instance on the PointInstancer")
        seed: int = param(0, "random seed (the same rays as ambient_occlusion with this seed)", low=0)

    def applies(self, ctx: Context) -> tuple[bool, str]:
        if ctx.params.instances and len(ctx.scene.instances):  # AO at the instances' own vertices
            return True, ""
        reason = missing_receivers(ctx.scene)
        return not reason, reason

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        inst = scene.instances
        frames = parse_frames(p.frames, inst.instance_times)
        fields_by_path = ctx.products.get(DisplacementFieldSet, DisplacementFieldSet({})).fields
        fields, proto_field, proto_frame = field_slots(inst.prototype_paths, fields_by_path)
        instance_field = proto_field[inst.instance_prototype] if len(inst) else np.zeros(0, np.int32)
        instance_field = np.where(invertible(inst.instance_transforms), instance_field, -1).astype(np.int32)
        # Field frame -> world: a shared field's frame folded into the transforms of its prototype's instances.
        instance_frame = proto_frame[inst.instance_prototype] if len(inst) else np.zeros((0, 4, 4))
        # Triangles without a usable field go through the BVH (built once, also for every frame).
        tri_field = np.where(scene.tri_instance >= 0, instance_field[np.maximum(scene.tri_instance, 0)]
                             if len(inst) else -1, -1)
        traced = np.flatnonzero(tri_field < 0)
        # Over every scene point, so tracer.epsilon is the scene tracer's ray offset (as in ambient_occlusion).
        tracer = Tracer(scene.points, scene.tri_vertices[traced], device=ctx.device, threads=ctx.threads)
        fieldset = FieldSet(fields, tracer.device)
        receivers = receiver_prims(scene)
        normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
        inward = vertex_inward(scene.points, scene.tri_vertices, normals)
        point_ids = np.flatnonzero(np.isin(scene.point_prim, receivers))
        result = Result(products={})
        moving = int((instance_field < 0).sum())
        if frames is not None and moving:
            result.messages.append(f"{moving} instance(s) without a field keep their extraction-time position in "
                                   f"every frame")
        spheres = InstanceSpheres(fieldset, instance_field, instance_frame @ inst.instance_transforms)
        on_instances = InstancePoints(scene, normals, inward, instance_field) if p.instances and len(inst) else None
        by_frame, by_frame_instances = {}, {}
        for step, frame in enumerate(frames or [None]):
            transforms = inst.instance_transforms
            if frame is not None:
                transforms = inst.instance_transforms_at_times[int(np.abs(inst.instance_times - frame).argmin())]
                spheres.update(instance_frame @ transforms)
            if on_instances is not None:
                positions, instance_normals, instance_inward = on_instances.at(transforms)
                ao_instances = compute_instance_ao(
                    tracer, spheres, positions, instance_normals, samples=p.samples, epsilon=tracer.epsilon,
                    max_distance=p.max_distance, seed=p.seed, interpolation=p.interpolation, own=on_instances.own,
                    inward=instance_inward)
                by_frame_instances[frame] = on_instances.means(ao_instances)
                result.outputs.extend(on_instances.records(by_frame_instances[frame], frame))
            ao_points = np.ones(scene.num_points, np.float32)
            ao_points[point_ids] = compute_instance_ao(
                tracer, spheres, scene.points[point_ids], normals[point_ids], samples=p.samples,
                epsilon=tracer.epsilon, max_distance=p.max_distance, seed=p.seed, interpolation=p.interpolation,
                inward=inward[point_ids])
            by_frame[frame] = ao_points
            for prim in receivers:
                result.outputs.append(Primvar(scene.prim_paths[prim], "bake:ao", ao_points[scene.prim_points(prim)],
                                              "float", "vertex", time=frame))
            ctx.progress((step + 1) / len(frames or [None]))
        result.products[InstanceOcclusionProduct] = InstanceOcclusionProduct(by_frame, by_frame_instances)
        instance_points = len(on_instances.point_ids) if on_instances is not None else 0
        result.stats["rays"] = float((len(point_ids) + instance_points) * strata_for(p.samples) ** 2 * len(by_frame))
        result.stats["fields"] = float(len(fields))
        result.stats["traced_triangles"] = float(len(traced))
        if not fields:
            result.messages.append("no displacement fields: every instance is traced as triangles")
        return result
