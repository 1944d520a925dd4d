"""Instance transforms in numpy: which (4, 4) prototype-to-world matrices can be inverted."""

from __future__ import annotations

import numpy as np

SINGULAR_DETERMINANT = 1e-12
"""|det| of a transform's 3x3 part below this, relative to its largest entry cubed, counts as singular:
a flattened instance, whose inverse would blow prototype-space distances up without bound."""


def invertible(transforms: np.ndarray) -> np.ndarray:
    """(I,) bool: finite (I, 4, 4) transforms whose 3x3 part is not (numerically) singular."""
    transforms = np.asarray(transforms, np.float64).reshape(-1, 4, 4)
    finite = np.isfinite(transforms).all(axis=(1, 2))
    safe = np.where(finite[:, None, None], transforms, np.eye(4))
    scale = np.abs(safe[:, :3, :3]).max(axis=(1, 2))
    return finite & (np.abs(np.linalg.det(safe[:, :3, :3])) > SINGULAR_DETERMINANT * np.maximum(scale, 1e-300) ** 3)
