"""Small in-memory stages for the extraction tests.

A plain module (not a conftest): tests import it with ``from stage_builders
import ...``; tests/conftest.py puts this folder on sys.path.
"""

from __future__ import annotations

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

UNIT_QUAD = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
"""Unit square in the xy plane, counter-clockwise seen from +z."""

# Regular tetrahedron-ish solid with every face wound counter-clockwise seen
# from outside (rightHanded -> outward normals).
TETRA_POINTS = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
TETRA_COUNTS = [3, 3, 3, 3]
TETRA_INDICES = [0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3]


def new_stage(up_axis: str | None = None, meters_per_unit: float | None = None) -> Usd.Stage:
    """An in-memory stage with a /World Xform as default prim."""
    stage = Usd.Stage.CreateInMemory()
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    if up_axis is not None:
        UsdGeom.SetStageUpAxis(stage, up_axis)
    if meters_per_unit is not None:
        UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    return stage


def add_mesh(stage: Usd.Stage, path: str, points, counts, indices, **attributes) -> UsdGeom.Mesh:
    """Define a Mesh; ``attributes`` maps schema attribute names (orientation, holeIndices, ...) to values."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([Gf.Vec3f(*map(float, p)) for p in points])
    mesh.CreateFaceVertexCountsAttr([int(c) for c in counts])
    mesh.CreateFaceVertexIndicesAttr([int(i) for i in indices])
    for name, value in attributes.items():
        getattr(mesh, f"Create{name[0].upper()}{name[1:]}Attr")(value)
    return mesh


def add_quads(stage: Usd.Stage, path: str, count: int = 1, **attributes) -> UsdGeom.Mesh:
    """``count`` unit quads side by side along +x, each its own face."""
    points, indices = [], []
    for q in range(count):
        base = len(points)
        points += [(x + q * 2, y, z) for x, y, z in UNIT_QUAD]
        indices += [base, base + 1, base + 2, base + 3]
    return add_mesh(stage, path, points, [4] * count, indices, **attributes)


def add_xform(stage: Usd.Stage, path: str, translate=None, rotate_xyz=None, scale=None,
              orient=None) -> UsdGeom.Xform:
    """An Xform with translate, rotateXYZ (degrees), orient (Gf.Quatf) and scale ops, in that order."""
    xform = UsdGeom.Xform.Define(stage, path)
    if translate is not None:
        xform.AddTranslateOp().Set(Gf.Vec3d(*translate))
    if rotate_xyz is not None:
        xform.AddRotateXYZOp().Set(Gf.Vec3f(*rotate_xyz))
    if orient is not None:
        xform.AddOrientOp().Set(orient)
    if scale is not None:
        xform.AddScaleOp().Set(Gf.Vec3f(*scale))
    return xform


def instanced_stage(path) -> str:
    """A floor and two native instances of /Classes/Chair (a quad) above it, written to ``path``."""
    stage = new_stage()
    add_quads(stage, "/World/Floor", count=3)
    stage.CreateClassPrim("/Classes/Chair")
    add_quads(stage, "/Classes/Chair/Seat")
    for name, x in (("A", 0.0), ("B", 2.0)):
        prim = add_xform(stage, f"/World/{name}", translate=(x, 0.0, 0.5)).GetPrim()
        prim.GetReferences().AddInternalReference("/Classes/Chair")
        prim.SetInstanceable(True)
    stage.GetRootLayer().Export(str(path))
    return str(path)


def add_preview_material(stage: Usd.Stage, path: str, diffuse=None, emissive=None, texture: str | None = None,
                         color_space: str | None = None) -> UsdShade.Material:
    """A Material with a UsdPreviewSurface; ``texture`` connects diffuseColor to a UsdUVTexture file."""
    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    if diffuse is not None:
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*diffuse))
    if emissive is not None:
        shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*emissive))
    if texture is not None:
        reader = UsdShade.Shader.Define(stage, f"{path}/Texture")
        reader.CreateIdAttr("UsdUVTexture")
        reader.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(texture))
        if color_space is not None:
            reader.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(color_space)
        rgb = reader.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


def bind(prim: Usd.Prim, material: UsdShade.Material) -> None:
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)


def write_png(path, pixels: np.ndarray) -> str:
    """Write an (H, W, C) uint8 array as a PNG with OpenImageIO; returns the path as a string."""
    import OpenImageIO as oiio

    height, width, channels = pixels.shape
    spec = oiio.ImageSpec(width, height, channels, oiio.UINT8)
    out = oiio.ImageOutput.create(str(path))
    assert out is not None and out.open(str(path), spec), oiio.geterror()
    assert out.write_image(np.ascontiguousarray(pixels, np.uint8)), out.geterror()
    out.close()
    return str(path)


def world_points(stage: Usd.Stage, path: str, time=Usd.TimeCode.Default()) -> np.ndarray:
    """A mesh's points transformed to world space with UsdGeom.XformCache (the oracle), float64."""
    prim = stage.GetPrimAtPath(path)
    matrix = UsdGeom.XformCache(time).GetLocalToWorldTransform(prim)
    local = UsdGeom.Mesh(prim).GetPointsAttr().Get(time)
    return np.array([matrix.Transform(Gf.Vec3d(p)) for p in local], np.float64)


def base_context(scene, tracer=None):
    """The context a processor's applies() gets, for a scene outside a Pipeline."""
    from usdbake.core import Context

    return Context(scene, None, tracer=tracer)
