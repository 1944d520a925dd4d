"""Product types: what one processor hands to the processors after it.

A processor declares ``provides = (SkyVisibilityProduct,)`` and returns
``Result(products={SkyVisibilityProduct: value})``; one that reads it declares
``requires = (SkyVisibilityProduct,)`` and gets ``ctx.products[SkyVisibilityProduct]``.
The runner wires producers to consumers by these types, so processors never
import each other: they share only plain-data classes (numpy arrays, no pxr).
Arrays are in the scene frame (relative to Scene.origin).

A product type lives in the package of the technique whose processors make and
read it (``processors/<technique>/products.py``); this module holds only those
that cross techniques or that core itself reads.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import Scene


@dataclass(frozen=True)
class RefinedScene:
    """The Scene after a processor refined receiver meshes (product of ``sky_visibility``): those
    prims have the refined triangles as their authored faces, exactly as extraction would read the
    bake's output. Processors with ``follows_refinement`` run on it in the same run; the runner and
    the cache read it."""

    scene: Scene
    prims: np.ndarray
    """(R,) int32 prims whose topology changed."""
