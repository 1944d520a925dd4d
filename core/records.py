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


@dataclass(frozen=True)
class Prim:
    """A prim to define (``type_name`` set) or to apply API schemas to (over)."""

    path: str
    type_name: str = ""
    api_schemas: tuple[str, ...] = ()


@dataclass(frozen=True)
class Texture:
    """An image written next to the bake layer with OpenImageIO (or our own writer)."""

    path: str
    """File name relative to the bake layer."""
    pixels: np.ndarray
    """(H, W, C) array; float32 -> EXR, uint8 -> PNG."""


@dataclass(frozen=True)
class File:
    """Raw bytes written next to the bake layer (formats OpenImageIO cannot write: .dds, .npz)."""

    path: str
    """File name relative to the bake layer."""
    data: bytes


Output = Primvar | Attribute | Prim | Texture | File
