"""Carry a mesh's authored attributes onto its refined faces (RefinedMesh records -> USD).

A refining processor describes the new topology in prim space (``core.records.RefinedMesh``): the
authored points keep their indices, every new point and every triangle corner is a barycentric
combination of the corners of one authored triangle. Here, with the composed stage at hand, every
authored attribute is re-authored for that topology:

=========================== ============================================================
authored                    on the refined mesh
=========================== ============================================================
points, velocities,         authored values kept, new points interpolated barycentrically
accelerations, vertex and
varying primvars
faceVarying primvars        interpolated per corner
uniform primvars            copied from the authored face to every triangle inside it
constant primvars           untouched
normals (any interpolation) as above by their interpolation, then renormalised
indexed primvars            values interpolated, then indexed again (new ``:indices``)
GeomSubsets (face)          indices remapped to the triangles inside their faces
creases                     crease edges split at the new points on them (sharpness kept)
holes                       cleared: hole faces are not part of the refined mesh
=========================== ============================================================

Every time sample is carried, and elementSize respected. What cannot be carried is refused
before any compute (``check_refinable``), naming the prim, the attribute and the value:
time-sampled points (the bake reads one time); vertex/varying/faceVarying primvars of a type that
has no barycentric mean (int, bool, string, token, quaternion, ...); and data OpenUSD itself
holds invalid, which has no meaning to carry: a value that is not an array, a length that does not
fit the interpolation and topology (one value per point, face-vertex or face, times elementSize),
indices that are not ``int[]``, not one per element or outside the values, an interpolation that is
not one of OpenUSD's, and normals that are not 3-vectors.
"""

from __future__ import annotations

import re

import numpy as np
from pxr import Sdf, Usd, UsdGeom

from ..core.errors import StageError
from ..core.products import RefinedScene
from ..core.records import Attribute, Block, Prim, Primvar, RefinedMesh
from ..core.scene import Scene
from .materials import authored_type

INTERPOLABLE = re.compile(r"^(float|double|half|(color|normal|point|vector|texCoord)\d[fdh]|(float|double|half)\d|"
                          r"matrix\dd)$")
"""Scalar USD types with a barycentric mean."""

POINT_ATTRIBUTES = ("points", "velocities", "accelerations")
"""Per-point attributes of UsdGeom.PointBased carried like vertex primvars."""

THREE_VECTOR = re.compile(r"^((normal|vector|point|color)3[fdh]|(float|double|half)3)$")
"""Scalar USD types that can hold a normal (UsdGeom declares normals as normal3f[])."""

ELEMENT = {"vertex": ("point", "points"), "varying": ("point", "points"),
           "faceVarying": ("face-vertex", "face-vertices"), "uniform": ("face", "faces")}
"""What one value of each carried interpolation belongs to (singular, plural), for messages."""

REMEDY = "mark the prim bake:skip = true, or bake it without sky_visibility/daylight"


def refinement_guard(stage: Usd.Stage, scene: Scene):
    """A ``Pipeline.run(before_compute=...)`` callback: ``check_refinable`` when a step that refines
    meshes is about to run."""
    def check(steps) -> None:
        if any(step.action != "skip" and RefinedScene in step.processor.provides for step in steps):
            check_refinable(stage, scene)
    return check


def check_refinable(stage: Usd.Stage, scene: Scene) -> None:
    """Refuse, before any compute, a receiver mesh whose authored data cannot be carried onto refined faces.

    Raises StageError naming the prim, the attribute, the value and why; the remedy is in the message.
    Everything ``carried_records`` will map is checked here, at every time sample it will carry.
    """
    has_faces = np.bincount(scene.tri_prim, minlength=len(scene.prim_paths)) > 0
    timecode = _timecode(scene.time_code)
    for prim_index in np.flatnonzero(scene.prim_writable & ~scene.prim_skip & has_faces):
        path = scene.prim_paths[prim_index]
        prim = stage.GetPrimAtPath(path)
        samples = prim.GetAttribute("points").GetNumTimeSamples()
        if samples > 1:
            raise StageError(path, "points", f"{samples} time samples: a refined mesh is computed at one time "
                                             f"and cannot follow animated points; {REMEDY}")
        geom = UsdGeom.Mesh(prim)
        span = scene.prim_points(prim_index)
        corners = geom.GetFaceVertexIndicesAttr().Get(timecode)
        counts = {"vertex": span.stop - span.start, "varying": span.stop - span.start,
                  "faceVarying": len(corners) if corners is not None else 0,
                  "uniform": int(scene.prim_face_count[prim_index])}
        for primvar in UsdGeom.PrimvarsAPI(prim).GetPrimvarsWithAuthoredValues():
            interpolation = primvar.GetInterpolation()
            type_name = str(primvar.GetTypeName().scalarType)
            if interpolation == "constant":
                continue  # not carried: one value for the whole mesh, whatever its topology
            if interpolation not in ELEMENT:
                raise StageError(path, primvar.GetAttr().GetName(),
                                 f"interpolation {interpolation!r} is not one of OpenUSD's (constant, uniform, "
                                 f"varying, vertex, faceVarying); fix it, {REMEDY}")
            if interpolation != "uniform" and not INTERPOLABLE.match(type_name):
                raise StageError(path, primvar.GetAttr().GetName(),
                                 f"{interpolation} {type_name} values cannot be interpolated onto refined faces "
                                 f"(no barycentric mean for {type_name}); {REMEDY}")
            indices = primvar.GetIndicesAttr()
            _check_carried(path, primvar.GetAttr(), interpolation, counts[interpolation],
                           element_size=max(1, primvar.GetElementSize()),
                           indices=indices if indices and indices.HasAuthoredValue() else None,
                           vectors=primvar.GetPrimvarName() == "normals")
        normals = geom.GetNormalsAttr()
        if normals.HasAuthoredValue() and geom.GetNormalsInterpolation() in ELEMENT:  # constant: not carried
            interpolation = geom.GetNormalsInterpolation()
            _check_carried(path, normals, interpolation, counts[interpolation], vectors=True)
        for name in POINT_ATTRIBUTES[1:]:
            attribute = prim.GetAttribute(name)
            if attribute and attribute.HasAuthoredValue():
                _check_carried(path, attribute, "vertex", counts["vertex"], vectors=True)


def _check_carried(path: str, attribute: Usd.Attribute, interpolation: str, expected: int, *, element_size: int = 1,
                   indices: Usd.Attribute | None = None, vectors: bool = False) -> None:
    """Refuse values OpenUSD holds invalid for ``interpolation`` on a mesh with ``expected`` elements of it:
    not an array, not 3-vectors where ``vectors``, a length that does not fit, indices that are not int[],
    not one per element or outside the values. Every time sample the carrier maps is read."""
    name, type_name = attribute.GetName(), authored_type(attribute)
    scalar = str(type_name.scalarType)
    one, many = ELEMENT[interpolation]
    fix = f"fix it, {REMEDY}"
    if vectors and not THREE_VECTOR.match(scalar):
        raise StageError(path, name, f"{type_name} values; {'normals' if 'normals' in name else name} must be "
                                     f"3-vectors ({'normal3f[]' if 'normals' in name else 'vector3f[]'}); {fix}")
    if not type_name.isArray:
        raise StageError(path, name, f"a single {scalar} value, not an array ({scalar}[]): {interpolation} "
                                     f"needs one per {one}; {fix}")
    if indices is not None and authored_type(indices) != Sdf.ValueTypeNames.IntArray:
        raise StageError(path, indices.GetName(), f"{authored_type(indices)} values; primvar indices must be "
                                                  f"int[]; {fix}")
    per = f"one per {one}" if element_size == 1 else f"elementSize {element_size}: {element_size} per {one}"
    for time in _samples(attribute, indices):
        at = "" if time is None else f"at time {time:g}, "
        values = attribute.Get(_timecode(time))
        if values is None or len(values) == 0:
            continue  # blocked (the carrier blocks it at that time too) or empty (left as authored)
        if indices is None:
            if len(values) != expected * element_size:
                raise StageError(path, name, f"{at}{len(values)} {interpolation} values for {expected} {many} "
                                             f"({per}); {fix}")
            continue
        if len(values) % element_size:
            raise StageError(path, name, f"{at}{len(values)} values, not a whole number of elements of "
                                         f"elementSize {element_size}; {fix}")
        index = np.asarray(indices.Get(_timecode(time)) or [], np.int64)
        if len(index) != expected:
            raise StageError(path, indices.GetName(), f"{at}{len(index)} indices for {expected} {many} "
                                                      f"({interpolation}: one per {one}); {fix}")
        count = len(values) // element_size
        outside = np.flatnonzero((index < 0) | (index >= count))
        if len(outside):
            first = int(outside[0])
            raise StageError(path, indices.GetName(), f"{at}index {int(index[first])} at position {first} is "
                                                      f"outside 0..{count - 1} ({name} holds {count} "
                                                      f"{'values' if element_size == 1 else 'elements'}); {fix}")


def complete_outputs(stage: Usd.Stage, outputs: list) -> list:
    """The records to author: RefinedMesh records expanded with ``stage``'s authored data, the
    ``:indices`` of an indexed primvar a processor replaces blocked (its values are not indexed), and
    ``instanceable = false`` on the native instances whose meshes receive data (``--deinstance``)."""
    outputs = deinstanced(stage, outputs) + list(outputs)
    taken = {(record.prim, _property(record)) for record in outputs if isinstance(record, (Primvar, Attribute))}
    completed = []
    for record in outputs:
        if isinstance(record, RefinedMesh):
            completed += carried_records(stage.GetPrimAtPath(record.prim), record, taken)
        else:
            completed.append(record)
    for record in outputs:
        if isinstance(record, Primvar) and record.time is None:
            primvar = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(record.prim)).GetPrimvar(record.name)
            key = (record.prim, f"primvars:{record.name}:indices")
            if primvar and primvar.IsIndexed() and key not in taken:
                completed.append(Attribute(record.prim, key[1], Block(), "int[]"))
                taken.add(key)
    return completed


def deinstanced(stage: Usd.Stage, outputs: list) -> list[Prim]:
    """Prim records de-instancing every native instance (nested ones too) a record writes under."""
    roots: set[str] = set()
    for path in {record.prim for record in outputs if isinstance(record, (Primvar, Attribute, RefinedMesh))}:
        prim = stage.GetPrimAtPath(path)
        if not prim or not prim.IsInstanceProxy():
            continue
        parent = prim.GetParent()
        while parent:
            if parent.IsInstance():
                roots.add(str(parent.GetPath()))
            parent = parent.GetParent()
    return [Prim(root, instanceable=False) for root in sorted(roots)]


def _property(record) -> str:
    return f"primvars:{record.name}" if isinstance(record, Primvar) else record.name


def carried_records(prim: Usd.Prim, mesh: RefinedMesh, taken: set) -> list:
    """Records re-authoring ``prim`` as ``mesh``: topology and every authored attribute (module docstring).

    Properties in ``taken`` ((prim path, property name) pairs another record authors) are left to it.
    """
    path = mesh.prim
    carry = _Carrier(prim, mesh)
    records = [
        Attribute(path, "faceVertexCounts", np.full(len(mesh.triangles), 3, np.int32), "int[]"),
        Attribute(path, "faceVertexIndices", mesh.triangles.ravel().astype(np.int32), "int[]"),
        Attribute(path, "orientation", "rightHanded", "token", uniform=True),
    ]
    geom = UsdGeom.Mesh(prim)
    for name in POINT_ATTRIBUTES:
        records += carry.attribute(prim.GetAttribute(name), "vertex")
    records += carry.attribute(geom.GetNormalsAttr(), geom.GetNormalsInterpolation(), unit=True)
    for primvar in UsdGeom.PrimvarsAPI(prim).GetPrimvarsWithAuthoredValues():
        records += carry.primvar(primvar)
    records += carry.subsets()
    records += carry.creases()
    holes = geom.GetHoleIndicesAttr()
    if holes.HasAuthoredValue() and len(holes.Get() or []):
        records.append(Attribute(path, "holeIndices", np.zeros(0, np.int32), "int[]"))
    return [r for r in records if (r.prim, _property(r)) not in taken]


def _samples(*attributes) -> list:
    """Time codes to carry: Default when any has a default value, then every authored time sample."""
    times = set()
    default = False
    for attribute in attributes:
        if attribute and attribute.HasAuthoredValue():
            times.update(attribute.GetTimeSamples())
            default |= attribute.Get(Usd.TimeCode.Default()) is not None
    return ([None] if default else []) + sorted(times)


def _timecode(time: float | None) -> Usd.TimeCode:
    return Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)


class _Carrier:
    """Maps authored values of one prim onto its RefinedMesh."""

    def __init__(self, prim: Usd.Prim, mesh: RefinedMesh):
        self.prim, self.mesh, self.path = prim, mesh, mesh.prim
        indices = UsdGeom.Mesh(prim).GetFaceVertexIndicesAttr().Get()
        self.face_vertex_indices = np.asarray(indices if indices is not None else [], np.int64)
        corners = mesh.triangles.ravel()
        self.new_points, first = np.unique(corners[corners >= mesh.point_count], return_index=True)
        self.new_point_corner = np.flatnonzero(corners >= mesh.point_count)[first]
        """For each new point (ascending), one corner (triangle * 3 + k) that uses it."""

    def point_count(self) -> int:
        return self.mesh.point_count + len(self.new_points)

    def at_corners(self, slot_values: np.ndarray) -> np.ndarray:
        """(F * 3, ...) values at the refined corners from values per authored face-vertex slot."""
        values = slot_values[self.mesh.source_corners]  # (F, 3 source corners, ...)
        mixed = np.einsum("fik,fk...->fi...", self.mesh.corner_weights, values.astype(np.float64))
        return mixed.reshape(-1, *slot_values.shape[1:])

    def map(self, values: np.ndarray, interpolation: str) -> np.ndarray:
        """Authored values (first axis per element of ``interpolation``) -> values for the refined mesh."""
        if interpolation == "uniform":
            return values[self.mesh.face]
        if interpolation == "faceVarying":
            return self.at_corners(values).astype(values.dtype)
        mixed = self.at_corners(values[self.face_vertex_indices])[self.new_point_corner]
        return np.concatenate([values[:self.mesh.point_count], mixed.astype(values.dtype)])

    def attribute(self, attribute: Usd.Attribute, interpolation: str, *, unit: bool = False) -> list:
        if not attribute or not attribute.HasAuthoredValue() or interpolation == "constant":
            return []  # a constant value (normals may be) holds for the refined faces as it is
        records = []
        for time in _samples(attribute):
            value = attribute.Get(_timecode(time))
            if value is None:  # a blocked time sample stays blocked
                records.append(Attribute(self.path, attribute.GetName(), Block(), str(attribute.GetTypeName()),
                                         time=time))
                continue
            values = np.asarray(value)
            if len(values) == 0:
                continue
            mapped = _unit(self.map(values, interpolation)) if unit else self.map(values, interpolation)
            records.append(Attribute(self.path, attribute.GetName(), mapped, str(attribute.GetTypeName()),
                                     time=time))
        return records

    def primvar(self, primvar: UsdGeom.Primvar) -> list:
        interpolation = primvar.GetInterpolation()
        if interpolation == "constant":
            return []
        name = primvar.GetPrimvarName()
        element_size = max(1, primvar.GetElementSize())
        type_name = str(primvar.GetTypeName().scalarType)
        records = []
        for time in _samples(primvar.GetAttr(), primvar.GetIndicesAttr()):
            flattened = primvar.ComputeFlattened(_timecode(time))
            if flattened is None:  # a blocked time sample stays blocked (bad indices were refused before compute)
                records.append(Attribute(self.path, f"primvars:{name}", Block(), str(primvar.GetTypeName()),
                                         time=time))
                continue
            values = np.asarray(flattened)
            if len(values) == 0:
                continue
            grouped = values.reshape(len(values) // element_size, element_size, *values.shape[1:])
            mapped = self.map(grouped, interpolation)
            if name == "normals":
                mapped = _unit(mapped)
            mapped = mapped.reshape(-1, *values.shape[1:])
            if primvar.IsIndexed():
                mapped, indices = _indexed(mapped.reshape(len(mapped) // element_size, -1))
                mapped = mapped.reshape(-1, *values.shape[1:])
                records.append(Attribute(self.path, f"primvars:{name}:indices", indices, "int[]", time=time))
            records.append(Primvar(self.path, name, mapped, type_name, interpolation, element_size, time=time))
        return records

    def subsets(self) -> list:
        records = []
        for subset in UsdGeom.Subset.GetAllGeomSubsets(UsdGeom.Imageable(self.prim)):
            if subset.GetElementTypeAttr().Get() != UsdGeom.Tokens.face:
                continue  # point subsets stay valid: authored points keep their indices
            attribute = subset.GetIndicesAttr()
            for time in _samples(attribute):
                faces = np.asarray(attribute.Get(_timecode(time)) or [], np.int64)
                chosen = np.flatnonzero(np.isin(self.mesh.face, faces)).astype(np.int32)
                records.append(Attribute(str(subset.GetPath()), "indices", chosen, "int[]", time=time))
        return records

    def creases(self) -> list:
        """Crease chains with the new points on their edges inserted (per-edge sharpness repeated)."""
        geom = UsdGeom.Mesh(self.prim)
        indices = np.asarray(geom.GetCreaseIndicesAttr().Get() or [], np.int64)
        lengths = np.asarray(geom.GetCreaseLengthsAttr().Get() or [], np.int64)
        sharpness = np.asarray(geom.GetCreaseSharpnessesAttr().Get() or [], np.float32)
        if len(indices) == 0 or len(lengths) == 0 or len(self.new_points) == 0:
            return []
        on_edge = self._points_on_authored_edges()
        per_edge = len(sharpness) != len(lengths)
        chains, new_lengths, new_sharpness, edge = [], [], [], 0
        start = 0
        for crease, length in enumerate(lengths):
            chain = [int(indices[start])]
            for a, b in zip(indices[start:start + length - 1], indices[start + 1:start + length]):
                inserted = [point for _, point in sorted(on_edge.get((int(a), int(b)), []))]
                chain += inserted + [int(b)]
                if per_edge and edge < len(sharpness):
                    new_sharpness += [sharpness[edge]] * (len(inserted) + 1)
                edge += 1
            start += length
            chains += chain
            new_lengths.append(len(chain))
            if not per_edge and crease < len(sharpness):
                new_sharpness.append(sharpness[crease])
        return [Attribute(self.path, "creaseIndices", np.array(chains, np.int32), "int[]"),
                Attribute(self.path, "creaseLengths", np.array(new_lengths, np.int32), "int[]"),
                Attribute(self.path, "creaseSharpnesses", np.array(new_sharpness, np.float32), "float[]")]

    def _points_on_authored_edges(self) -> dict:
        """{(a, b): [(share of b, new point), ...]} for new points on the segment between authored points."""
        corner = self.new_point_corner
        triangle, k = corner // 3, corner % 3
        points = self.face_vertex_indices[self.mesh.source_corners[triangle]]  # (N, 3) authored points
        weights = self.mesh.corner_weights[triangle, k]  # (N, 3)
        found: dict = {}
        for new_index, (ids, share) in enumerate(zip(points, weights)):
            support = {}
            for point, weight in zip(ids.tolist(), share.tolist()):
                if weight > 0:
                    support[point] = support.get(point, 0.0) + weight
            if len(support) == 2:
                (a, wa), (b, wb) = support.items()
                point = self.mesh.point_count + new_index
                found.setdefault((a, b), []).append((wb, point))
                found.setdefault((b, a), []).append((wa, point))
        return found


def _unit(vectors: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(vectors.astype(np.float64), axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(length > 0, vectors / length, vectors).astype(vectors.dtype)


def _indexed(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unique values, int32 indices) of per-element rows."""
    unique, inverse = np.unique(rows, axis=0, return_inverse=True)
    return unique, inverse.reshape(-1).astype(np.int32)
