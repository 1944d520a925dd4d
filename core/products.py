"""Product types: what one processor hands to the processors after it.

A processor declares ``provides = (SkyVisibilityProduct,)`` and returns
``Result(products={SkyVisibilityProduct: value})``; one that reads it declares
``requires = (SkyVisibilityProduct,)`` and gets ``ctx.products[SkyVisibilityProduct]``.
The runner wires producers to consumers by these types, so processors never
import each other: they share only these plain-data classes (numpy arrays, no
pxr, no Warp). Arrays are in the scene frame (relative to Scene.origin).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class AmbientOcclusionProduct:
    """Per-point ambient occlusion (product of ``ambient_occlusion``)."""

    point_ao: np.ndarray
    """(P,) float32 unoccluded share of the cosine-weighted hemisphere at each Scene point (0 where not baked)."""


@dataclass(frozen=True)
class SkyVisibilityProduct:
    """The refined receiver mesh and its per-face sky visibility factors (product ``sky_visibility``)."""

    face_points: np.ndarray
    """(P, 3) float64 refined mesh vertices relative to Scene.origin."""
    face_vertices: np.ndarray
    """(F, 3) int32 indices into face_points (scene winding)."""
    face_normals: np.ndarray
    """(F, 3) float32 unit normals (those of the source triangles)."""
    face_areas: np.ndarray
    """(F,) float32."""
    face_source: np.ndarray
    """(F,) int32 source triangle (index into the Scene's triangles)."""
    face_prim: np.ndarray
    """(F,) int32 prim index (Scene.prim_paths)."""
    face_face: np.ndarray
    """(F,) int32 authored face of the source prim."""
    face_level: np.ndarray
    """(F,) int32 area halvings below the source triangle."""
    face_corner_weights: np.ndarray
    """(F, 3, 3) float64 barycentric coordinates of each face corner in its source triangle."""
    point_source: np.ndarray
    """(P,) int64 Scene point each of face_points is (-1 for a point the refinement added)."""
    visibility: np.ndarray
    """(F, N) uint8 V_ij * 255 (rounded)."""
    visibility_scale: float
    """V = visibility * visibility_scale."""
    exposure: np.ndarray
    """(F,) float32 sum_j V_ij dw_j / pi."""
    patches: Any
    """usdbake.kernels.sky.SkyPatches: the patch layout V refers to."""
    to_world: np.ndarray
    """(3, 3) float64 ENU -> scene frame for the stage's up axis (north = the layout's north)."""
    up_axis: str
    prims: np.ndarray
    """(R,) int32 receiver prims (faces of prim prims[r] are face_prim == prims[r], in order)."""
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def num_faces(self) -> int:
        return len(self.face_vertices)

    def visibility_float(self) -> np.ndarray:
        """(F, N) float32 dequantized V, computed once and kept (4 bytes per factor)."""
        if "float" not in self._cache:
            self._cache["float"] = self.visibility.astype(np.float32) * np.float32(self.visibility_scale)
        return self._cache["float"]

    def visibility_patch_major(self) -> np.ndarray:
        """(N, F) float32 dequantized V, patch-major (the layout ``daylight.relight`` streams fastest)."""
        if "patch_major" not in self._cache:
            self._cache["patch_major"] = np.ascontiguousarray(self.visibility.T, np.float32) * np.float32(
                self.visibility_scale)
        return self._cache["patch_major"]

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_cache"] = {}
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)


@dataclass(frozen=True)
class RefinedScene:
    """The Scene after a processor refined receiver meshes (product of ``sky_visibility``): those
    prims have the refined triangles as their authored faces, exactly as extraction would read the
    bake's output. Processors with ``follows_refinement`` run on it in the same run."""

    scene: Any
    """usdbake.core.scene.Scene."""
    prims: np.ndarray
    """(R,) int32 prims whose topology changed."""


@dataclass(frozen=True)
class AnnualDaylightProduct:
    """Annual daylight metrics per face of the sky_visibility mesh (product of ``annual_daylight``)."""

    daylight_factor: np.ndarray
    """(F,) float32 percent, CIE overcast sky."""
    autonomy: np.ndarray
    """(F,) float32 share of occupied hours at or above the threshold."""
    useful: np.ndarray
    """(F, 3) float32 UDI shares of occupied hours: below, within, above the band."""
    sun_hours: np.ndarray
    """(F,) float32 occupied hours of direct sunlight at or above the ASE level."""
    mean_illuminance: np.ndarray
    """(F,) float32 lux, mean over occupied hours."""
    sensors: np.ndarray
    """(F,) bool faces the spatial metrics are taken over."""
    sda: float
    ase: float


@dataclass(frozen=True)
class DaylightProduct:
    """Product ``daylight``: radiance per refined face and time."""

    times: np.ndarray
    """(K,) datetime64[us] local times."""
    face_radiance: np.ndarray
    """(K, F, 3) float32 outgoing radiance, W/(m^2 sr)."""
    sun_zenith: np.ndarray
    """(K,) degrees."""
    sun_azimuth: np.ndarray
    """(K,) degrees from north towards east."""


@dataclass(frozen=True)
class DisplacementField:
    """One prototype's field (the product handed to instance_ao)."""

    prototype: str
    """Prototype prim path."""
    center: np.ndarray
    """(3,) float64 bounding-sphere centre in the field's frame (prototype space unless ``frame`` says)."""
    radius: float
    """Bounding-sphere radius in prototype space."""
    side: int
    """n: the positional samples are an n x n equal-area octahedral grid (n^2 samples)."""
    map_size: int
    """M: direction maps are M x M."""
    encoding: str
    """'uint8' or 'bit1'."""
    texels: np.ndarray
    """uint8: (n*n, M, M) distance codes (255 = miss); bit1: (n*n, M*M/8) packed hit bits (LSB first)."""
    mean_codes: np.ndarray
    """(n*n,) uint8 mean hit distance code per sample (bit1; for uint8 also filled, unused)."""
    triangles: int = 0
    build_seconds: float = 0.0
    prototype_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    """(P, 3) float32 prototype-space vertices the field was built from (instance_ao traces self-occlusion)."""
    prototype_triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int32))
    """(T, 3) int32 triangles of prototype_points."""
    frame: np.ndarray = field(default_factory=lambda: np.eye(4))
    """(4, 4) float64 row-vector rigid motion from the frame the field was built in (that of ``center``, the
    texels and prototype_points) to this prototype's space: the identity unless the field is shared with a
    moved copy of its prototype (``processors.instancing.displacement_fields.ShapeIndex``)."""

    @property
    def nbytes(self) -> int:
        """Bytes of field data (texels, plus the per-sample means in bit1 mode)."""
        return int(self.texels.nbytes + (self.mean_codes.nbytes if self.encoding == "bit1" else 0))


@dataclass(frozen=True)
class Patches:
    """Voxel-clustered patches and the fragments (sub-triangles) they are made of."""

    patch_centroids: np.ndarray
    """(n, 3) float32 area-weighted centroids (scene frame)."""
    patch_normals: np.ndarray
    """(n, 3) float32 unit mean normals."""
    patch_areas: np.ndarray
    """(n,) float32 areas (stage units^2)."""
    patch_albedo: np.ndarray
    """(n, 3) float32 area-weighted mean albedo."""
    patch_emission: np.ndarray
    """(n, 3) float32 area-weighted mean emitted radiance."""
    patch_fragment_start: np.ndarray
    """(n + 1,) int32: patch i owns patch_fragments[start[i]:start[i+1]]."""
    patch_fragments: np.ndarray
    """(Fr,) int32 fragment ids sorted by patch."""
    patch_fragment_cdf: np.ndarray
    """(Fr,) float32 cumulative area fraction within the patch, aligned with patch_fragments."""
    fragment_vertices: np.ndarray
    """(Fr, 3, 3) float32 corners of each fragment."""
    fragment_tri: np.ndarray
    """(Fr,) int32 scene triangle of each fragment."""
    fragment_patch: np.ndarray
    """(Fr,) int32 patch of each fragment (-1 for fragments of degenerate triangles)."""
    tri_subdivision: np.ndarray
    """(T,) int32 m: triangle t is split into m^2 fragments."""
    tri_fragment_start: np.ndarray
    """(T + 1,) int32 first fragment of each triangle."""
    tri_patch: np.ndarray
    """(T,) int32 patch of the fragment holding the triangle's centre (-1: degenerate)."""
    voxel_size: float

    @property
    def count(self) -> int:
        return len(self.patch_areas)


@dataclass(frozen=True)
class CompressedOperator:
    """A multi-bounce operator as BC1 log codes + an exact sparse part, in permuted (stored) order."""

    size: int
    """n, the number of patches."""
    blocks: np.ndarray
    """(n4/4 * n4/4, 8) uint8 BC1 blocks of the (n4, n4) code texture, n4 = n rounded up to 4."""
    permutation: np.ndarray
    """(n,) int32 patch stored at row/column i."""
    sparse_indptr: np.ndarray
    """(n + 1,) int32 CSR row pointers (stored order)."""
    sparse_indices: np.ndarray
    """(nnz,) int32 stored column of each exact entry."""
    sparse_values: np.ndarray
    """(nnz, 3) float32 exact RGB values."""
    lut: np.ndarray
    """(256,) float32 code -> value: 0 for code 0, exp(code * log_scale + log_offset) otherwise."""
    log_scale: float
    """quantizationScale: ln v (log) or v (linear) per code step."""
    log_offset: float
    """quantizationOffset."""
    quantization: str
    """'log' (thesis) or 'linear'."""
    row_scale: np.ndarray
    """(n, 3) float32 per stored row and channel factor on the decoded BC1 part (row-sum correction)."""
    stats: dict = field(default_factory=dict)

    @property
    def padded(self) -> int:
        return (self.size + 3) // 4 * 4

    @property
    def nbytes(self) -> int:
        """Bytes of everything a relight reads: blocks, sparse part, permutation and table."""
        return int(self.blocks.nbytes + self.sparse_indptr.nbytes + self.sparse_indices.nbytes
                   + self.sparse_values.nbytes + self.permutation.nbytes + self.lut.nbytes + self.row_scale.nbytes)


@dataclass(frozen=True)
class FormFactorProduct:
    """What ``form_factors`` hands to ``radiosity``: patches, the compressed operator, checks."""

    patches: Patches
    operator: CompressedOperator
    bounces: int
    infinite: bool
    checks: dict


@dataclass(frozen=True)
class ProbeCloud:
    """Tetrahedralized probes with irradiance SH (struct of arrays, scene frame)."""

    probe_positions: np.ndarray
    """(P, 3) float32."""
    probe_sh: np.ndarray
    """(P, 9, 3) float32 irradiance SH, real orthonormal basis (kernels/sh.py), W/m^2."""
    tet_vertices: np.ndarray
    """(T, 4) int32."""
    tet_neighbors: np.ndarray
    """(T, 4) int32, -1 on the hull."""
    tet_blocked: np.ndarray
    """(T,) uint8 6-bit blocked-edge masks (tetrahedra.TET_EDGES); zeros without leak fixing."""
    tetra: Any
    """usdbake.processors.light_probes.tetrahedra.Tetrahedralization of the probes."""
    direct_lights: bool = True
    """The SH hold the direct light of the lights that are not geometry (distant, sphere, rect, disk); False:
    the lookup adds it (``light_probes.irradiance_at`` with a tracer) or the engine's real-time lights do."""
    capture_positions: Any = None
    """(P, 3) float32 where each probe was captured when that differs from ``probe_positions`` (conforming
    tetrahedra: a probe on a wall is captured a little off it, on its own side); None: the same."""


@dataclass(frozen=True)
class IrradianceGridProduct:
    """A baked grid (scene frame)."""

    layout: Any
    """usdbake.processors.irradiance_grid.irradiance_grid.GridLayout: origin, cell size, resolution."""
    directions: np.ndarray
    """(V, 6) uint8 hemi-octahedral codes."""
    colors: np.ndarray
    """(V, 6) uint32 RGB9E5."""
    vertex_valid: np.ndarray
    """(V,) bool: computed (True) or inside geometry and filled by push-pull (False)."""
    vectors: np.ndarray
    """(V, 6, 3, 3) float32 unquantized vectors (invalid vertices filled), for error measurements."""


@dataclass(frozen=True)
class DisplacementFieldSet:
    """Every prototype's field, by prototype prim path (product of ``displacement_fields``)."""

    fields: dict[str, DisplacementField]


@dataclass(frozen=True)
class InstanceOcclusionProduct:
    """AO from displacement-field lookups (product of ``instance_ao``)."""

    point_ao_by_frame: dict
    """{time code or None: (P,) float32 per-point AO}."""
    instance_ao_by_frame: dict
    """{time code or None: per-instance AO}; empty unless the ``instances`` param is on."""


@dataclass(frozen=True)
class RadiosityProduct:
    """Direct and indirect irradiance per patch and per point (product of ``radiosity``), W/m^2."""

    patch_centroids: np.ndarray
    patch_normals: np.ndarray
    patch_areas: np.ndarray
    patch_irradiance_direct: np.ndarray
    """(n, 3) float32 E0."""
    patch_irradiance_indirect: np.ndarray
    """(n, 3) float32 k-bounce indirect irradiance."""
    patch_radiosity: np.ndarray
    """(n, 3) float32 outgoing radiosity B = rho (E0 + E_ind) + pi L_e."""
    vertex_irradiance_direct: np.ndarray
    """(P, 3) float32 per Scene point."""
    vertex_irradiance_indirect: np.ndarray
    """(P, 3) float32 per Scene point."""


@dataclass(frozen=True)
class ProgressiveMeshProduct:
    """Per prim path: (vertex rank in stream order, vertex each one collapses to)."""

    orders: dict[str, tuple[np.ndarray, np.ndarray]]
