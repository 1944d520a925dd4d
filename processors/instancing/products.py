"""Displacement fields per prototype and the instance AO looked up in them.

Types of what one processor hands to the next (how they are wired: core/products.py, which holds
those that cross techniques); these stay within this technique.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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
