"""Output records: what a processor asks to be authored in USD, described without pxr.

``usdbake.stages.bake_layer`` turns them into USD.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Primvar:
    """A primvar ``primvars:<name>`` on ``prim``; ``name`` is in the ``bake:`` namespace."""

    prim: str
    name: str
    values: np.ndarray
    type_name: str
    """Sdf scalar type name without []: 'float', 'color3f', 'uchar', ..."""
    interpolation: str
    """'constant', 'uniform', 'vertex', 'faceVarying'."""
    element_size: int = 1
    time: float | None = None
    """USD time code for a time sample, None for the default value."""


@dataclass(frozen=True)
class Attribute:
    """A plain attribute (array or scalar) on ``prim``."""

    prim: str
    name: str
    value: Any
    type_name: str
    """Sdf type name, with [] for arrays ('float3[]', 'asset', 'token')."""
    uniform: bool = False
    time: float | None = None
    connect_to: str | None = None
    """Path of an attribute this one connects to (shading networks)."""
    custom: bool = False
    """Author it as a custom attribute (``userProperties:``, which DCCs import as custom properties)."""


@dataclass(frozen=True)
class Prim:
    """A prim to define (``type_name`` set) or to apply API schemas to (over)."""

    path: str
    type_name: str = ""
    api_schemas: tuple[str, ...] = ()
    instanceable: bool | None = None
    """Set the prim's instanceable metadata (False: de-instance it); None leaves it alone."""
    references: tuple[str, ...] = ()
    """Prim paths of this stage the prim references (internal references: a variant of an authored prim)."""


@dataclass(frozen=True)
class Relationship:
    """A relationship ``name`` on ``prim`` targeting ``targets`` (prim or property paths), e.g. a
    ``material:binding`` that binds a mesh to a variant of its material."""

    prim: str
    name: str
    targets: tuple[str, ...]


@dataclass(frozen=True)
class Texture:
    """An image written next to the bake layer with OpenImageIO (or our own writer)."""

    path: str
    """File name relative to the bake layer."""
    pixels: np.ndarray
    """(H, W, C) array, row 0 at the top; float32 or float16 -> EXR, uint8 or uint16 -> PNG (the path's
    extension must match)."""


@dataclass(frozen=True)
class File:
    """Raw bytes written next to the bake layer (formats OpenImageIO cannot write: .dds, .npz)."""

    path: str
    """File name relative to the bake layer."""
    data: bytes


@dataclass(frozen=True)
class RefinedMesh:
    """A mesh prim re-authored as the triangles of a conforming refinement of its authored faces.

    Point i < ``point_count`` is authored point i (kept at its index); later points are new. Every
    triangle lies inside one triangle of its authored face's triangulation (its *source*), and each
    of its corners is a barycentric combination of the source's corners: that is how
    ``usdbake.stages.refined_mesh`` carries every authored attribute (points, normals, velocities,
    primvars of every interpolation, GeomSubsets, creases, holes) onto the new topology, in the
    prim's own space. Authored with ``orientation = rightHanded``.
    """

    prim: str
    point_count: int
    """Authored points of the prim (the first points of the refined mesh)."""
    triangles: np.ndarray
    """(F, 3) int32 indices into the refined points, wound for rightHanded in the prim's space."""
    face: np.ndarray
    """(F,) int32 authored face each triangle lies in."""
    source_corners: np.ndarray
    """(F, 3) int32 face-vertex slots (positions in the authored faceVertexIndices) of the source's corners."""
    corner_weights: np.ndarray
    """(F, 3, 3) float64: corner i of triangle t is sum_k corner_weights[t, i, k] * source corner k."""


@dataclass(frozen=True)
class Block:
    """An explicit absence of value (Sdf.ValueBlock) for an Attribute: hides what weaker layers author
    (e.g. the ``:indices`` of a primvar a processor replaces with unindexed values)."""


Output = Primvar | Attribute | Prim | Relationship | Texture | File | RefinedMesh
