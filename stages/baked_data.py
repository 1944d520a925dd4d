"""Baked data off a composed stage, read into plain arrays for ``usdbake preview``.

Besides the Scene (``extract.extract_scene``), the previewer draws what a bake
authored and what the stage says about the view. This module reads it and
hands back numpy arrays in frozen dataclasses; mapping values onto the
Scene's triangles, decoding and colour are ``usdbake.preview``'s.

========================  =====================================================
reader                    reads
========================  =====================================================
``open_stage``            a stage file (or passes an open stage through)
``has_attribute``         whether any of some prims has one of some attributes
``read_primvar``          the first of some primvars on a prim, flattened
``read_camera``           a UsdGeom.Camera (Gf.Camera: transform, film, lens)
``read_probe_clouds``     every LightProbeCloud: probePositions, shCoefficients
``read_vector_grids``     every IrradianceVectorGrid: lattice, colorsRGB9E5
========================  =====================================================

Positions come back in world space (float64); the caller subtracts
``Scene.origin``. ``time=None`` reads the default time.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Tf, Usd, UsdGeom

from ..core.errors import UsageError

PROBE_CLOUD_TYPES = ("LightProbeCloud",)
VECTOR_GRID_TYPES = ("IrradianceVectorGrid",)
CONDON_SHORTLEY_BASIS = "realOrthonormalCondonShortley"
"""The LightProbeCloud ``shBasis`` token of SH coefficients that carry the (-1)^m phase."""


def open_stage(stage: str | Usd.Stage) -> Usd.Stage:
    """``stage`` itself when it is open already, else the stage at that path (UsageError when it cannot be)."""
    if isinstance(stage, Usd.Stage):
        return stage
    if not Path(stage).exists():
        raise UsageError(f"{stage}: no such file")
    try:
        opened = Usd.Stage.Open(str(stage))
    except Tf.ErrorException as error:
        raise UsageError(f"{stage}: cannot be read as USD ({' '.join(str(error).split())[-200:]})") from None
    if opened is None:
        raise UsageError(f"{stage}: cannot be read as USD")
    return opened


def _timecode(time: float | None) -> Usd.TimeCode:
    return Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)


# ---------------------------------------------------------------------------
# Primvars


@dataclass(frozen=True)
class PrimvarValues:
    """One primvar of one prim as authored, flattened (indices applied)."""

    attribute: str
    """``prim path.property name``."""
    values: np.ndarray | None
    """(N * element_size, C) float64, or None when the primvar has no value at the time asked for."""
    components: int
    """C: 1 (scalar) or 3 (vector / colour); 0 when ``values`` is None."""
    interpolation: str
    """USD token: constant, uniform, varying, vertex or faceVarying."""
    element_size: int
    face_vertex_counts: np.ndarray
    """(F,) int64 faceVertexCounts of the mesh for a faceVarying primvar; empty otherwise."""
    face_vertex_indices: np.ndarray
    """(I,) int64 faceVertexIndices of the mesh for a faceVarying primvar; empty otherwise."""


def has_attribute(stage: Usd.Stage, prim_paths, names: list[str]) -> bool:
    """Whether any prim of ``prim_paths`` has one of the attributes ``names``."""
    for path in set(prim_paths):
        prim = stage.GetPrimAtPath(path)
        if prim and any(prim.HasAttribute(name) for name in names):
            return True
    return False


def read_primvar(stage: Usd.Stage, path: str, names: list[str], time: float | None = None, *,
                 widths: tuple[int, ...] = (1, 3)) -> PrimvarValues | None:
    """The first of the primvars ``names`` that the prim at ``path`` has; None when it has none.

    Raises UsageError when the primvar's values are not ``widths`` floats each (a float or a 3-vector / colour
    type by default; (2,) for texture coordinates).
    """
    prim = stage.GetPrimAtPath(path)
    if not prim:
        return None
    for name in names:
        if not prim.HasAttribute(name):
            continue
        primvar = UsdGeom.Primvar(prim.GetAttribute(name))
        attribute = f"{path}.{name}"
        interpolation = str(primvar.GetInterpolation())
        element_size = int(primvar.GetElementSize())
        no_faces = np.zeros(0, np.int64)
        raw = _flattened(primvar, time)
        if raw is None:
            return PrimvarValues(attribute, None, 0, interpolation, element_size, no_faces, no_faces)
        values, components = _as_components(raw, primvar.GetTypeName(), attribute, widths)
        counts = indices = no_faces
        if interpolation == UsdGeom.Tokens.faceVarying and prim.IsA(UsdGeom.Mesh):
            mesh = UsdGeom.Mesh(prim)
            counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(_timecode(time)) or [], np.int64)
            indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(_timecode(time)) or [], np.int64)
        return PrimvarValues(attribute, values, components, interpolation, element_size, counts, indices)
    return None


def _flattened(primvar: UsdGeom.Primvar, time: float | None):
    """Values at ``time``; at the default time, the first time sample when only samples exist."""
    value = primvar.ComputeFlattened(_timecode(time))
    if value is None and time is None:
        samples = primvar.GetAttr().GetTimeSamples()
        if samples:
            value = primvar.ComputeFlattened(Usd.TimeCode(samples[0]))
    return value


def _as_components(values, type_name: Sdf.ValueTypeName, attribute: str,
                   widths: tuple[int, ...] = (1, 3)) -> tuple[np.ndarray, int]:
    """(N, C) float64 values, C one of ``widths``."""
    scalar = type_name.scalarType
    dims = tuple(scalar.dimensions) if hasattr(scalar, "dimensions") else ()
    refused = UsageError(f"{attribute}: type {type_name} cannot be previewed (need a float or a 3-vector/colour, "
                         f"got shape {dims})")
    try:
        array = np.asarray(values, np.float64)
    except (TypeError, ValueError):  # text (string, token, asset) primvars
        raise refused from None
    if not type_name.isArray:  # one value (a constant primvar authored as a scalar): one row
        array = array.reshape(1, -1)
    if array.ndim == 1 and 1 in widths:
        return array[:, None], 1
    if array.ndim == 2 and array.shape[1] in widths:
        return array, int(array.shape[1])
    raise UsageError(f"{attribute}: type {type_name} cannot be previewed (need a float or a 3-vector/colour, "
                     f"got shape {array.shape[1:] or dims})")


@dataclass(frozen=True)
class StageLightmap:
    """One lightmap a mesh's ``LightmapAPI:<name>`` describes: its image and the UV primvar it is laid out on."""

    attribute: str
    """``prim path.bake:lightmap:<name>:file``."""
    file: str
    """The resolved image path."""
    uvs: PrimvarValues


def read_lightmap(stage: Usd.Stage, path: str, name: str, time: float | None = None) -> StageLightmap | None:
    """The lightmap ``name`` of the prim at ``path``, or None when it has none. UsageError naming the attribute
    when its file does not resolve or its UV primvar is missing."""
    prim = stage.GetPrimAtPath(path)
    prefix = f"bake:lightmap:{name}"
    if not prim or not prim.HasAttribute(f"{prefix}:file"):
        return None
    attribute = f"{path}.{prefix}:file"
    # a file per time (daylight's lightmaps) is read at ``time``, or at its first sample without one
    asset = prim.GetAttribute(f"{prefix}:file").Get(Usd.TimeCode(time) if time is not None
                                                     else Usd.TimeCode.EarliestTime())
    resolved = asset.resolvedPath if asset is not None else ""
    if not resolved:
        raise UsageError(f"{attribute}: {asset.path if asset is not None else 'no file'} does not resolve")
    uv_name = prim.GetAttribute(f"{prefix}:uv").Get() if prim.HasAttribute(f"{prefix}:uv") else "st"
    uvs = read_primvar(stage, path, [f"primvars:{uv_name}"], time, widths=(2,))
    if uvs is None or uvs.values is None:
        raise UsageError(f"{path}.{prefix}:uv: the mesh has no primvars:{uv_name} to lay the lightmap on")
    return StageLightmap(attribute, resolved, uvs)


def read_lightmap_image(file: str) -> np.ndarray:
    """(H, W, C) float32 linear values of a lightmap file, row 0 at v = 0 (the file's bottom row).
    UsageError naming the file when OpenImageIO cannot read it."""
    import OpenImageIO as oiio

    buffer = oiio.ImageBuf(file)
    pixels = buffer.get_pixels(oiio.FLOAT) if not buffer.has_error else None
    if pixels is None or buffer.has_error:
        raise UsageError(f"{file}: cannot be read ({buffer.geterror()})")
    return np.ascontiguousarray(np.asarray(pixels, np.float32)[::-1])


# ---------------------------------------------------------------------------
# Cameras


@dataclass(frozen=True)
class StageCamera:
    """A UsdGeom.Camera as Gf.Camera computes it (lengths in the camera's unit: mm, tenths of a stage unit)."""

    camera_to_world: np.ndarray
    """(4, 4) float64 row-vector matrix (as Gf): camera space -> world space."""
    focal_length: float
    horizontal_aperture: float
    vertical_aperture: float
    horizontal_aperture_offset: float
    vertical_aperture_offset: float
    projection: str
    """'perspective' or 'orthographic'."""


def read_camera(stage: Usd.Stage, path: str, time: float | None = None) -> StageCamera:
    """The UsdGeom.Camera at ``path``; UsageError (naming the stage's cameras) when there is none."""
    prim = stage.GetPrimAtPath(path) if Sdf.Path.IsValidPathString(path) else None
    if not prim:
        cameras = [str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Camera)]
        raise UsageError(f"--camera {path}: no such prim (cameras in the stage: {', '.join(cameras) or 'none'})")
    if not prim.IsA(UsdGeom.Camera):
        raise UsageError(f"--camera {path}: is a {prim.GetTypeName() or 'typeless prim'}, not a Camera")
    gf_camera = UsdGeom.Camera(prim).GetCamera(_timecode(time))
    if gf_camera.horizontalAperture <= 0 or gf_camera.verticalAperture <= 0 or gf_camera.focalLength <= 0:
        raise UsageError(f"{path}: focal length {gf_camera.focalLength} and apertures "
                         f"{gf_camera.horizontalAperture} x {gf_camera.verticalAperture} must be positive")
    return StageCamera(
        camera_to_world=np.array(gf_camera.transform, np.float64), focal_length=float(gf_camera.focalLength),
        horizontal_aperture=float(gf_camera.horizontalAperture),
        vertical_aperture=float(gf_camera.verticalAperture),
        horizontal_aperture_offset=float(gf_camera.horizontalApertureOffset),
        vertical_aperture_offset=float(gf_camera.verticalApertureOffset),
        projection="orthographic" if gf_camera.projection == Gf.Camera.Orthographic else "perspective")


# ---------------------------------------------------------------------------
# Probe clouds and vector grids


@dataclass(frozen=True)
class StageProbeCloud:
    """One LightProbeCloud prim with probe positions."""

    path: str
    probe_positions: np.ndarray
    """(P, 3) float64 world-space probe positions."""
    probe_sh: np.ndarray | None
    """(P, 9, 3) float32 L2 SH irradiance coefficients per probe and colour; None when absent or mis-sized."""
    condon_shortley: bool
    """``shBasis`` is realOrthonormalCondonShortley."""


@dataclass(frozen=True)
class StageVectorGrid:
    """One IrradianceVectorGrid prim with a positive resolution."""

    path: str
    vertex_positions: np.ndarray
    """(V, 3) float64 world-space lattice vertices, x fastest, then y, then z."""
    vertex_colors_rgb9e5: np.ndarray
    """(V * K,) uint32 colorsRGB9E5 as authored (K = vectors_per_vertex when the count matches)."""
    vectors_per_vertex: int


def _prims_of_type(stage: Usd.Stage, type_names: tuple[str, ...]) -> list[Usd.Prim]:
    return [p for p in stage.Traverse() if p.GetTypeName() in type_names]


def _to_world(prim: Usd.Prim, points: np.ndarray, time: float | None) -> np.ndarray:
    """(N, 3) float64 world positions of ``prim``-local points."""
    world = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(_timecode(time)), np.float64) \
        if prim.IsA(UsdGeom.Xformable) else np.eye(4)
    homogeneous = np.c_[np.asarray(points, np.float64).reshape(-1, 3), np.ones(len(points))]
    return (homogeneous @ world)[:, :3]


def read_probe_clouds(stage: Usd.Stage, time: float | None = None) -> list[StageProbeCloud]:
    """Every LightProbeCloud that has probePositions, in traversal order."""
    clouds = []
    for prim in _prims_of_type(stage, PROBE_CLOUD_TYPES):
        positions = prim.GetAttribute("probePositions").Get(_timecode(time)) if prim.HasAttribute(
            "probePositions") else None
        if not positions:
            continue
        positions = np.asarray(positions, np.float64).reshape(-1, 3)
        coefficients = prim.GetAttribute("shCoefficients").Get(_timecode(time)) if prim.HasAttribute(
            "shCoefficients") else None
        coefficients = np.asarray(coefficients if coefficients is not None else [], np.float32).reshape(-1, 3)
        basis = prim.GetAttribute("shBasis").Get() if prim.HasAttribute("shBasis") else None
        clouds.append(StageProbeCloud(
            path=str(prim.GetPath()), probe_positions=_to_world(prim, positions, time),
            probe_sh=coefficients.reshape(len(positions), 9, 3) if len(coefficients) == 9 * len(positions) else None,
            condon_shortley=basis == CONDON_SHORTLEY_BASIS))
    return clouds


def read_vector_grids(stage: Usd.Stage, time: float | None = None) -> list[StageVectorGrid]:
    """Every IrradianceVectorGrid with a positive resolution, in traversal order."""
    grids = []
    for prim in _prims_of_type(stage, VECTOR_GRID_TYPES):
        def get(name, default=None):
            attr = prim.GetAttribute(name)
            value = attr.Get(_timecode(time)) if attr else None
            return default if value is None else value
        resolution = np.asarray(get("resolution", (0, 0, 0)), np.int64)
        if (resolution <= 0).any():
            continue
        origin = np.asarray(get("gridOrigin", (0, 0, 0)), np.float64)
        cell = np.asarray(get("cellSize", (1, 1, 1)), np.float64)
        k, j, i = np.meshgrid(*(np.arange(n) for n in resolution[::-1]), indexing="ij")
        points = origin + np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1) * cell  # x fastest
        grids.append(StageVectorGrid(
            path=str(prim.GetPath()), vertex_positions=_to_world(prim, points, time),
            vertex_colors_rgb9e5=np.asarray(get("colorsRGB9E5", []), np.uint32),
            vectors_per_vertex=int(get("vectorsPerVertex", 6))))
    return grids
