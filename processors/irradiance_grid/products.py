"""The baked irradiance vector grid and the progressive meshes' stream orders.

Types of what one processor hands to the next (how they are wired: core/products.py, which holds
those that cross techniques); these stay within this technique.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .vector_grid import GridLayout


@dataclass(frozen=True)
class IrradianceGridProduct:
    """A baked grid (scene frame)."""

    layout: GridLayout
    """Origin, cell size, resolution (vector_grid.GridLayout)."""
    directions: np.ndarray
    """(V, 6) uint8 hemi-octahedral codes."""
    colors: np.ndarray
    """(V, 6) uint32 RGB9E5."""
    vertex_valid: np.ndarray
    """(V,) bool: computed (True) or inside geometry and filled by push-pull (False)."""
    vectors: np.ndarray
    """(V, 6, 3, 3) float32 unquantized vectors (invalid vertices filled), for error measurements."""


@dataclass(frozen=True)
class ProgressiveMeshProduct:
    """Per prim path: (vertex rank in stream order, vertex each one collapses to)."""

    orders: dict[str, tuple[np.ndarray, np.ndarray]]
