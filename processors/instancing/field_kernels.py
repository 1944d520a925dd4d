"""The displacement-field format, one definition for its producer and its consumer.

Gaitatzes, Chrysanthou & Papaioannou, "Presampled visibility for ambient
occlusion", Journal of WSCG 16 (2008). ``processors.instancing.displacement_fields``
writes fields (Algorithm 1, Section 3.1) and ``processors.instancing.instance_ao`` reads
them (Algorithm 2, Section 3.2); both take the layout, the codes and the
lookup from here, so the two cannot drift apart.

**Layout.** A field of side n and map size M holds n^2 positional samples;
sample k (row k // n, column k % n) sits at ``positional_sample(k, n)``, the
cell centre s_k of the equal-area octahedral grid (``processors.instancing.sphere_maps``;
Section 3.3 asks for even samples with a constant-time inverse). Its M x M
direction map covers the hemisphere around the inward normal -s_k: texel
(a, b) is ``texel_direction``: ``cosine_hemisphere((a+.5)/M, (b+.5)/M)`` in
``tangent_frame(-s_k)``, the concentric map + Malley layout of Section 3.4.

**Codes** (Section 3.1 normalises a hit distance t by the sphere's diameter
2R; Section 4, "Storage and Error Considerations", stores one byte per ray):

- ``uint8``: one code per texel, round(254 * t / 2R) for a hit (0..254,
  error at most 2R/508), 255 (``MISS_CODE``) for no hit; texels of sample k at
  ``k * M*M + b * M + a``;
- ``bit1`` (Section 4, "Further Memory Optimization": one visibility bit per
  ray plus one distance per sample): one hit bit per texel, least significant
  first, M*M/8 bytes per sample, plus one distance code per sample used for
  every hit texel. The paper's distance is the sample's average distance to
  the object along its normal; here it is the mean over the sample's hit
  texels (255 when the sample sees no hit).

**Texture atlas.** n x n tiles, sample k at tile (row k // n, column k % n).
``uint8``: each tile M x M codes, texel (row b, column a). ``bit1``: each tile
M rows of M/8 bytes; below the tiles, n more rows hold the mean codes in their
first n columns.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .products import DisplacementField
from ...kernels.sampling import cosine_hemisphere, tangent_frame
from .sphere_maps import (
    equal_area_sphere_to_square,
    equal_area_square_to_sphere,
    malley_direction_to_square,
    octahedral_wrap,
)
from ...kernels.tracer import Tracer
from ...kernels.traversal import TraceScene

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

MISS_CODE = 255
"""Code of a ray that leaves the sphere without a hit."""
MAX_HIT_CODE = 254
"""Hit distances t / 2R in [0, 1] map to codes 0..254."""
POSITION_MAPPING = "octahedralEqualArea"
"""``bake:field:positionMapping``: positional samples on the equal-area octahedral grid."""
DIRECTION_MAPPING = "concentricMalley"
"""``bake:field:directionMapping``: direction maps in the concentric map + Malley layout."""
INTERPOLATE_POSITION = wp.constant(1)
"""Lookup flag: blend the 4 nearest positional samples (else the nearest one)."""
INTERPOLATE_DIRECTION = wp.constant(2)
"""Lookup flag: blend the 4 nearest texels (else the nearest one)."""
INTERPOLATION_MODES = {"nearest": 0, "position": 1, "direction": 2, "quadrilinear": 3}
"""Lookup modes by name -> flags."""


# ---------------------------------------------------------------------------
# Warp functions: layout and lookup


@wp.struct
class FieldArrays:
    """Every field of a run packed into flat arrays, indexed by field f (built by ``FieldSet``)."""

    field_center: wp.array(dtype=wp.vec3)
    """(F,) bounding-sphere centre c, prototype space (stage units)."""
    field_radius: wp.array(dtype=float)
    """(F,) bounding-sphere radius R, prototype space (stage units)."""
    field_side: wp.array(dtype=int)
    """(F,) n: n x n positional samples."""
    field_map_size: wp.array(dtype=int)
    """(F,) M: M x M direction map per sample."""
    field_bits: wp.array(dtype=int)
    """(F,) 1 for the bit1 encoding, 0 for uint8."""
    field_offset: wp.array(dtype=int)
    """(F,) first byte of the field in ``texels``."""
    field_mean_offset: wp.array(dtype=int)
    """(F,) first byte of the field in ``means``."""
    prototypes: TraceScene
    """Each field's prototype triangles in prototype space, instance f of this scene (self-occlusion of
    instance vertices: ``trace_any_in_instance``)."""
    texels: wp.array(dtype=wp.uint8)
    """Every field's texels (codes or packed hit bits), concatenated."""
    means: wp.array(dtype=wp.uint8)
    """Every field's per-sample mean hit codes, concatenated."""


@wp.func
def positional_sample(k: int, side: int) -> wp.vec3:
    """Unit vector s_k of positional sample k (p_k = c + R * s_k): the centre of cell (row k // n, column
    k % n) of the n x n equal-area octahedral grid, so every sample covers 4*pi/n^2 sr. It plays the role
    of Slater's subdivision in Gaitatzes et al. 2008, Section 3.3: even samples with a constant-time inverse."""
    return equal_area_square_to_sphere((float(k % side) + 0.5) / float(side), (float(k // side) + 0.5) / float(side))


@wp.func
def texel_direction(frame: wp.mat33, a: int, b: int, map_size: int) -> wp.vec3:
    """Unit direction of texel (a, b) of an M x M direction map, ``frame`` the sample's
    ``tangent_frame(-s_k)``: Malley's cosine-weighted map at the texel centre, the layout of Gaitatzes
    et al. 2008, Section 3.4 (each texel an equal share of the cosine-weighted hemisphere). Inverted in
    ``sample_hit``."""
    return frame * cosine_hemisphere((float(a) + 0.5) / float(map_size), (float(b) + 0.5) / float(map_size))


@wp.func
def nearest_cell(u: float, n: int) -> int:
    """Index of the cell of an n-cell axis over [0, 1] that holds u (u = 1 in the last cell): the
    "discretize" step of Algorithm 2 (Gaitatzes et al. 2008, Section 3.2), nearest sample or texel."""
    return wp.min(int(u * float(n)), n - 1)


@wp.func
def bilinear_corner(uv: wp.vec2, n: int, corner: int):
    """Corner ``corner`` (0..3, column step first) of the 2 x 2 cells of an n x n grid whose centres surround
    uv in [0, 1]^2: (column, row, bilinear weight; weights of the 4 corners sum to 1). Column and row may
    lie one step outside the grid; the caller clamps (direction maps) or wraps (the octahedral grid).
    The blends of the ``position``/``direction`` modes, after the interpolation Gaitatzes et al. 2008
    suggest in Section 5."""
    gx = uv[0] * float(n) - 0.5
    gy = uv[1] * float(n) - 0.5
    i = int(wp.floor(gx))
    j = int(wp.floor(gy))
    fx = gx - float(i)
    fy = gy - float(j)
    di = corner % 2
    dj = corner // 2
    return i + di, j + dj, wp.where(di == 1, fx, 1.0 - fx) * wp.where(dj == 1, fy, 1.0 - fy)


@wp.func
def texel_code(fields: FieldArrays, f: int, k: int, a: int, b: int) -> int:
    """Distance code of texel (a, b) of sample k of field f (layout in the module docstring): the stored
    code (uint8; Gaitatzes et al. 2008, Section 3.1, t / 2R in 254 steps), or for bit1 (Section 4, "Further
    Memory Optimization") the sample's mean code where the hit bit is set and MISS_CODE elsewhere."""
    map_size = fields.field_map_size[f]
    offset = fields.field_offset[f]
    texel = b * map_size + a
    if fields.field_bits[f] == 0:
        return int(fields.texels[offset + k * map_size * map_size + texel])
    byte = int(fields.texels[offset + k * (map_size * map_size // 8) + texel // 8])
    if ((byte >> (texel % 8)) & 1) == 1:
        return int(fields.means[fields.field_mean_offset[f] + k])
    return MISS_CODE


@wp.func
def code_hits(code: int, t_entry: float, scale: float, diameter: float, max_distance: float) -> float:
    """1 if the hit a code stores occludes, else 0 (Gaitatzes et al. 2008, Section 3.2: the stored distance
    is added to the distance of the ray's entry into the sphere).

    ``t_entry`` is the world distance (stage units) from the ray origin to its entry into the sphere;
    ``diameter`` (2R, prototype units) times ``scale`` (world units per prototype unit along the ray)
    turns the code back into a world distance. The hit occludes when it lies in
    [-one code step, max_distance] from the origin.
    """
    if code == MISS_CODE:
        return 0.0
    t_hit = t_entry + float(code) / float(MAX_HIT_CODE) * diameter * scale
    if t_hit >= -diameter * scale / float(MAX_HIT_CODE) and t_hit <= max_distance:
        return 1.0
    return 0.0


@wp.func
def sample_hit(fields: FieldArrays, f: int, k: int, direction: wp.vec3, t_entry: float, scale: float,
               diameter: float, max_distance: float, interpolate: int) -> wp.vec2:
    """(hit fraction in [0, 1], valid) of positional sample k of field f for a prototype-space unit direction.

    Gaitatzes et al. 2008, Section 3.2: the direction in the sample's frame picks the texel through the
    inverse of the Section 3.4 map: the nearest texel, or with INTERPOLATE_DIRECTION the bilinear blend of
    the 4 nearest texels' hit decisions (Section 5 suggests interpolating the distances; blending the
    decisions is this code's variant). The sample's stored ray is the one parallel to ours through p_k;
    its distance is used as if measured from our entry point (the paper's approximation; a parallax
    correction by (p_k - entry) . d measured no better on random rays and worse on instanced_props.usda,
    so it is left out). Invalid (y = 0) when the direction leaves the sphere at sample k (outside its
    inward hemisphere).
    """
    local = wp.transpose(tangent_frame(-positional_sample(k, fields.field_side[f]))) * direction
    if local[2] <= 0.0:
        return wp.vec2(0.0, 0.0)
    uv = malley_direction_to_square(local)
    map_size = fields.field_map_size[f]
    if (interpolate & INTERPOLATE_DIRECTION) == 0:
        code = texel_code(fields, f, k, nearest_cell(uv[0], map_size), nearest_cell(uv[1], map_size))
        return wp.vec2(code_hits(code, t_entry, scale, diameter, max_distance), 1.0)
    hit = float(0.0)
    for corner in range(4):
        a, b, w = bilinear_corner(uv, map_size, corner)
        code = texel_code(fields, f, k, wp.clamp(a, 0, map_size - 1), wp.clamp(b, 0, map_size - 1))
        hit += w * code_hits(code, t_entry, scale, diameter, max_distance)
    return wp.vec2(hit, 1.0)


@wp.func
def field_visibility(origin: wp.vec3, direction: wp.vec3, max_distance: float, inverse_linear: wp.mat33,
                     inverse_offset: wp.vec3, fields: FieldArrays, f: int, interpolate: int) -> float:
    """Visibility V in [0, 1] of a world ray (unit direction) through one instance of field f (Gaitatzes
    et al. 2008, Section 3.2, "Displacement Field Indexing").

    The ray meets the bounding sphere; the instance's inverse transform q' = M^-1 q (Section 3.2), here
    the affine map ``inverse_linear * q + inverse_offset``, takes it to prototype space with the same
    parameter t, so t stays a world distance (stage units) and prototype distances along the mapped
    direction d' convert to world ones by 1 / |d'|. The entry point picks the positional sample through
    the inverse octahedral map (nearest; with INTERPOLATE_POSITION, the 4 nearest blended by the weights
    of the samples that see the ray), the direction picks the texel (``sample_hit``). A ray that misses
    the sphere, or meets it only behind the origin or beyond ``max_distance``, gets V = 1.
    """
    o = inverse_linear * origin + inverse_offset - fields.field_center[f]
    d = inverse_linear * direction
    radius = fields.field_radius[f]
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
    side = fields.field_side[f]
    if (interpolate & INTERPOLATE_POSITION) == 0:
        k = nearest_cell(uv[1], side) * side + nearest_cell(uv[0], side)
        r = sample_hit(fields, f, k, dn, t0, scale, diameter, max_distance, interpolate)
        if r[1] > 0.0:
            return 1.0 - r[0]
        return 1.0
    hit = float(0.0)
    weight = float(0.0)
    for corner in range(4):
        i, j, w = bilinear_corner(uv, side, corner)
        cell = octahedral_wrap(i, j, side)
        r = sample_hit(fields, f, cell[1] * side + cell[0], dn, t0, scale, diameter, max_distance, interpolate)
        hit += w * r[0]
        weight += w * r[1]
    if weight > 0.0:
        return 1.0 - hit / weight
    return 1.0


# ---------------------------------------------------------------------------
# numpy: codes, atlas, packing


def encode_field(distances: np.ndarray, encoding: str) -> tuple[np.ndarray, np.ndarray]:
    """Codes of a field from its ray distances (layout and codes in the module docstring).

    Parameters
    ----------
    distances : (K, M, M) float32 t / 2R of each ray's first hit (dimensionless); >= 1.5 = miss
    encoding : 'uint8' or 'bit1'

    Returns
    -------
    texels : uint8 (K, M, M) codes, or bit1 (K, M*M/8) packed hit bits
    mean_codes : (K,) uint8 mean hit code per sample (MISS_CODE where the sample sees no hit)
    """
    hit = distances <= 1.0
    codes = np.where(hit, np.clip(np.rint(distances * MAX_HIT_CODE), 0, MAX_HIT_CODE), MISS_CODE).astype(np.uint8)
    count = hit.reshape(len(hit), -1).sum(axis=1)
    total = np.where(hit, distances, 0.0).reshape(len(hit), -1).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    mean_codes = np.where(count > 0, np.clip(np.rint(np.nan_to_num(mean) * MAX_HIT_CODE), 0, MAX_HIT_CODE),
                          MISS_CODE).astype(np.uint8)
    if encoding == "uint8":
        return codes, mean_codes
    if encoding == "bit1":
        return np.packbits(hit.reshape(len(hit), -1), axis=1, bitorder="little"), mean_codes
    raise ValueError(f"unknown encoding {encoding!r}")


def field_atlas(field: DisplacementField) -> np.ndarray:
    """(H, W) uint8 atlas image of a field (layout in the module docstring)."""
    n, m = field.side, field.map_size
    if field.encoding == "uint8":
        tiles = field.texels.reshape(n, n, m, m)
        return tiles.transpose(0, 2, 1, 3).reshape(n * m, n * m)
    width = m // 8
    tiles = field.texels.reshape(n, n, m, width)
    atlas = np.zeros((n * m + n, n * width), np.uint8)
    atlas[:n * m] = tiles.transpose(0, 2, 1, 3).reshape(n * m, n * width)
    atlas[n * m:, :n] = field.mean_codes.reshape(n, n)
    return atlas


def field_from_atlas(atlas: np.ndarray, *, side: int, map_size: int, encoding: str) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of field_atlas: (texels, mean_codes) as stored in DisplacementField (mean_codes empty for uint8)."""
    atlas = np.asarray(atlas, np.uint8)
    atlas = atlas[:, :, 0] if atlas.ndim == 3 else atlas
    n, m = side, map_size
    if encoding == "uint8":
        texels = atlas.reshape(n, m, n, m).transpose(0, 2, 1, 3).reshape(n * n, m, m)
        return np.ascontiguousarray(texels), np.zeros(0, np.uint8)
    width = m // 8
    texels = atlas[:n * m].reshape(n, m, n, width).transpose(0, 2, 1, 3).reshape(n * n, m * width)
    return np.ascontiguousarray(texels), np.ascontiguousarray(atlas[n * m:, :n]).reshape(n * n)


class FieldSet:
    """Displacement fields packed into one ``FieldArrays`` on a device (built once, shared by every frame).

    ``fields`` is the list of DisplacementField; field f of the kernels is ``fields[f]``. ``arrays`` is
    the struct the kernels take. An empty list still gives one (unused) slot per array.
    """

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
        count = max(1, len(self.fields))
        pad = lambda values, fill: np.asarray(list(values) + [fill] * (count - len(values)))  # noqa: E731
        meshes = [(np.asarray(getattr(field, "prototype_points", np.zeros((0, 3))), np.float32).reshape(-1, 3),
                   np.asarray(getattr(field, "prototype_triangles", np.zeros((0, 3))), np.int32).reshape(-1, 3))
                  for field in self.fields]
        self.prototypes = Tracer.of_meshes(meshes, device=device)  # kept alive with the arrays
        arrays = FieldArrays()
        arrays.field_center = array(pad([f.center for f in self.fields], np.zeros(3)).astype(np.float32)
                                    .reshape(-1, 3), wp.vec3)
        arrays.field_radius = array(pad([f.radius for f in self.fields], 0.0).astype(np.float32), float)
        arrays.field_side = array(pad([f.side for f in self.fields], 1).astype(np.int32), int)
        arrays.field_map_size = array(pad([f.map_size for f in self.fields], 8).astype(np.int32), int)
        arrays.field_bits = array(pad([int(f.encoding == "bit1") for f in self.fields], 0).astype(np.int32), int)
        arrays.field_offset = array(pad(offsets, 0).astype(np.int32), int)
        arrays.field_mean_offset = array(pad(mean_offsets, 0).astype(np.int32), int)
        arrays.prototypes = self.prototypes.scene
        arrays.texels = array(cat(texel_parts).astype(np.uint8), wp.uint8)
        arrays.means = array(cat(mean_parts).astype(np.uint8), wp.uint8)
        self.arrays = arrays
