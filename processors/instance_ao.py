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

Parameters
----------
============= ===== ============ =================================================================
name          type  default      meaning
============= ===== ============ =================================================================
samples       int   256          rays per point (rounded to a square for stratification)
max_distance  float inf          hits farther than this (stage units) do not occlude
interpolation str   nearest      nearest (1 sample x 1 texel, the paper), position (bilinear over
                                 4 samples), direction (bilinear over 4 texels) or quadrilinear (both)
frames        str   ''           '' (extraction time), 'all', 'a:b[:step]' or 'f1,f2,...': time codes
                                 whose authored instance transforms get an AO time sample each
instances     bool  False        also AO at the instances' own vertices: self-occlusion traced through
                                 the prototype's BVH (in prototype space), mutual occlusion through
                                 the other instances' fields; written per instance (area-weighted mean)
seed          int   0            random seed (the same rays as ambient_occlusion with this seed)
============= ===== ============ =================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core import Context, Params, Primvar, Processor, Result, param
from ..core.products import DisplacementFieldSet, InstanceOcclusionProduct
from ..kernels.sampling import cosine_hemisphere, strata_for, stratified_pair, tangent_frame
from ..kernels.sphere_maps import (equal_area_sphere_to_square, equal_area_square_to_sphere,
                                  malley_direction_to_square, octahedral_wrap)
from ..geometry.mesh import receiver_prims, vertex_normals
from ..core.scene import Scene
from ..kernels.tracer import RAY_EPSILON_RELATIVE, Tracer

wp.set_module_options({"enable_backward": False})

MISS_CODE = 255
"""Field code of a ray that leaves the sphere without a hit (as in displacement_fields)."""
MAX_HIT_CODE = 254
"""Codes 0..254 are hit distances t / 2R * 254."""
SINGULAR_DETERMINANT = 1e-12
"""|det| of an instance's 3x3 below this (relative to its scale cubed): traced as triangles instead."""
FRAME_MATCH = 1e-6
"""Requested frames match authored time codes within this."""
FAR = 3.0e38
INTERPOLATE_POSITION = wp.constant(1)
INTERPOLATE_DIRECTION = wp.constant(2)
INTERPOLATION_MODES = {"nearest": 0, "position": 1, "direction": 2, "quadrilinear": 3}


# ---------------------------------------------------------------------------
# Warp functions and kernels


@wp.func
def texel_code(texels: wp.array(dtype=wp.uint8), means: wp.array(dtype=wp.uint8), offset: int,
               mean_offset: int, bits: int, map_size: int, k: int, a: int, b: int) -> int:
    """Distance code of texel (a, b) of sample k: the stored code (uint8), or the sample's mean code if the bit
    is set (bit1)."""
    texel = b * map_size + a
    if bits == 0:
        return int(texels[offset + k * map_size * map_size + texel])
    byte = int(texels[offset + k * (map_size * map_size // 8) + texel // 8])
    if ((byte >> (texel % 8)) & 1) == 1:
        return int(means[mean_offset + k])
    return MISS_CODE


@wp.func
def code_hits(code: int, t_entry: float, scale: float, diameter: float, max_distance: float) -> float:
    """1 if the stored hit lies in [-one code step, max_distance] from the ray origin (world units), else 0.

    ``t_entry`` is the world distance from the origin to the ray's entry into the sphere.
    """
    if code == MISS_CODE:
        return 0.0
    t_hit = t_entry + float(code) / float(MAX_HIT_CODE) * diameter * scale
    if t_hit >= -diameter * scale / float(MAX_HIT_CODE) and t_hit <= max_distance:
        return 1.0
    return 0.0


@wp.func
def sample_hit(texels: wp.array(dtype=wp.uint8), means: wp.array(dtype=wp.uint8), offset: int, mean_offset: int,
               bits: int, side: int, map_size: int, k: int, direction: wp.vec3, t_entry: float,
               scale: float, diameter: float, max_distance: float, interpolate: int) -> wp.vec2:
    """(hit fraction, valid) of positional sample k for a prototype-space unit direction.

    The sample's stored ray is the one parallel to ours through p_k; its distance is used as if measured
    from our entry point (the paper's approximation; a parallax correction by (p_k - entry) . d measured
    no better on random rays and worse on instanced_props.usda, so it is left out).
    Invalid (y = 0) when the direction leaves the sphere at sample k (outside its inward hemisphere).
    """
    s = equal_area_square_to_sphere((float(k % side) + 0.5) / float(side), (float(k // side) + 0.5) / float(side))
    local = wp.transpose(tangent_frame(-s)) * direction
    if local[2] <= 0.0:
        return wp.vec2(0.0, 0.0)
    uv = malley_direction_to_square(local)
    if (interpolate & INTERPOLATE_DIRECTION) == 0:
        a = wp.min(int(uv[0] * float(map_size)), map_size - 1)
        b = wp.min(int(uv[1] * float(map_size)), map_size - 1)
        code = texel_code(texels, means, offset, mean_offset, bits, map_size, k, a, b)
        return wp.vec2(code_hits(code, t_entry, scale, diameter, max_distance), 1.0)
    gx = uv[0] * float(map_size) - 0.5
    gy = uv[1] * float(map_size) - 0.5
    a0 = int(wp.floor(gx))
    b0 = int(wp.floor(gy))
    fx = gx - float(a0)
    fy = gy - float(b0)
    hit = float(0.0)
    for corner in range(4):
        da = corner % 2
        db = corner // 2
        a = wp.clamp(a0 + da, 0, map_size - 1)
        b = wp.clamp(b0 + db, 0, map_size - 1)
        w = wp.where(da == 1, fx, 1.0 - fx) * wp.where(db == 1, fy, 1.0 - fy)
        code = texel_code(texels, means, offset, mean_offset, bits, map_size, k, a, b)
        hit += w * code_hits(code, t_entry, scale, diameter, max_distance)
    return wp.vec2(hit, 1.0)


@wp.func
def field_visibility(origin: wp.vec3, direction: wp.vec3, max_distance: float, inverse_linear: wp.mat33,
                     inverse_offset: wp.vec3, center: wp.vec3, radius: float, side: int, map_size: int, bits: int,
                     offset: int, mean_offset: int, texels: wp.array(dtype=wp.uint8),
                     means: wp.array(dtype=wp.uint8), interpolate: int) -> float:
    """Visibility in [0, 1] of a world ray (unit direction) through one instance, from its prototype's field.

    The affine inverse maps the ray to prototype space with the same parameter t, so t is world distance;
    prototype-space distances along the mapped direction d' convert to world by 1 / |d'|.
    """
    o = inverse_linear * origin + inverse_offset - center
    d = inverse_linear * direction
    a = wp.dot(d, d)
    if not (a > 0.0):
        return 1.0
    b = wp.dot(d, o)
    c = wp.dot(o, o) - radius * radius
    disc = b * b - a * c
    if not (disc > 0.0):
        return 1.0
    root = wp.sqrt(disc)
    t0 = (-b - root) / a
    t1 = (-b + root) / a
    if t1 <= 0.0 or t0 > max_distance:
        return 1.0
    length = wp.sqrt(a)
    dn = d / length
    scale = 1.0 / length  # world distance per prototype-space unit along this ray
    entry = o + d * t0
    entry_length = wp.length(entry)
    if not (entry_length > 0.0):
        return 1.0
    uv = equal_area_sphere_to_square(entry / entry_length)
    diameter = 2.0 * radius
    if (interpolate & INTERPOLATE_POSITION) == 0:
        i = wp.min(int(uv[0] * float(side)), side - 1)
        j = wp.min(int(uv[1] * float(side)), side - 1)
        r = sample_hit(texels, means, offset, mean_offset, bits, side, map_size, j * side + i, dn, t0,
                       scale, diameter, max_distance, interpolate)
        if r[1] > 0.0:
            return 1.0 - r[0]
        return 1.0
    gx = uv[0] * float(side) - 0.5
    gy = uv[1] * float(side) - 0.5
    i0 = int(wp.floor(gx))
    j0 = int(wp.floor(gy))
    fx = gx - float(i0)
    fy = gy - float(j0)
    hit = float(0.0)
    weight = float(0.0)
    for corner in range(4):
        di = corner % 2
        dj = corner // 2
        cell = octahedral_wrap(i0 + di, j0 + dj, side)
        w = wp.where(di == 1, fx, 1.0 - fx) * wp.where(dj == 1, fy, 1.0 - fy)
        r = sample_hit(texels, means, offset, mean_offset, bits, side, map_size, cell[1] * side + cell[0], dn,
                       t0, scale, diameter, max_distance, interpolate)
        hit += w * r[0]
        weight += w * r[1]
    if weight > 0.0:
        return 1.0 - hit / weight
    return 1.0


@wp.kernel
def instance_ao_kernel(
    start: int,
    mesh: wp.uint64,
    spheres: wp.uint64,
    positions: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    own: wp.array(dtype=int),
    strata: int,
    max_distance: float,
    epsilon: float,
    seed: int,
    interpolate: int,
    inverse_linear: wp.array(dtype=wp.mat33),
    inverse_offset: wp.array(dtype=wp.vec3),
    instance_field: wp.array(dtype=int),
    field_mesh: wp.array(dtype=wp.uint64),
    field_center: wp.array(dtype=wp.vec3),
    field_radius: wp.array(dtype=float),
    field_side: wp.array(dtype=int),
    field_map_size: wp.array(dtype=int),
    field_bits: wp.array(dtype=int),
    field_offset: wp.array(dtype=int),
    field_mean_offset: wp.array(dtype=int),
    texels: wp.array(dtype=wp.uint8),
    means: wp.array(dtype=wp.uint8),
    ao: wp.array(dtype=float),
):
    """Algorithm 2 at points with normals; the ray sequence matches ambient_occlusion.vertex_ao_kernel.

    A point on an instance (own[i] >= 0) traces its own prototype's triangles for self-occlusion (in
    prototype space) and skips its own field.
    """
    i = start + wp.tid()
    n = normals[i]
    if wp.length(n) < 0.5:
        ao[i] = 1.0
        return
    state = wp.rand_init(seed, i)
    frame = tangent_frame(n)
    origin = positions[i] + n * epsilon
    visible = float(0.0)
    for k in range(strata * strata):
        u = stratified_pair(k, strata, state)
        direction = frame * cosine_hemisphere(u[0], u[1])
        if wp.mesh_query_ray_anyhit(mesh, origin, direction, max_distance):
            continue
        self_instance = own[i]
        if self_instance >= 0:
            linear = inverse_linear[self_instance]
            local_direction = linear * direction
            scale = wp.length(local_direction)
            if scale > 0.0:
                if wp.mesh_query_ray_anyhit(field_mesh[instance_field[self_instance]],
                                            linear * origin + inverse_offset[self_instance],
                                            local_direction / scale, max_distance * scale):
                    continue
        v = float(1.0)
        query = wp.bvh_query_ray(spheres, origin, direction)
        item = int(0)
        while wp.bvh_query_next(query, item, max_distance):
            f = instance_field[item]
            if f >= 0 and v > 0.0 and item != self_instance:
                v = v * field_visibility(origin, direction, max_distance, inverse_linear[item], inverse_offset[item],
                                         field_center[f], field_radius[f], field_side[f], field_map_size[f],
                                         field_bits[f], field_offset[f], field_mean_offset[f], texels, means,
                                         interpolate)
        visible += v
    ao[i] = visible / float(strata * strata)


@wp.kernel
def field_query_kernel(
    start: int,
    origins: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    max_distance: float,
    interpolate: int,
    inverse_linear: wp.array(dtype=wp.mat33),
    inverse_offset: wp.array(dtype=wp.vec3),
    field_center: wp.array(dtype=wp.vec3),
    field_radius: wp.array(dtype=float),
    field_side: wp.array(dtype=int),
    field_map_size: wp.array(dtype=int),
    field_bits: wp.array(dtype=int),
    field_offset: wp.array(dtype=int),
    field_mean_offset: wp.array(dtype=int),
    texels: wp.array(dtype=wp.uint8),
    means: wp.array(dtype=wp.uint8),
    visibility: wp.array(dtype=float),
):
    """Visibility of single rays through instance 0 of field 0 (tests and the per-ray benchmark)."""
    i = start + wp.tid()
    visibility[i] = field_visibility(origins[i], directions[i], max_distance, inverse_linear[0], inverse_offset[0],
                                     field_center[0], field_radius[0], field_side[0], field_map_size[0],
                                     field_bits[0], field_offset[0], field_mean_offset[0], texels, means, interpolate)


# ---------------------------------------------------------------------------
# Pure functions


def invertible(transforms: np.ndarray) -> np.ndarray:
    """(I,) bool: finite transforms whose 3x3 part is not (numerically) singular."""
    transforms = np.asarray(transforms, np.float64).reshape(-1, 4, 4)
    finite = np.isfinite(transforms).all(axis=(1, 2))
    safe = np.where(finite[:, None, None], transforms, np.eye(4))
    scale = np.abs(safe[:, :3, :3]).max(axis=(1, 2))
    return finite & (np.abs(np.linalg.det(safe[:, :3, :3])) > SINGULAR_DETERMINANT * np.maximum(scale, 1e-300) ** 3)


class FieldSet:
    """Displacement fields packed into flat Warp arrays (built once, shared by every frame)."""

    def __init__(self, fields: list, device):
        self.fields = list(fields)
        self.device = device
        texel_parts, mean_parts, offsets, mean_offsets = [], [], [], []
        offset = mean_offset = 0
        for field in self.fields:
            texel_parts.append(np.ascontiguousarray(field.texels).ravel())
            means = np.ascontiguousarray(field.mean_codes, np.uint8).ravel()
            if len(means) != field.side ** 2:
                means = np.full(field.side ** 2, MISS_CODE, np.uint8)
            mean_parts.append(means)
            offsets.append(offset)
            mean_offsets.append(mean_offset)
            offset += texel_parts[-1].size
            mean_offset += means.size
        if offset >= 2 ** 31:
            raise ValueError(f"fields hold {offset} bytes; more than 2^31 is not supported in one run")
        cat = lambda parts: np.concatenate(parts) if parts else np.zeros(1, np.uint8)  # noqa: E731
        array = lambda values, dtype: wp.array(np.ascontiguousarray(values), dtype=dtype, device=device)  # noqa: E731
        self.texels = array(cat(texel_parts).astype(np.uint8), wp.uint8)
        self.means = array(cat(mean_parts).astype(np.uint8), wp.uint8)
        count = max(1, len(self.fields))
        pad = lambda values, fill: np.asarray(list(values) + [fill] * (count - len(values)))  # noqa: E731
        self.center = array(pad([f.center for f in self.fields], np.zeros(3)).astype(np.float32).reshape(-1, 3),
                            wp.vec3)
        self.radius = array(pad([f.radius for f in self.fields], 0.0).astype(np.float32), float)
        self.side = array(pad([f.side for f in self.fields], 1).astype(np.int32), int)
        self.map_size = array(pad([f.map_size for f in self.fields], 8).astype(np.int32), int)
        self.bits = array(pad([int(f.encoding == "bit1") for f in self.fields], 0).astype(np.int32), int)
        self.offset = array(pad(offsets, 0).astype(np.int32), int)
        self.mean_offset = array(pad(mean_offsets, 0).astype(np.int32), int)
        self.meshes = []  # prototype BVHs for self-occlusion of instance vertices (kept alive here)
        for field in self.fields:
            points = np.asarray(getattr(field, "prototype_points", np.zeros((0, 3))), np.float32).reshape(-1, 3)
            triangles = np.asarray(getattr(field, "prototype_triangles", np.zeros((0, 3))), np.int32).reshape(-1, 3)
            self.meshes.append(Tracer(points, triangles, device=device))
        self.mesh_ids = array(pad([t.mesh.id for t in self.meshes], 0).astype(np.uint64), wp.uint64)

    def kernel_inputs(self) -> list:
        return [self.center, self.radius, self.side, self.map_size, self.bits, self.offset, self.mean_offset,
                self.texels, self.means]


class InstanceSpheres:
    """Per-instance inverse transforms and a BVH over the instances' bounding-sphere boxes (refit per frame)."""

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
        self.update(transforms)

    def update(self, transforms: np.ndarray) -> None:
        """Point the instances at new (I, 4, 4) prototype-to-world matrices: arrays rewritten, BVH refitted."""
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
        else:
            self.bvh.refit()


def compute_instance_ao(tracer: Tracer, spheres: InstanceSpheres, positions: np.ndarray, normals: np.ndarray, *,
                        samples: int, epsilon: float, max_distance: float = math.inf, seed: int = 0,
                        interpolation: str = "nearest", own: np.ndarray | None = None) -> np.ndarray:
    """AO at points with unit normals: non-field geometry through ``tracer``, instances through their fields.

    Parameters
    ----------
    tracer : Tracer over the triangles without a field
    spheres : InstanceSpheres at the wanted frame
    positions, normals : (N, 3) float32
    own : (N,) int32, optional
        Instance each point belongs to (-1: a receiver); such points trace their own prototype for
        self-occlusion and skip their own field.

    Returns
    -------
    (N,) float32 in [0, 1]; 1 where the normal is zero.
    """
    positions = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    normals = np.ascontiguousarray(normals, np.float32).reshape(-1, 3)
    if positions.shape != normals.shape:
        raise ValueError(f"positions {positions.shape} and normals {normals.shape} differ")
    own = np.full(len(positions), -1, np.int32) if own is None else np.ascontiguousarray(own, np.int32)
    if own.shape != (len(positions),):
        raise ValueError(f"own {own.shape} does not match {len(positions)} positions")
    strata = strata_for(samples)
    ao = wp.zeros(len(positions), dtype=float, device=tracer.device)
    tracer.launch(instance_ao_kernel, len(positions), [
        tracer.mesh.id, spheres.bvh.id, tracer.array(positions, wp.vec3), tracer.array(normals, wp.vec3),
        tracer.array(own, wp.int32), strata, float(min(max_distance, FAR)), float(epsilon), int(seed),
        INTERPOLATION_MODES[interpolation], spheres.inverse_linear, spheres.inverse_offset, spheres.field,
        spheres.fieldset.mesh_ids, *spheres.fieldset.kernel_inputs(), ao,
    ])
    tracer.rays_cast += len(positions) * strata * strata
    return ao.numpy()


def query_field(field, transform: np.ndarray, origins: np.ndarray, directions: np.ndarray, *,
                max_distance: float = math.inf, interpolation: str = "nearest", device: str = "cpu",
                tracer: Tracer | None = None) -> np.ndarray:
    """(N,) float32 visibility of world rays (unit directions) through one instance of ``field``.

    ``transform`` is the (4, 4) prototype-to-world matrix (row-vector convention).
    """
    fieldset = FieldSet([field], device)
    spheres = InstanceSpheres(fieldset, np.zeros(1, np.int32), np.asarray(transform, np.float64)[None])
    origins = np.ascontiguousarray(origins, np.float32).reshape(-1, 3)
    directions = np.ascontiguousarray(directions, np.float32).reshape(-1, 3)
    visibility = wp.zeros(len(origins), dtype=float, device=device)
    inputs = [wp.array(origins, dtype=wp.vec3, device=device), wp.array(directions, dtype=wp.vec3, device=device),
              float(min(max_distance, FAR)), INTERPOLATION_MODES[interpolation], spheres.inverse_linear,
              spheres.inverse_offset, *fieldset.kernel_inputs(), visibility]
    if tracer is not None:
        tracer.launch(field_query_kernel, len(origins), inputs)
    else:
        wp.launch(field_query_kernel, dim=len(origins), inputs=[0, *inputs], device=device)
    return visibility.numpy()


class InstancePoints:
    """The instances' own vertices as AO sample points, moved rigidly with their instance per frame."""

    def __init__(self, scene: Scene, normals: np.ndarray, instance_field: np.ndarray):
        inst = scene.instances
        prim_instance = np.full(len(scene.prim_paths), -1, np.int32)
        prim_instance[scene.tri_prim] = scene.tri_instance
        point_instance = prim_instance[scene.point_prim]
        self.scene = scene
        self.point_ids = np.flatnonzero(point_instance >= 0)
        self.instance = point_instance[self.point_ids]
        # instances without a field are triangles in the BVH: they occlude themselves there and do not move
        self.moving = instance_field[self.instance] >= 0
        self.own = np.where(self.moving, self.instance, -1).astype(np.int32)
        self.points = scene.points[self.point_ids].astype(np.float64)
        self.normals = normals[self.point_ids].astype(np.float64)
        area = np.zeros(scene.num_points)
        np.add.at(area, scene.tri_vertices.ravel(), np.repeat(scene.tri_areas.astype(np.float64) / 3, 3))
        self.weights = area[self.point_ids]
        self.base_inverse = np.linalg.inv(np.where(invertible(inst.instance_transforms)[:, None, None],
                                                   inst.instance_transforms, np.eye(4)))
        count = len(inst.instancer_paths)
        self.instancer_count = (inst.instancer_instance_count if len(inst.instancer_instance_count) == count else
                                np.bincount(inst.instance_instancer, minlength=count))
        if len(inst.instance_index) == len(inst):
            self.row = np.asarray(inst.instance_index)
        else:  # scenes built without the authored rows: instances in order within each instancer
            self.row = np.zeros(len(inst), np.int64)
            for n in range(count):
                mine = np.flatnonzero(inst.instance_instancer == n)
                self.row[mine] = np.arange(len(mine))

    def at(self, transforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) float32 positions and unit normals with each instance moved by transforms (I, 4, 4)."""
        relative = self.base_inverse @ np.where(invertible(transforms)[:, None, None], transforms, np.eye(4))
        per_point = relative[self.instance]
        points = np.einsum("ni,nij->nj", np.c_[self.points, np.ones(len(self.points))], per_point)[:, :3]
        normal_map = np.linalg.inv(per_point[:, :3, :3]).transpose(0, 2, 1)
        normals = np.einsum("ni,nij->nj", self.normals, normal_map)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.where(length > 0, normals / np.maximum(length, 1e-300), 0.0)
        points = np.where(self.moving[:, None], points, self.points)
        normals = np.where(self.moving[:, None], normals, self.normals)
        return points.astype(np.float32), normals.astype(np.float32)

    def means(self, ao: np.ndarray) -> np.ndarray:
        """(I,) float32 area-weighted mean AO per instance (1 for an instance without area)."""
        count = len(self.scene.instances)
        total = np.bincount(self.instance, weights=ao * self.weights, minlength=count)
        weight = np.bincount(self.instance, weights=self.weights, minlength=count)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(weight > 0, total / weight, 1.0).astype(np.float32)

    def records(self, means: np.ndarray, frame: float | None) -> list:
        """primvars:bake:ao on each PointInstancer: one value per authored instance (vertex = per instance)."""
        inst = self.scene.instances
        records = []
        for n, path in enumerate(inst.instancer_paths):
            values = np.ones(int(self.instancer_count[n]), np.float32)  # masked instances: 1
            mine = np.flatnonzero(inst.instance_instancer == n)
            values[self.row[mine]] = means[mine]
            records.append(Primvar(path, "bake:ao", values, "float", "vertex", time=frame))
        return records


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
        scene = ctx.scene
        if len(receiver_prims(scene)) == 0:
            return False, "no writable meshes (all instanced, bake:skip or empty)"
        return True, ""

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        inst = scene.instances
        frames = parse_frames(p.frames, inst.instance_times)
        fields_by_path = ctx.products.get(DisplacementFieldSet, DisplacementFieldSet({})).fields
        paths = [path for path in inst.prototype_paths if path in fields_by_path]
        fields = [fields_by_path[path] for path in paths]
        proto_field = np.array([paths.index(path) if path in paths else -1 for path in inst.prototype_paths],
                               np.int32)
        instance_field = proto_field[inst.instance_prototype] if len(inst) else np.zeros(0, np.int32)
        instance_field = np.where(invertible(inst.instance_transforms), instance_field, -1).astype(np.int32)
        # Triangles without a usable field go through the BVH (built once, also for every frame).
        tri_field = np.where(scene.tri_instance >= 0, instance_field[np.maximum(scene.tri_instance, 0)]
                             if len(inst) else -1, -1)
        traced = np.flatnonzero(tri_field < 0)
        tracer = Tracer(scene.points, scene.tri_vertices[traced], device=ctx.device, threads=ctx.threads)
        epsilon = max(RAY_EPSILON_RELATIVE * scene.diagonal, 1e-30)  # the scene tracer's offset, as ambient_occlusion
        fieldset = FieldSet(fields, tracer.device)
        receivers = receiver_prims(scene)
        normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
        point_ids = np.flatnonzero(np.isin(scene.point_prim, receivers))
        result = Result(products={})
        moving = int((instance_field < 0).sum())
        if frames is not None and moving:
            result.messages.append(f"{moving} instance(s) without a field keep their extraction-time position in "
                                   f"every frame")
        spheres = InstanceSpheres(fieldset, instance_field, inst.instance_transforms)
        on_instances = InstancePoints(scene, normals, instance_field) if p.instances and len(inst) else None
        by_frame, by_frame_instances = {}, {}
        for step, frame in enumerate(frames or [None]):
            transforms = inst.instance_transforms
            if frame is not None:
                transforms = inst.instance_transforms_at_times[int(np.abs(inst.instance_times - frame).argmin())]
                spheres.update(transforms)
            if on_instances is not None:
                positions, instance_normals = on_instances.at(transforms)
                ao_instances = compute_instance_ao(
                    tracer, spheres, positions, instance_normals, samples=p.samples, epsilon=epsilon,
                    max_distance=p.max_distance, seed=p.seed, interpolation=p.interpolation, own=on_instances.own)
                by_frame_instances[frame] = on_instances.means(ao_instances)
                result.outputs.extend(on_instances.records(by_frame_instances[frame], frame))
            ao_points = np.ones(scene.num_points, np.float32)
            ao_points[point_ids] = compute_instance_ao(
                tracer, spheres, scene.points[point_ids], normals[point_ids], samples=p.samples, epsilon=epsilon,
                max_distance=p.max_distance, seed=p.seed, interpolation=p.interpolation)
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
