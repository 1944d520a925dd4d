"""A mesh's texture coordinates per triangle corner: the ``st`` set and a dedicated lightmap set, read for
the texture target (``geometry.lightmap_layout`` decides which one a bake uses, or generates one).

Every primvar interpolation USD allows for a UV set is read (faceVarying, vertex, varying, uniform; indexed
or not). A set that cannot be used (a constant, a count
that does not match the topology, a value type that is not two floats, NaN or infinite values) is left out with a warning naming
the prim, the primvar and the value, never an error: vertex bakes do not read UVs at all.
"""

from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd, UsdGeom

ST_NAMES = ("st", "UVMap", "uv", "st0", "map1")
"""The asset's main UV set, first found (USD's convention, Blender's, Houdini's and Maya's names)."""
LIGHTMAP_NAMES = ("lightmapST", "lightmap", "st1", "uv2", "UVMap_001", "map2")
"""A dedicated lightmap UV set, first found: what engines and DCCs call a second UV set."""
_UV_TYPES = {Sdf.ValueTypeNames.TexCoord2f, Sdf.ValueTypeNames.Float2, Sdf.ValueTypeNames.TexCoord2d,
             Sdf.ValueTypeNames.Double2, Sdf.ValueTypeNames.TexCoord2h, Sdf.ValueTypeNames.Half2}


def corner_uvs(prim: Usd.Prim, names: tuple[str, ...], triangles: np.ndarray, tri_corner: np.ndarray,
               tri_face: np.ndarray, face_count: int, timecode: Usd.TimeCode,
               warnings: list) -> tuple[str, np.ndarray | None]:
    """(name, (T, 3, 2) float32 UV of each triangle corner) of the first primvar of ``names`` the mesh holds,
    or ("", None). ``triangles`` holds the mesh's point indices, ``tri_corner`` its face-vertex slots."""
    primvars = UsdGeom.PrimvarsAPI(prim)
    for name in names:
        primvar = primvars.GetPrimvar(name)
        if not primvar or not primvar.HasValue():
            continue
        values = primvar.Get(timecode)
        where = f"{prim.GetPath()}: primvars:{name}"
        if primvar.GetTypeName().scalarType not in {t.scalarType for t in _UV_TYPES} or values is None:
            warnings.append(f"{where} is {primvar.GetTypeName()}, not two floats per element: not used as UVs")
            continue
        values = np.asarray(values, np.float64).reshape(-1, 2)
        if primvar.IsIndexed():  # flattened here: USD's ComputeFlattened prints a warning of its own for bad indices
            indices = np.asarray(primvar.GetIndices(timecode), np.int64)
            bad = np.flatnonzero((indices < 0) | (indices >= len(values)))
            if len(bad):
                warnings.append(f"{where}:indices: index {int(indices[bad[0]])} at position {int(bad[0])} is outside "
                                f"0..{len(values) - 1}: not used as UVs")
                continue
            values = values[indices]
        interpolation = primvar.GetInterpolation()
        index = {UsdGeom.Tokens.faceVarying: tri_corner, UsdGeom.Tokens.vertex: triangles,
                 UsdGeom.Tokens.varying: triangles,
                 UsdGeom.Tokens.uniform: np.repeat(tri_face[:, None], 3, axis=1)}.get(interpolation)
        needed = {UsdGeom.Tokens.uniform: face_count}.get(interpolation, int(index.max()) + 1 if index is not None
                                                          and index.size else 0)
        if index is None or len(values) < needed:
            warnings.append(f"{where} ({interpolation}) has {len(values)} values where the topology needs "
                            f"{needed}: not used as UVs")
            continue
        if not np.isfinite(values).all():
            bad = int(np.flatnonzero(~np.isfinite(values).all(axis=1))[0])
            warnings.append(f"{where} holds {tuple(values[bad])} at {bad}: not used as UVs")
            continue
        return name, values[index].astype(np.float32) if index.size else np.zeros((0, 3, 2), np.float32)
    return "", None
