"""Helpers of the texture-target tests: the meshes a bake must leave untouched, and reading a lightmap back."""

from __future__ import annotations

import numpy as np
from pxr import UsdGeom


def composed_meshes(stage) -> dict:
    """{(prim, attribute): bytes} of every mesh's topology, points, st and normals as composed."""
    return {(str(prim.GetPath()), attr.GetName()): np.asarray(attr.Get()).tobytes()
            for prim in stage.Traverse() if prim.IsA(UsdGeom.Mesh)
            for attr in prim.GetAttributes()
            if attr.GetName() in ("points", "faceVertexCounts", "faceVertexIndices", "primvars:st", "normals")
            and attr.HasValue()}


def read_image(path: str) -> np.ndarray:
    """(H, W, C) float32 pixels of an image file, row 0 at the top, read with OpenImageIO."""
    import OpenImageIO as oiio

    buffer = oiio.ImageBuf(path)
    assert not buffer.has_error, buffer.geterror()
    return buffer.get_pixels(oiio.FLOAT)


def saved_and_baked(stage, path, processor: str, params: dict, target: str):
    """The in-memory ``stage`` saved to ``path``, opened again and baked through the hook with ``target``
    (lightmaps written next to it); returns the opened stage, which holds the bake layer."""
    import usdbake
    from pxr import Usd

    stage.GetRootLayer().Export(str(path))
    stage = Usd.Stage.Open(str(path))
    usdbake.bake(stage, processor, params, target=target, texture_dir=str(path.parent))
    return stage
