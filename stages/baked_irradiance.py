"""The irradiance a bake stored in a composed stage, read into plain arrays for ``usdbake.irradiance_at``.

Reading only: no light is computed here. Where the bake layer sits (a sublayer, the session layer's
usdbake layer, a reference) does not matter; the composed stage is read at ``time`` (None: the default).

==========================  ==========================================================================
reader                      reads
==========================  ==========================================================================
``check_queries``           the query points and normals: (N, 3), finite, normals of length 1
``open_with_source``        the stage (or stage file) and the source to read ("auto": the first held)
``read_probe_cloud``        the first LightProbeCloud: probePositions, shCoefficients, tetrahedra,
                            tetNeighbors, bake:tetBlockedEdges, bake:capturePositions, bake:directLights
``read_vector_grid``        the first IrradianceVectorGrid: gridOrigin, cellSize, resolution,
                            directions, colorsRGB9E5, bake:includeDirect, and the irradiance_grid params
                            its bake layer's provenance records
``read_radiosity_surfaces`` every Mesh with primvars:bake:irradianceDirect and ...Indirect: world
                            points, triangles, the two primvars summed
``has_source``              whether the stage holds one of the three
==========================  ==========================================================================

A cloud or grid keeps its prim's own frame (a bake writes world space on a root prim; a reference under
a transform moves it): ``world_to_local`` takes the queries there (``to_local``). Surfaces come back in
world space.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from pxr import Usd, UsdGeom, UsdLux

from ..core.errors import StageError, UsageError
from .baked_data import PROBE_CLOUD_TYPES, VECTOR_GRID_TYPES, open_stage
from .mesh_prims import _validate_mesh
from .provenance import is_bake_layer, provenance_of
from .triangulate import triangulate

SOURCE_PRIMS = {"light_probes": "a LightProbeCloud prim with probePositions (light_probes)",
                "irradiance_grid": "an IrradianceVectorGrid prim with a resolution (irradiance_grid)",
                "radiosity": "meshes with primvars:bake:irradianceDirect (radiosity)"}
"""What ``irradiance_at`` reads per source, in the order ``source="auto"`` tries them, as errors name it."""
SOURCES = tuple(SOURCE_PRIMS)
DIRECT_PRIMVAR = "primvars:bake:irradianceDirect"
INDIRECT_PRIMVAR = "primvars:bake:irradianceIndirect"
PROBE_BASIS = "realOrthonormal"
"""The only shBasis the lookup evaluates (kernels/sh.py)."""
SMALL_LIGHT_TYPES = (UsdLux.DistantLight, UsdLux.SphereLight, UsdLux.RectLight, UsdLux.DiskLight)
"""The lights a light_probes bake with ``direct_lights=lookup`` leaves out of the SH (domes are in)."""
UNIT_NORMAL = 1e-3
"""Normals may be off unit length by this much (float32 storage and renormalizing leave ~1e-7)."""


def check_queries(points, normals) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) float64 points and unit normals; UsageError naming the first bad row otherwise."""
    arrays = []
    for name, value in (("points", points), ("normals", normals)):
        try:
            array = np.asarray(value, np.float64)
        except (TypeError, ValueError):
            raise UsageError(f"{name}: expected an (N, 3) array of numbers, got {type(value).__name__}") from None
        if array.ndim != 2 or array.shape[1] != 3:
            raise UsageError(f"{name}: expected shape (N, 3), got {array.shape}")
        bad = np.flatnonzero(~np.isfinite(array).all(axis=1))
        if len(bad):
            raise UsageError(f"{name}[{bad[0]}] = {tuple(array[bad[0]].tolist())} is not finite "
                             f"({len(bad)} such rows)")
        arrays.append(array)
    points, normals = arrays
    if len(normals) != len(points):
        raise UsageError(f"normals: {len(normals)} rows for {len(points)} points")
    length = np.linalg.norm(normals, axis=1)
    bad = np.flatnonzero(np.abs(length - 1.0) > UNIT_NORMAL)
    if len(bad):
        raise UsageError(f"normals[{bad[0]}] = {tuple(normals[bad[0]].tolist())} has length {length[bad[0]]:.6g}, "
                         f"not 1 ({len(bad)} such rows)")
    return points, normals / length[:, None]


def to_local(world_to_local: np.ndarray, points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points and unit normals in a prim's frame (row vectors, as Gf): normals by the inverse
    transpose of the linear part, renormalized."""
    local = np.c_[points, np.ones(len(points))] @ world_to_local
    linear_inverse_transpose = np.linalg.inv(world_to_local[:3, :3]).T
    turned = normals @ linear_inverse_transpose
    return local[:, :3], turned / np.linalg.norm(turned, axis=1, keepdims=True)


def _timecode(time: float | None) -> Usd.TimeCode:
    return Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)


def _first_prim(stage: Usd.Stage, type_names: tuple[str, ...], attribute: str) -> Usd.Prim | None:
    """The first prim (traversal order) of one of ``type_names`` that has ``attribute`` authored."""
    for prim in stage.Traverse():
        if prim.GetTypeName() in type_names and prim.GetAttribute(attribute).HasValue():
            return prim
    return None


def _world_to_local(prim: Usd.Prim, timecode: Usd.TimeCode) -> np.ndarray:
    world = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(timecode), np.float64)
    if abs(np.linalg.det(world[:3, :3])) < 1e-30:
        raise StageError(str(prim.GetPath()), "xformOpOrder", "its world transform is singular (a zero scale)")
    return np.linalg.inv(world)


def _array(prim: Usd.Prim, name: str, timecode: Usd.TimeCode, dtype, columns: int | None = None,
           rows: int | None = None) -> np.ndarray | None:
    """An attribute's value as a numpy array (None when not authored); StageError when the count is off."""
    attribute = prim.GetAttribute(name)
    value = attribute.Get(timecode) if attribute else None
    if value is None:
        return None
    array = np.asarray(value, dtype)
    if columns is not None:
        if array.size % columns:
            raise StageError(str(prim.GetPath()), name, f"{array.size} values are not a multiple of {columns}")
        array = array.reshape(-1, columns)
    if rows is not None and len(array) != rows:
        raise StageError(str(prim.GetPath()), name, f"{len(array)} entries, expected {rows}")
    return array


def _required(prim: Usd.Prim, name: str, value):
    if value is None:
        raise StageError(str(prim.GetPath()), name, "missing (the bake writes it)")
    return value


# ---------------------------------------------------------------------------
# Light-probe cloud


@dataclass(frozen=True)
class BakedProbeCloud:
    """A LightProbeCloud prim's arrays, in the prim's frame."""

    path: str
    probe_positions: np.ndarray
    """(P, 3) float64."""
    probe_sh: np.ndarray
    """(P, 9, 3) float32 irradiance SH (real orthonormal basis, W/m^2)."""
    tet_vertices: np.ndarray
    """(T, 4) int64 probe indices."""
    tet_neighbors: np.ndarray
    """(T, 4) int64, -1 on the hull."""
    tet_blocked: np.ndarray | None
    """(T,) uint8 blocked-edge masks; None when not authored."""
    capture_positions: np.ndarray | None
    """(P, 3) float64 where each probe was captured (conforming clouds); None: at probe_positions."""
    lights_left_out: tuple[str, ...]
    """Paths of the stage's visible distant/sphere/rect/disk lights whose direct light the SH lack
    (``bake:directLights = excluded``); empty when the SH hold it or there are none."""
    world_to_local: np.ndarray
    """(4, 4) float64 row-vector matrix: world -> the prim's frame."""


def read_probe_cloud(stage: Usd.Stage, time: float | None = None) -> BakedProbeCloud | None:
    """The first LightProbeCloud with probePositions; None when there is none. StageError for an order,
    basis or quantity the lookup cannot evaluate, or arrays whose sizes disagree."""
    prim = _first_prim(stage, PROBE_CLOUD_TYPES, "probePositions")
    if prim is None:
        return None
    path, timecode = str(prim.GetPath()), _timecode(time)
    for name, expected in (("shOrder", 2), ("shBasis", PROBE_BASIS), ("bake:shQuantity", "irradiance")):
        value = prim.GetAttribute(name).Get(timecode) if prim.HasAttribute(name) else None
        if value is not None and value != expected:
            raise StageError(path, name, f"{value!r}: irradiance_at reads {name} = {expected!r} only")
    positions = _array(prim, "probePositions", timecode, np.float64, 3)
    count = len(positions)
    sh = _required(prim, "shCoefficients", _array(prim, "shCoefficients", timecode, np.float32, 3, 9 * count))
    tets = _required(prim, "tetrahedra", _array(prim, "tetrahedra", timecode, np.int64, 4))
    neighbors = _required(prim, "tetNeighbors", _array(prim, "tetNeighbors", timecode, np.int64, 4, len(tets)))
    if len(tets) == 0:
        raise StageError(path, "tetrahedra", "empty: the cloud has no tetrahedra to interpolate in")
    if tets.min() < 0 or tets.max() >= count:
        raise StageError(path, "tetrahedra", f"index {int(tets.max() if tets.max() >= count else tets.min())} "
                                             f"is outside 0..{count - 1}")
    if neighbors.min() < -1 or neighbors.max() >= len(tets):
        raise StageError(path, "tetNeighbors", f"an entry is outside -1..{len(tets) - 1}")
    blocked = _array(prim, "bake:tetBlockedEdges", timecode, np.uint8)
    if blocked is not None and len(blocked) != len(tets):
        raise StageError(path, "bake:tetBlockedEdges", f"{len(blocked)} entries, expected {len(tets)}")
    capture = _array(prim, "bake:capturePositions", timecode, np.float64, 3, count)
    excluded = prim.HasAttribute("bake:directLights") and prim.GetAttribute("bake:directLights").Get() == "excluded"
    return BakedProbeCloud(path=path, probe_positions=positions, probe_sh=sh.reshape(count, 9, 3), tet_vertices=tets,
                           tet_neighbors=neighbors, tet_blocked=blocked, capture_positions=capture,
                           lights_left_out=_small_lights(stage, timecode) if excluded else (),
                           world_to_local=_world_to_local(prim, timecode))


def _small_lights(stage: Usd.Stage, timecode: Usd.TimeCode) -> tuple[str, ...]:
    """Visible lights a bake treats as small (not domes), as paths."""
    return tuple(str(prim.GetPath()) for prim in stage.Traverse()
                 if any(prim.IsA(kind) for kind in SMALL_LIGHT_TYPES)
                 and UsdGeom.Imageable(prim).ComputeVisibility(timecode) != UsdGeom.Tokens.invisible)


# ---------------------------------------------------------------------------
# Irradiance vector grid


@dataclass(frozen=True)
class BakedVectorGrid:
    """An IrradianceVectorGrid prim's arrays, in the prim's frame."""

    path: str
    grid_origin: np.ndarray
    """(3,) float64 position of vertex (0, 0, 0)."""
    cell_size: np.ndarray
    """(3,) float64."""
    resolution: tuple[int, int, int]
    directions: np.ndarray
    """(V, 6, 3) uint8 quantized directions (kernels/direction24.py)."""
    colors: np.ndarray
    """(V, 6) uint32 RGB9E5 colours (kernels/rgb9e5.py)."""
    include_direct: bool
    """``bake:includeDirect``: False when the grid holds indirect light only."""
    params: dict
    """The irradiance_grid params of the bake that wrote the prim (its layer's provenance); {} if unknown."""
    world_to_local: np.ndarray
    """(4, 4) float64 row-vector matrix: world -> the prim's frame."""


def read_vector_grid(stage: Usd.Stage, time: float | None = None) -> BakedVectorGrid | None:
    """The first IrradianceVectorGrid with a resolution; None when there is none. StageError for a grid of
    other than 6 vectors per vertex or arrays whose sizes disagree."""
    prim = _first_prim(stage, VECTOR_GRID_TYPES, "resolution")
    if prim is None:
        return None
    path, timecode = str(prim.GetPath()), _timecode(time)
    resolution = _array(prim, "resolution", timecode, np.int64)
    if resolution.shape != (3,) or (resolution < 1).any():
        raise StageError(path, "resolution", f"{tuple(resolution.tolist())}: expected 3 positive counts")
    per_vertex = prim.GetAttribute("vectorsPerVertex").Get(timecode) if prim.HasAttribute("vectorsPerVertex") else 6
    if per_vertex != 6:
        raise StageError(path, "vectorsPerVertex", f"{per_vertex}: irradiance_at reads 6 (+-x, +-y, +-z) only")
    count = int(np.prod(resolution))
    cell = np.asarray(_required(prim, "cellSize", _array(prim, "cellSize", timecode, np.float64)))
    if cell.shape != (3,) or not (cell > 0).all():
        raise StageError(path, "cellSize", f"{tuple(cell.tolist())}: expected 3 positive sizes")
    directions = _required(prim, "directions", _array(prim, "directions", timecode, np.uint8, 18, count))
    colors = _required(prim, "colorsRGB9E5", _array(prim, "colorsRGB9E5", timecode, np.uint32, 6, count))
    include = prim.GetAttribute("bake:includeDirect").Get(timecode) if prim.HasAttribute("bake:includeDirect") else True
    return BakedVectorGrid(
        path=path, grid_origin=np.asarray(_required(prim, "gridOrigin", _array(prim, "gridOrigin", timecode,
                                                                                np.float64)), np.float64),
        cell_size=cell, resolution=tuple(int(n) for n in resolution), directions=directions.reshape(count, 6, 3),
        colors=colors, include_direct=include is not False, params=_bake_params(prim, "irradiance_grid"),
        world_to_local=_world_to_local(prim, timecode))


def _bake_params(prim: Usd.Prim, processor: str) -> dict:
    """``processor``'s params in the provenance of the strongest bake layer that has an opinion on ``prim``."""
    for spec in prim.GetPrimStack():
        if is_bake_layer(spec.layer):
            step = provenance_of(spec.layer).get("processors", {}).get(processor, {})
            return dict(step.get("params", {}))
    return {}


# ---------------------------------------------------------------------------
# Radiosity surfaces


@dataclass(frozen=True)
class BakedSurfaces:
    """The meshes radiosity wrote irradiance on, flattened to world-space triangles."""

    mesh_paths: tuple[str, ...]
    points: np.ndarray
    """(P, 3) float64 world positions, the meshes' points one after another."""
    triangles: np.ndarray
    """(T, 3) int64 indices into points, each triangle wound so its normal faces the mesh's front."""
    tri_mesh: np.ndarray
    """(T,) int64 index into mesh_paths."""
    point_irradiance: np.ndarray
    """(P, 3) float64 irradianceDirect + irradianceIndirect (W/m^2)."""


def read_radiosity_surfaces(stage: Usd.Stage, time: float | None = None) -> BakedSurfaces | None:
    """Every Mesh with primvars:bake:irradianceDirect; None when there is none. StageError for a mesh
    without the indirect primvar, or a primvar that is not one value per point."""
    timecode = _timecode(time)
    xforms = UsdGeom.XformCache(timecode)
    paths, points, triangles, tri_mesh, values = [], [], [], [], []
    base = 0
    for prim in stage.Traverse():
        if not (prim.IsA(UsdGeom.Mesh) and prim.GetAttribute(DIRECT_PRIMVAR).HasValue()):
            continue
        path = str(prim.GetPath())
        mesh = UsdGeom.Mesh(prim)
        local = np.asarray(mesh.GetPointsAttr().Get(timecode) or [], np.float64).reshape(-1, 3)
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(timecode) or [], np.int64)
        indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(timecode) or [], np.int64)
        _validate_mesh(path, local, counts, indices)
        irradiance = sum(_vertex_primvar(prim, name, len(local), timecode) for name in (DIRECT_PRIMVAR,
                                                                                         INDIRECT_PRIMVAR))
        skip = counts < 3
        holes = np.asarray(mesh.GetHoleIndicesAttr().Get(timecode) or [], np.int64)
        skip[holes[(holes >= 0) & (holes < len(counts))]] = True
        tris, _ = triangulate(local, counts, indices, skip)
        if mesh.GetOrientationAttr().Get(timecode) == UsdGeom.Tokens.leftHanded:
            tris = tris[:, ::-1]
        world = np.array(xforms.GetLocalToWorldTransform(prim), np.float64)
        paths.append(path)
        points.append((np.c_[local, np.ones(len(local))] @ world)[:, :3])
        triangles.append(tris.astype(np.int64) + base)
        tri_mesh.append(np.full(len(tris), len(paths) - 1, np.int64))
        values.append(irradiance)
        base += len(local)
    if not paths:
        return None
    return BakedSurfaces(mesh_paths=tuple(paths), points=np.concatenate(points), triangles=np.concatenate(triangles),
                         tri_mesh=np.concatenate(tri_mesh), point_irradiance=np.concatenate(values))


def _vertex_primvar(prim: Usd.Prim, name: str, count: int, timecode: Usd.TimeCode) -> np.ndarray:
    """(count, 3) float64 values of a vertex primvar (indices applied)."""
    path = str(prim.GetPath())
    primvar = UsdGeom.Primvar(prim.GetAttribute(name))
    if not primvar or not primvar.HasValue():
        raise StageError(path, name, "missing beside primvars:bake:irradianceDirect (radiosity writes both)")
    interpolation = primvar.GetInterpolation()
    if interpolation not in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        raise StageError(path, name, f"interpolation {interpolation!r}: expected 'vertex' (one value per point)")
    values = np.asarray(primvar.ComputeFlattened(timecode), np.float64)
    if values.shape != (count, 3):
        raise StageError(path, name, f"{len(values)} values of shape {values.shape[1:]} for {count} points: "
                                     "expected one colour per point")
    return values


def open_with_source(stage, source: str) -> tuple[Usd.Stage, str]:
    """The open stage (``stage`` itself or the stage file it names) and the source to read: ``source``, or for
    "auto" the first of SOURCES the stage holds. UsageError for anything else, or a stage without it."""
    if source != "auto" and source not in SOURCES:
        raise UsageError(f"source={source!r}: expected 'auto' or one of {', '.join(map(repr, SOURCES))}")
    if not isinstance(stage, (Usd.Stage, str, os.PathLike)):
        raise UsageError(f"stage={type(stage).__name__}: expected an open Usd.Stage or the path of a stage file")
    stage = open_stage(stage)
    wanted = SOURCES if source == "auto" else (source,)
    found = next((name for name in wanted if has_source(stage, name)), None)
    if found is None:
        what = "no baked irradiance" if source == "auto" else f"no {source} bake"
        raise UsageError(f"{stage.GetRootLayer().identifier}: {what}: looked for "
                         f"{'; '.join(SOURCE_PRIMS[name] for name in wanted)}")
    return stage, found


def has_source(stage: Usd.Stage, source: str) -> bool:
    """Whether the stage holds what ``source`` (one of SOURCES) reads."""
    if source == "light_probes":
        return _first_prim(stage, PROBE_CLOUD_TYPES, "probePositions") is not None
    if source == "irradiance_grid":
        return _first_prim(stage, VECTOR_GRID_TYPES, "resolution") is not None
    return any(prim.IsA(UsdGeom.Mesh) and prim.GetAttribute(DIRECT_PRIMVAR).HasValue() for prim in stage.Traverse())
