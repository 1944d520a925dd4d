"""Stages shaped like the assets users bring, written to files (the catalogue's hostile shapes).

Each builder writes a .usda into ``folder`` and returns its path. Y-up, centimetres
(metersPerUnit 0.01), flat-shaded geometry with unwelded creases, authored normals,
faceVarying indexed UVs, GeomSubsets bound to two materials.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

BOX_CM = 50.0
FLOOR_CM = 400.0

# A flat-shaded box: 6 quads, each with its own 4 points (unwelded creases), outward winding.
_BOX_FACES = (  # (normal axis, sign): quads wound counter-clockwise seen from outside
    ((0, 0, -1), [(0, 0, 0), (0, 1, 0), (1, 1, 0), (1, 0, 0)]),
    ((0, 0, 1), [(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]),
    ((0, -1, 0), [(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)]),
    ((0, 1, 0), [(0, 1, 0), (0, 1, 1), (1, 1, 1), (1, 1, 0)]),
    ((-1, 0, 0), [(0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0)]),
    ((1, 0, 0), [(1, 0, 0), (1, 1, 0), (1, 1, 1), (1, 0, 1)]),
)
UV_CORNERS = [(0, 0), (1, 0), (1, 1), (0, 1)]


def new_stage(path: Path) -> Usd.Stage:
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    return stage


def material(stage: Usd.Stage, path: str, color, texture: str | None = None) -> UsdShade.Material:
    """A UsdPreviewSurface material; ``texture`` connects a UsdUVTexture (reading primvars:st) to diffuseColor."""
    mat = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    diffuse = shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f)
    if texture is None:
        diffuse.Set(Gf.Vec3f(*color))
    else:
        image = UsdShade.Shader.Define(stage, f"{path}/Image")
        image.CreateIdAttr("UsdUVTexture")
        image.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(texture)
        diffuse.ConnectToSource(image.ConnectableAPI(), "rgb")
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return mat


def add_box(stage: Usd.Stage, path: str, *, size: float = BOX_CM, offset=(0.0, 0.0, 0.0),
            materials: tuple | None = None) -> UsdGeom.Mesh:
    """Flat-shaded box of unwelded quads with vertex normals, faceVarying indexed st, uniform
    displayColor and (with ``materials``) two face GeomSubsets bound to them."""
    points, normals, indices, uv_indices = [], [], [], []
    for normal, corners in _BOX_FACES:
        base = len(points)
        points += [tuple(size * c + o for c, o in zip(corner, offset)) for corner in corners]
        normals += [normal] * 4
        indices += [base, base + 1, base + 2, base + 3]
        uv_indices += [0, 1, 2, 3]
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in points]))
    mesh.CreateFaceVertexCountsAttr([4] * 6)
    mesh.CreateFaceVertexIndicesAttr(indices)
    mesh.CreateNormalsAttr(Vt.Vec3fArray([Gf.Vec3f(*n) for n in normals]))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    primvars = UsdGeom.PrimvarsAPI(mesh)
    st = primvars.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set(Vt.Vec2fArray([Gf.Vec2f(*uv) for uv in UV_CORNERS]))
    st.SetIndices(Vt.IntArray(uv_indices))
    color = primvars.CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.uniform)
    color.Set(Vt.Vec3fArray([Gf.Vec3f(0.2 * k, 0.5, 0.8) for k in range(6)]))
    if materials:
        binding = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
        for name, faces, mat in (("sides", [0, 1, 2, 3], materials[0]), ("caps", [4, 5], materials[1])):
            subset = binding.CreateMaterialBindSubset(name, Vt.IntArray(faces), UsdGeom.Tokens.face)
            UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(mat)
    return mesh


def add_floor(stage: Usd.Stage, path: str, *, size: float = FLOOR_CM) -> UsdGeom.Mesh:
    """A floor quad (y = 0, facing +y) with faceVarying primvars:normals and unindexed st."""
    half = size / 2
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([(-half, 0, -half), (-half, 0, half), (half, 0, half), (half, 0, -half)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    primvars = UsdGeom.PrimvarsAPI(mesh)
    primvars.CreatePrimvar("normals", Sdf.ValueTypeNames.Normal3fArray, UsdGeom.Tokens.faceVarying).Set(
        Vt.Vec3fArray([Gf.Vec3f(0, 1, 0)] * 4))
    primvars.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying).Set(
        Vt.Vec2fArray([Gf.Vec2f(*uv) for uv in UV_CORNERS]))
    return mesh


def room_with_box(folder: Path, name: str = "room_with_box.usda") -> Path:
    """A floor and a box on it, two materials on the box's subsets: the refinement case."""
    path = Path(folder) / name
    stage = new_stage(path)
    red = material(stage, "/World/Looks/Red", (0.8, 0.1, 0.1))
    blue = material(stage, "/World/Looks/Blue", (0.1, 0.1, 0.8))
    add_floor(stage, "/World/Floor")
    add_box(stage, "/World/Box", offset=(-BOX_CM / 2, 0.0, -BOX_CM / 2), materials=(red, blue))
    stage.Save()
    return path


def carried_values(stage: Usd.Stage, path: str) -> dict:
    """Lengths a valid mesh must have, and what its attributes hold (for assertions)."""
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath(path))
    return {
        "points": len(mesh.GetPointsAttr().Get()),
        "faces": len(mesh.GetFaceVertexCountsAttr().Get()),
        "corners": len(mesh.GetFaceVertexIndicesAttr().Get()),
    }


def primvar_counts(primvar: UsdGeom.Primvar) -> list[int]:
    """Elements a primvar provides (its indices' length when indexed), at its default and every time sample."""
    times = [Usd.TimeCode.Default()] + [Usd.TimeCode(t) for t in primvar.GetAttr().GetTimeSamples()]
    counts = []
    for time in times:
        values = primvar.ComputeFlattened(time)
        if values is not None:
            counts.append(len(values) // max(1, primvar.GetElementSize()))
    return counts


def expected_count(mesh: UsdGeom.Mesh, interpolation: str) -> int | None:
    return {
        "vertex": len(mesh.GetPointsAttr().Get()), "varying": len(mesh.GetPointsAttr().Get()),
        "uniform": len(mesh.GetFaceVertexCountsAttr().Get()),
        "faceVarying": len(mesh.GetFaceVertexIndicesAttr().Get()),
    }.get(interpolation)


def topology_mismatches(stage: Usd.Stage) -> list[str]:
    """One line per mesh attribute whose length does not fit its mesh's topology (empty when valid)."""
    problems = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        valid, why = UsdGeom.Mesh.ValidateTopology(mesh.GetFaceVertexIndicesAttr().Get(),
                                                     mesh.GetFaceVertexCountsAttr().Get(),
                                                     len(mesh.GetPointsAttr().Get()))
        if not valid:
            problems.append(f"{prim.GetPath()}: {why}")
        for primvar in UsdGeom.PrimvarsAPI(prim).GetPrimvarsWithValues():
            expected = expected_count(mesh, primvar.GetInterpolation())
            for count in primvar_counts(primvar):
                if expected is not None and count != expected:
                    problems.append(f"{primvar.GetAttr().GetPath()}: {count} values for "
                                    f"{expected} {primvar.GetInterpolation()} elements")
        normals = mesh.GetNormalsAttr().Get()
        if normals is not None:
            expected = expected_count(mesh, mesh.GetNormalsInterpolation())
            if expected is not None and len(normals) != expected:
                problems.append(f"{prim.GetPath()}.normals: {len(normals)} values for {expected}")
        faces = len(mesh.GetFaceVertexCountsAttr().Get())
        for subset in UsdGeom.Subset.GetAllGeomSubsets(mesh):
            indices = np.asarray(subset.GetIndicesAttr().Get() or [])
            if len(indices) and (indices.max() >= faces or indices.min() < 0):
                problems.append(f"{subset.GetPath()}.indices: outside 0..{faces - 1}")
    return problems


PAWN_SPACING_CM = 80.0


def add_pawn_prototype(stage: Usd.Stage, path: str) -> None:
    """A 'pawn': a flat-shaded box on a smaller box (two meshes), defined at ``path``."""
    UsdGeom.Xform.Define(stage, path)
    add_box(stage, f"{path}/Base", size=40.0, offset=(-20.0, 0.0, -20.0))
    add_box(stage, f"{path}/Head", size=20.0, offset=(-10.0, 40.0, -10.0))


def instanced_board(folder: Path, *, instanced: bool = True, name: str | None = None, floor: bool = True) -> Path:
    """A floor with pawns: a row as native instances (instanceable internal references to a
    prototype under /Assets), and a row as a PointInstancer whose prototype is defined under it.

    With ``instanced=False`` the same geometry is plain: the references are not instanceable and
    every PointInstancer instance is an ordinary Xform referencing the prototype (the flattened twin).
    """
    path = Path(folder) / (name or ("board_instanced.usda" if instanced else "board_flat.usda"))
    stage = new_stage(path)
    assets = stage.DefinePrim("/Assets")
    assets.SetSpecifier(Sdf.SpecifierClass)  # not rendered itself
    add_pawn_prototype(stage, "/Assets/Pawn")
    if floor:
        add_floor(stage, "/World/Floor", size=FLOOR_CM * 2)
    for k in range(4):
        pawn = UsdGeom.Xform.Define(stage, f"/World/Pawns/Pawn_{k}")
        pawn.AddTranslateOp().Set(Gf.Vec3d(-120.0 + k * PAWN_SPACING_CM, 0.0, -80.0))
        pawn.GetPrim().GetReferences().AddInternalReference("/Assets/Pawn")
        pawn.GetPrim().SetInstanceable(instanced)
    positions = [Gf.Vec3f(-120.0 + k * PAWN_SPACING_CM, 0.0, 80.0) for k in range(4)]
    if instanced:
        instancer = UsdGeom.PointInstancer.Define(stage, "/World/Row")
        prototype = UsdGeom.Xform.Define(stage, "/World/Row/Prototypes/Pawn").GetPrim()
        prototype.GetReferences().AddInternalReference("/Assets/Pawn")
        instancer.CreatePrototypesRel().SetTargets([prototype.GetPath()])
        instancer.CreateProtoIndicesAttr([0] * len(positions))
        instancer.CreatePositionsAttr(positions)
    else:
        for k, position in enumerate(positions):
            copy = UsdGeom.Xform.Define(stage, f"/World/Row/Pawn_{k}")
            copy.AddTranslateOp().Set(Gf.Vec3d(*position))
            copy.GetPrim().GetReferences().AddInternalReference("/Assets/Pawn")
    stage.Save()
    return path
