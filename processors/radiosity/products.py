"""Patches, the compressed multi-bounce operator, and the irradiance radiosity solves with them.

Types of what one processor hands to the next (how they are wired: core/products.py, which holds
those that cross techniques); these stay within this technique.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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
    """(P, 3) float32 per Scene point; 0 where not baked (every point with ``target=texture``)."""
    vertex_irradiance_indirect: np.ndarray
    """(P, 3) float32 per Scene point; 0 where not baked (every point with ``target=texture``)."""
