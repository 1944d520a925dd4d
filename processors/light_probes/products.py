"""The light-probe cloud: probes, their irradiance SH and their tetrahedralization.

Types of what one processor hands to the next (how they are wired: core/products.py, which holds
those that cross techniques); these stay within this technique.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .tetrahedra import Tetrahedralization


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
    tetra: Tetrahedralization
    """The tetrahedralization of the probes."""
    direct_lights: bool = True
    """The SH hold the direct light of the lights that are not geometry (distant, sphere, rect, disk); False:
    the lookup adds it (``processors/light_probes/interpolation.irradiance_at`` with a tracer) or the
    engine's real-time lights do."""
    capture_positions: np.ndarray | None = None
    """(P, 3) float32 where each probe was captured when that differs from ``probe_positions`` (conforming
    tetrahedra: a probe on a wall is captured a little off it, on its own side); None: the same."""
