"""Ambient occlusion's product: per-point AO for later processors.

Types of what one processor hands to the next (how they are wired: core/products.py, which holds
those that cross techniques); these stay within this technique.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class AmbientOcclusionProduct:
    """Per-point ambient occlusion (product of ``ambient_occlusion``)."""

    point_ao: np.ndarray
    """(P,) float32 unoccluded share of the cosine-weighted hemisphere at each Scene point (0 where not baked)."""
