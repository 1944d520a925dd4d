"""One mesh prim read in its own space (triangulated, shaded, checked), and the list of placed meshes a
Scene is assembled from (``stages.extract``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pxr import Usd, UsdGeom

from ..core.errors import StageError
from .materials import MaterialReader
from .triangulate import triangulate_corners
from .uv_sets import LIGHTMAP_NAMES, ST_NAMES, corner_uvs

RENDERABLE_PURPOSES = (UsdGeom.Tokens.default_, UsdGeom.Tokens.render)


@dataclass
class LocalMesh:
    """One mesh prim's triangulated topology and shading in its own space (shared by all its instances)."""

    path: str
    points: np.ndarray        # (P, 3) float64 local
    triangles: np.ndarray     # (T, 3) int32, authored winding
    tri_corner: np.ndarray    # (T, 3) int32 face-vertex slot of each corner (faceVertexIndices position)
    tri_face: np.ndarray      # (T,) int32
    face_count: int
    corner_count: int           # face-vertex slots: len(faceVertexIndices)
    tri_albedo: np.ndarray    # (T, 3) float32
    tri_emission: np.ndarray  # (T, 3) float32
    tri_transmittance: np.ndarray  # (T,) float32 visible transmittance at normal incidence, 0: opaque
    left_handed: bool
    double_sided: bool
    skip: bool
    surface: str
    subset_surfaces: tuple = ()  # ((GeomSubset path, its UsdPreviewSurface path), ...) of material-bound subsets
    st_name: str = ""           # the main UV set's primvar (stages.uv_sets.ST_NAMES), "" when none
    tri_st: np.ndarray | None = None  # (T, 3, 2) float32 its UV per triangle corner
    lightmap_uv_name: str = ""  # a dedicated lightmap UV set (stages.uv_sets.LIGHTMAP_NAMES), "" when none
    tri_lightmap_uv: np.ndarray | None = None  # (T, 3, 2) float32


@dataclass
class SceneBuilder:
    """Accumulates per-prim arrays, then concatenates them into a Scene."""

    meshes: list = field(default_factory=list)       # (LocalMesh, world matrix (4,4) float64, writable, instance)
    instance_roots: list = field(default_factory=list)  # per mesh: native instance roots above it, outermost first
    warnings: list = field(default_factory=list)

    def add(self, mesh: LocalMesh, world: np.ndarray, writable: bool, instance: int = -1,
            roots: tuple[str, ...] = ()) -> None:
        self.meshes.append((mesh, world, writable, instance))
        self.instance_roots.append(roots)


def renderable(prim: Usd.Prim, timecode: Usd.TimeCode) -> bool:
    """Whether the prim is drawn at ``timecode``: visible, of the default or render purpose (or not imageable)."""
    imageable = UsdGeom.Imageable(prim)
    if not imageable:
        return True
    if imageable.GetVisibilityAttr().Get(timecode) == UsdGeom.Tokens.invisible:
        return False
    purpose = imageable.GetPurposeAttr().Get()
    return purpose in RENDERABLE_PURPOSES or not purpose


def read_mesh(prim: Usd.Prim, timecode: Usd.TimeCode, materials: "MaterialReader", warnings: list) -> LocalMesh:
    """The mesh prim in its own space: triangulated (holes and faces of fewer than 3 vertices skipped, with a
    warning each), shaded per face, checked (StageError naming the attribute)."""
    mesh = UsdGeom.Mesh(prim)
    path = str(prim.GetPath())
    _check_time_sampled(path, mesh, timecode)
    points = np.asarray(mesh.GetPointsAttr().Get(timecode) or [], np.float64).reshape(-1, 3)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(timecode) or [], np.int64)
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(timecode) or [], np.int64)
    _validate_mesh(path, points, counts, indices)
    skip_faces = counts < 3
    if skip_faces.any():
        warnings.append(f"{path}: {int(skip_faces.sum())} faces with fewer than 3 vertices skipped")
    holes = np.asarray(mesh.GetHoleIndicesAttr().Get(timecode) or [], np.int64)
    holes = holes[(holes >= 0) & (holes < len(counts))]
    if len(holes):
        skip_faces[holes] = True
        warnings.append(f"{path}: {len(holes)} hole faces skipped")
    tri_corner, tri_face = triangulate_corners(points, counts, indices, skip_faces)
    triangles = indices[tri_corner].astype(np.int32).reshape(-1, 3)
    albedo, emission, surface = materials.face_shading(prim, len(counts))
    transmittance = materials.face_transmittance(prim, len(counts))
    skip_attr = prim.GetAttribute("bake:skip")
    uv_args = (triangles, tri_corner, tri_face, len(counts), timecode, warnings)
    st_name, tri_st = corner_uvs(prim, ST_NAMES, *uv_args)
    lightmap_uv_name, tri_lightmap_uv = corner_uvs(prim, LIGHTMAP_NAMES, *uv_args)
    return LocalMesh(
        path=path, points=points, triangles=triangles, tri_corner=tri_corner, tri_face=tri_face, face_count=len(counts), corner_count=len(indices),
        tri_albedo=albedo[tri_face], tri_emission=emission[tri_face], tri_transmittance=transmittance[tri_face],
        left_handed=mesh.GetOrientationAttr().Get(timecode) == UsdGeom.Tokens.leftHanded,
        double_sided=bool(mesh.GetDoubleSidedAttr().Get(timecode)),
        skip=bool(skip_attr and skip_attr.Get(timecode)), surface=surface,
        subset_surfaces=materials.subset_surfaces(prim), st_name=st_name, tri_st=tri_st,
        lightmap_uv_name=lightmap_uv_name, tri_lightmap_uv=tri_lightmap_uv,
    )


def _check_time_sampled(path: str, mesh: UsdGeom.Mesh, timecode: Usd.TimeCode) -> None:
    """Topology read at the default time from attributes that hold only time samples is empty: say so."""
    if not timecode.IsDefault():
        return
    for attribute in (mesh.GetPointsAttr(), mesh.GetFaceVertexCountsAttr(), mesh.GetFaceVertexIndicesAttr()):
        times = attribute.GetTimeSamples()
        if times and attribute.Get(timecode) is None:
            raise StageError(path, attribute.GetName(), f"has {len(times)} time samples ({times[0]:g}..{times[-1]:g}) "
                                                        f"and no default value; bake one frame with --time T "
                                                        f"(hook: time=T)")


def _validate_mesh(path: str, points: np.ndarray, counts: np.ndarray, indices: np.ndarray) -> None:
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if len(bad):
        raise StageError(path, "points", f"point {bad[0]} is {tuple(float(v) for v in points[bad[0]])} "
                                         f"({len(bad)} non-finite points); fix or remove them")
    if counts.sum() != len(indices):
        raise StageError(path, "faceVertexCounts", f"sum {int(counts.sum())} != len(faceVertexIndices) "
                                                   f"{len(indices)}")
    if (counts < 0).any():
        raise StageError(path, "faceVertexCounts", f"negative count {int(counts.min())}")
    out_of_range = np.flatnonzero((indices < 0) | (indices >= len(points)))
    if len(out_of_range):
        raise StageError(path, "faceVertexIndices", f"index {int(indices[out_of_range[0]])} at position "
                                                    f"{out_of_range[0]} is outside 0..{len(points) - 1}")
