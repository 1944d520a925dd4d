"""Stage -> Scene: traverse a composed Usd.Stage once and flatten it into arrays.

Honours visibility, purpose (default/render only), active state, instance
proxies of instanceable prims, and UsdGeom.PointInstancer (prototypes are
flattened per instance so they occlude, and the instances are also kept as
transforms in Scene.instances). Polygons are triangulated (fan for convex,
ear clipping for concave), holes are skipped with a warning, winding follows
``orientation`` and the sign of the transform's determinant (as Hydra does).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Gf, Usd, UsdGeom, UsdLux

from ..core.errors import StageError
from ..core.scene import LIGHT_DISK, LIGHT_DISTANT, LIGHT_DOME, LIGHT_RECT, LIGHT_SPHERE, Instances, Lights, Scene
from .composition import check_composition
from .materials import MaterialReader
from .sky_dome import SKY_LAYER_KEY, DomeTexture
from .triangulate import triangulate_corners

RENDERABLE_PURPOSES = (UsdGeom.Tokens.default_, UsdGeom.Tokens.render)
LIGHT_TYPES = (
    (UsdLux.DistantLight, LIGHT_DISTANT), (UsdLux.DomeLight, LIGHT_DOME), (UsdLux.SphereLight, LIGHT_SPHERE),
    (UsdLux.RectLight, LIGHT_RECT), (UsdLux.DiskLight, LIGHT_DISK),
)


@dataclass
class LocalMesh:
    """One mesh prim's triangulated topology and shading in its own space (shared by all its instances)."""

    path: str
    points: np.ndarray        # (P, 3) float64 local
    triangles: np.ndarray     # (T, 3) int32, authored winding
    tri_corner: np.ndarray    # (T, 3) int32 face-vertex slot of each corner (faceVertexIndices position)
    tri_face: np.ndarray      # (T,) int32
    face_count: int
    tri_albedo: np.ndarray    # (T, 3) float32
    tri_emission: np.ndarray  # (T, 3) float32
    left_handed: bool
    double_sided: bool
    skip: bool
    surface: str


@dataclass
class _Builder:
    """Accumulates per-prim arrays, then concatenates them into a Scene."""

    meshes: list = field(default_factory=list)       # (LocalMesh, world matrix (4,4) float64, writable, instance)
    instance_roots: list = field(default_factory=list)  # per mesh: native instance roots above it, outermost first
    warnings: list = field(default_factory=list)

    def add(self, mesh: LocalMesh, world: np.ndarray, writable: bool, instance: int = -1,
            roots: tuple[str, ...] = ()) -> None:
        self.meshes.append((mesh, world, writable, instance))
        self.instance_roots.append(roots)


def extract_scene(stage: Usd.Stage, *, time: float | None = None, allow_missing: bool = False,
                  deinstance: bool = False) -> Scene:
    """Flatten ``stage`` at ``time`` (None: the default time) into a Scene.

    Natively instanced meshes are read-only instances (kept in ``Scene.instances``), unless
    ``deinstance``: then they are ordinary, writable receivers, which the bake layer de-instances
    (``stages.refined_mesh.complete_outputs`` sets ``instanceable = false`` on their roots).

    Raises StageError naming prim, attribute and value for data that cannot be baked
    (NaN/inf points, out-of-range indices, mismatched counts), and naming the asset and
    the layer that asks for it for a missing or unreadable sublayer, reference or payload
    (unless ``allow_missing``: then each becomes a warning and its geometry is left out).
    A texture that cannot be read becomes a warning naming the fallback albedo used.
    """
    timecode = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    xforms = UsdGeom.XformCache(timecode)
    builder = _Builder(warnings=check_composition(stage, allow_missing=allow_missing))
    materials = MaterialReader(timecode, warnings=builder.warnings)
    local_meshes: dict[str, LocalMesh] = {}
    light_prims: list[Usd.Prim] = []
    volume_prims: list[Usd.Prim] = []
    instances = _InstanceTable()

    def local_mesh(prim: Usd.Prim) -> LocalMesh:
        key = str(prim.GetPath())
        if key not in local_meshes:
            local_meshes[key] = _read_mesh(prim, timecode, materials, builder.warnings)
        return local_meshes[key]

    predicate = Usd.TraverseInstanceProxies(Usd.PrimIsActive & Usd.PrimIsDefined & ~Usd.PrimIsAbstract)
    iterator = iter(Usd.PrimRange.Stage(stage, predicate))
    for prim in iterator:
        if prim.HasAPI("ProbeVolumeAPI"):  # before the visibility test: a volume is often an invisible cube
            volume_prims.append(prim)
        if not _renderable(prim, timecode):
            iterator.PruneChildren()
            continue
        if prim.IsA(UsdGeom.PointInstancer):
            _add_point_instancer(prim, timecode, xforms, local_mesh, builder, instances)
            iterator.PruneChildren()
        elif prim.IsA(UsdGeom.Mesh):
            world = np.array(xforms.GetLocalToWorldTransform(prim), np.float64)
            roots = _instance_roots(prim) if prim.IsInstanceProxy() else ()
            instance = instances.native(stage.GetPrimAtPath(roots[0]), xforms) if roots and not deinstance else -1
            builder.add(local_mesh(prim), world, writable=not roots or deinstance, instance=instance, roots=roots)
        elif any(prim.IsA(light_type) for light_type, _ in LIGHT_TYPES):
            light_prims.append(prim)

    return _assemble(stage, builder, light_prims, volume_prims, instances, xforms, timecode, time)


def _instance_roots(prim: Usd.Prim) -> tuple[str, ...]:
    """The native instances an instance proxy lies under (nested ones too), outermost first."""
    roots = []
    parent = prim.GetParent()
    while parent:
        if parent.IsInstance():
            roots.append(str(parent.GetPath()))
        parent = parent.GetParent()
    return tuple(reversed(roots))


def _renderable(prim: Usd.Prim, timecode: Usd.TimeCode) -> bool:
    imageable = UsdGeom.Imageable(prim)
    if not imageable:
        return True
    if imageable.GetVisibilityAttr().Get(timecode) == UsdGeom.Tokens.invisible:
        return False
    purpose = imageable.GetPurposeAttr().Get()
    return purpose in RENDERABLE_PURPOSES or not purpose


def _read_mesh(prim: Usd.Prim, timecode: Usd.TimeCode, materials: "MaterialReader", warnings: list) -> LocalMesh:
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
    skip_attr = prim.GetAttribute("bake:skip")
    return LocalMesh(
        path=path, points=points, triangles=triangles, tri_corner=tri_corner, tri_face=tri_face, face_count=len(counts),
        tri_albedo=albedo[tri_face], tri_emission=emission[tri_face],
        left_handed=mesh.GetOrientationAttr().Get(timecode) == UsdGeom.Tokens.leftHanded,
        double_sided=bool(mesh.GetDoubleSidedAttr().Get(timecode)),
        skip=bool(skip_attr and skip_attr.Get(timecode)), surface=surface,
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


class _InstanceTable:
    """Collects PointInstancer instances and native instances (each its own 'instancer') for Scene.instances."""

    def __init__(self):
        self.instancer_paths: list[str] = []
        self.instancer_counts: list[int] = []
        self.instancer_native: list[bool] = []
        self.prototype_paths: list[str] = []
        self.prototype_targets: list[list[str]] = []
        self.rows: list[tuple[int, int, np.ndarray, int]] = []  # (instancer, prototype, to-world, authored row)
        self.sources: list[tuple] = []  # (instancer prim, kept rows, protoIndices, first instance index)
        self.native_rows: dict[str, int] = {}  # instance root path -> instance
        self.native_prototypes: dict[str, int] = {}  # USD prototype path -> prototype
        self.stage: Usd.Stage | None = None

    def prototype(self, path: str) -> int:
        if path not in self.prototype_paths:
            self.prototype_paths.append(path)
            self.prototype_targets.append([path])
        return self.prototype_paths.index(path)

    def instancer(self, path: str, count: int, native: bool) -> int:
        self.instancer_paths.append(path)
        self.instancer_counts.append(count)
        self.instancer_native.append(native)
        return len(self.instancer_paths) - 1

    def native(self, root: Usd.Prim, xforms) -> int:
        """The instance of a native instance root (registered on first use): an instancer of one instance
        whose prototype is the root's USD prototype, named by what it references."""
        key = str(root.GetPath())
        if key in self.native_rows:
            return self.native_rows[key]
        self.stage = root.GetStage()
        usd_prototype = str(root.GetPrototype().GetPath())
        if usd_prototype not in self.native_prototypes:
            name = _native_prototype_name(root)
            if name in self.prototype_paths:  # another USD prototype of the same source (e.g. other variants)
                name = f"{name} ({usd_prototype})"
            self.native_prototypes[usd_prototype] = len(self.prototype_paths)
            self.prototype_paths.append(name)
            self.prototype_targets.append([])
        prototype = self.native_prototypes[usd_prototype]
        self.prototype_targets[prototype].append(key)
        instancer = self.instancer(key, 1, native=True)
        self.rows.append((instancer, prototype, np.array(xforms.GetLocalToWorldTransform(root), np.float64), 0))
        self.native_rows[key] = len(self.rows) - 1
        return self.native_rows[key]


def _native_prototype_name(root: Usd.Prim) -> str:
    """What a native instance references: '/Assets/Pawn' (internal), 'props/pawn.usda:/Pawn' (external),
    else its USD prototype's path."""
    for arc in Usd.PrimCompositionQuery.GetDirectReferences(root).GetCompositionArcs():
        target = str(arc.GetTargetPrimPath())
        layer = arc.GetTargetLayer()
        if layer is None or layer == root.GetStage().GetRootLayer():
            return target
        return f"{Path(layer.identifier).name}:{target}"
    return str(root.GetPrototype().GetPath())


def _add_point_instancer(prim, timecode, xforms, local_mesh, builder: _Builder, instances: _InstanceTable) -> None:
    instancer = UsdGeom.PointInstancer(prim)
    path = str(prim.GetPath())
    targets = instancer.GetPrototypesRel().GetTargets()
    proto_indices = np.asarray(instancer.GetProtoIndicesAttr().Get(timecode) or [], np.int64)
    if len(proto_indices) == 0:
        return
    if not targets:
        raise StageError(path, "prototypes", f"targets nothing, but protoIndices names {len(proto_indices)} instances")
    bad = np.flatnonzero((proto_indices < 0) | (proto_indices >= len(targets)))
    if len(bad):
        count = f"{len(targets)} target" + ("s" if len(targets) > 1 else "")
        raise StageError(path, "protoIndices", f"index {int(proto_indices[bad[0]])} at instance {bad[0]}, but "
                                               f"prototypes has {count} (0..{len(targets) - 1})")
    builder.warnings.extend(check_instancer_arrays(prim, timecode, len(proto_indices)))
    matrices = instancer.ComputeInstanceTransformsAtTime(
        timecode, timecode, UsdGeom.PointInstancer.IncludeProtoXform, UsdGeom.PointInstancer.IgnoreMask)
    if matrices is None or len(matrices) != len(proto_indices):
        raise StageError(path, "positions", "instance transforms could not be computed (positions, "
                                            "orientations and protoIndices must have matching lengths)")
    _check_finite_transforms(path, np.array(matrices, np.float64).reshape(-1, 4, 4))
    mask = instancer.ComputeMaskAtTime(timecode) or [True] * len(proto_indices)
    instancer_world = np.array(xforms.GetLocalToWorldTransform(prim), np.float64)
    instancer_index = instances.instancer(path, len(proto_indices), native=False)
    stage = prim.GetStage()
    proto_meshes = {}
    for proto_index, target in enumerate(targets):
        proto_root = stage.GetPrimAtPath(target)
        if not proto_root:
            raise StageError(path, "prototypes", f"target {target} does not exist")
        proto_meshes[proto_index] = _prototype_meshes(proto_root, timecode, xforms, local_mesh)
    instances.sources.append((prim, np.flatnonzero(np.asarray(mask, bool)), proto_indices, len(instances.rows)))
    for row, (proto_index, matrix) in enumerate(zip(proto_indices, matrices)):
        if not mask[row]:
            continue
        to_world = np.array(matrix, np.float64) @ instancer_world
        instance = len(instances.rows)
        instances.rows.append((instancer_index, instances.prototype(str(targets[proto_index])), to_world, row))
        for mesh, relative in proto_meshes[proto_index]:
            builder.add(mesh, relative @ to_world, writable=False, instance=instance)


INSTANCE_ARRAYS = ("positions", "orientations", "orientationsf", "scales")
"""PointInstancer arrays read per instance with no length check: OpenUSD's transform computation warns
about short ``orientations`` or ``scales`` and then reads past their end (different garbage each run),
and fails on short ``positions``. Each must hold one value per protoIndices entry (or none, but
positions): refused otherwise."""

DROPPED_INSTANCE_ARRAYS = ("velocities", "angularVelocities", "accelerations")
"""PointInstancer arrays OpenUSD drops, with a warning, when their length is wrong (the instances are placed
as if they were zero): usdbake does the same and says so."""


def check_instancer_arrays(prim: Usd.Prim, timecode: Usd.TimeCode, count: int, *, when: str = "") -> list[str]:
    """Warnings for the per-instance arrays OpenUSD ignores; StageError, before any transform is computed,
    for a per-instance array whose length is not ``count`` (the protoIndices), for non-finite values,
    and for ``ids`` that cannot mask the instances (a wrong length while invisibleIds or inactiveIds
    select instances by id). ``when``: ' at time T' for a time sample other than the bake's."""
    path = str(prim.GetPath())
    warnings = []
    for name in ("positions", *INSTANCE_ARRAYS[1:], *DROPPED_INSTANCE_ARRAYS):
        attr = prim.GetAttribute(name)
        value = attr.Get(timecode) if attr and attr.HasAuthoredValue() else None
        if value is None or (len(value) == 0 and name != "positions"):
            continue
        if len(value) != count:
            reference = "protoIndices" if name == "positions" else "positions"
            if name in DROPPED_INSTANCE_ARRAYS:
                warnings.append(f"{path}.{name}: {len(value)} values for {count} {reference}{when}; ignored, as "
                                f"OpenUSD does (the instances are placed as if every value were zero)")
                continue
            rule = "one per instance" if name == "positions" else "one per instance, or none"
            raise StageError(path, name, f"{len(value)} values for {count} {reference}{when} ({rule})")
        values = np.array(value, np.float64).reshape(len(value), -1)  # quaternions: (i, j, k, real)
        bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
        if len(bad):
            shown = tuple(float(x) for x in values[bad[0]])
            raise StageError(path, name, f"value {bad[0]} is {shown}{when} ({len(bad)} non-finite values)")
    masking = bool(prim.GetMetadata("inactiveIds")) or bool(prim.GetAttribute("invisibleIds").Get(timecode))
    ids = prim.GetAttribute("ids").Get(timecode) if prim.GetAttribute("ids") else None
    if masking and ids is not None and len(ids) and len(ids) != count:
        raise StageError(path, "ids", f"{len(ids)} values for {count} protoIndices{when} (invisibleIds and "
                                      f"inactiveIds name instances by id: one id per instance)")
    return warnings


def _check_finite_transforms(path: str, matrices: np.ndarray, when: str = "") -> None:
    """StageError naming the first instance whose transform is not finite (an overflow of scales times
    the prototype's transform, say), before any compute."""
    bad = np.flatnonzero(~np.isfinite(matrices).all(axis=(1, 2)))
    if len(bad):
        raise StageError(path, "positions", f"instance {bad[0]}'s transform is not finite{when} "
                                            f"({len(bad)} such instances)")


def _prototype_meshes(root: Usd.Prim, timecode, xforms, local_mesh) -> list:
    """Renderable meshes under a prototype root, with transforms relative to the root's space."""
    found = []
    predicate = Usd.TraverseInstanceProxies(Usd.PrimIsActive & Usd.PrimIsDefined)
    iterator = iter(Usd.PrimRange(root, predicate))
    for prim in iterator:
        if prim != root and not _renderable(prim, timecode):
            iterator.PruneChildren()
        elif prim.IsA(UsdGeom.Mesh):
            relative = Gf.Matrix4d(1.0) if prim == root else xforms.ComputeRelativeTransform(prim, root)[0]
            found.append((local_mesh(prim), np.array(relative, np.float64)))
    return found


def _assemble(stage, builder: _Builder, light_prims, volume_prims, instances: _InstanceTable, xforms, timecode,
              time) -> Scene:
    with np.errstate(over="ignore", invalid="ignore"):  # an overflowing transform is named just below
        world_points = [np.c_[m.points, np.ones(len(m.points))] @ world for m, world, _, _ in builder.meshes]
    for (mesh, world, _, _), points in zip(builder.meshes, world_points):
        _check_world_points(mesh.path, world, points[:, :3])
    all_points = np.concatenate([p[:, :3] for p in world_points]) if world_points else np.zeros((0, 3))
    origin = ((all_points.min(axis=0) + all_points.max(axis=0)) / 2) if len(all_points) else np.zeros(3)
    _check_extent(stage, all_points)

    point_start = np.zeros(len(builder.meshes) + 1, np.int64)
    tri_parts, corner_parts, face_parts, prim_parts = [], [], [], []
    for m_index, ((mesh, world, _, _), points) in enumerate(zip(builder.meshes, world_points)):
        point_start[m_index + 1] = point_start[m_index] + len(points)
        flip = mesh.left_handed ^ (np.linalg.det(world[:3, :3]) < 0)
        triangles = mesh.triangles[:, ::-1] if flip else mesh.triangles
        tri_parts.append(triangles + point_start[m_index])
        corner_parts.append(mesh.tri_corner[:, ::-1] if flip else mesh.tri_corner)
        prim_parts.append(np.full(len(triangles), m_index, np.int32))
        face_parts.append(mesh.tri_face)

    def cat(parts, empty_shape, dtype):
        return np.concatenate(parts, dtype=dtype, casting="unsafe") if parts else np.zeros(empty_shape, dtype)

    points = (all_points - origin).astype(np.float32)
    tri_vertices = cat(tri_parts, (0, 3), np.int32)
    tri_normals, tri_areas = _triangle_normals(points, tri_vertices)
    meshes = [m for m, _, _, _ in builder.meshes]
    tri_prim = cat(prim_parts, 0, np.int32)
    per_tri = lambda name, shape: cat([getattr(m, name) for m in meshes], shape, np.float32)  # noqa: E731
    return Scene(
        points=points, tri_vertices=tri_vertices, tri_normals=tri_normals, tri_areas=tri_areas,
        tri_albedo=per_tri("tri_albedo", (0, 3)), tri_emission=per_tri("tri_emission", (0, 3)),
        tri_prim=tri_prim, tri_face=cat(face_parts, 0, np.int32), tri_corner=cat(corner_parts, (0, 3), np.int32),
        tri_instance=np.array([inst for _, _, _, inst in builder.meshes], np.int32)[tri_prim]
        if len(tri_prim) else np.zeros(0, np.int32),
        tri_double_sided=np.array([m.double_sided for m in meshes], bool)[tri_prim]
        if len(tri_prim) else np.zeros(0, bool),
        point_prim=np.repeat(np.arange(len(meshes), dtype=np.int32), np.diff(point_start)),
        prim_paths=tuple(m.path for m in meshes),
        prim_point_start=point_start,
        prim_face_count=np.array([m.face_count for m in meshes], np.int32),
        prim_writable=np.array([w for _, _, w, _ in builder.meshes], bool),
        prim_skip=np.array([m.skip for m in meshes], bool),
        prim_instance_roots=tuple(builder.instance_roots),
        prim_surface=tuple(m.surface for m in meshes),
        lights=_read_lights(light_prims, xforms, timecode, origin),
        instances=_instances(instances, origin),
        origin=origin,
        prim_to_world=_prim_to_world(builder, origin),
        probe_volumes=probe_volumes(volume_prims, timecode, origin),
        up_axis=str(UsdGeom.GetStageUpAxis(stage)),
        meters_per_unit=float(UsdGeom.GetStageMetersPerUnit(stage)),
        site=stage_site(stage),
        time_code=time,
        source=stage.GetRootLayer().identifier,
        warnings=tuple(builder.warnings),
    )


EXTENT_RANGE = (1e-12, 1e15)
"""Scene extents (bounding-box diagonal, stage units) usdbake bakes; outside it the bake is refused before
any compute, naming the extent. The Scene and the processors work in float32, and some of their values are
products of two lengths (areas, squared distances, the light model's 1/d^2 bound of (1e-4 d)^2): at 1e-12
a feature of 1e-6 of the extent still squares to 1e-36, a normal float32 (they start at 1.2e-38); at 1e15
the squares reach 1e30, eight decades under float32's 3.4e38 for the sums and radiance products they enter.
The ray core itself is scale-free (``kernels.tracer.trace_scale``): ambient occlusion, sky visibility,
radiosity and the irradiance grid of the Cornell box agree from 1e-14 to 1e18 units across."""


def _check_extent(stage: Usd.Stage, points: np.ndarray) -> None:
    """StageError naming the scene's extent when it lies outside EXTENT_RANGE (a scene of one point, or
    none, has no extent to check)."""
    if len(points) == 0:
        return
    diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    low, high = EXTENT_RANGE
    if diagonal == 0.0 or low <= diagonal <= high:
        return
    where = stage.GetRootLayer().identifier
    raise StageError(where if stage.GetRootLayer().anonymous else Path(where).name, "",
                     f"the geometry spans {diagonal:.4g} stage units (bounding-box diagonal); usdbake computes in "
                     f"float32 and bakes extents from {low:g} to {high:g}: scale the stage (an xformOp:scale on "
                     f"its root prim, and metersPerUnit to match)")


def _check_world_points(path: str, world: np.ndarray, points: np.ndarray) -> None:
    """StageError naming a mesh whose points are finite but whose world-space points are not: a transform
    (its own or a parent's) holds a non-finite value, or scales the points past float64."""
    if not np.isfinite(world).all():
        raise StageError(path, "", "its world transform holds a non-finite value (an xformOp of the prim or of a "
                                   "parent is inf or nan)")
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if len(bad):
        raise StageError(path, "", f"point {bad[0]} overflows to {tuple(float(v) for v in points[bad[0]])} in "
                                   f"world space ({len(bad)} such points): its transform, or a parent's, scales "
                                   f"it past float64")


def probe_volumes(prims: list, timecode: Usd.TimeCode, origin: np.ndarray) -> np.ndarray:
    """(K, 2, 3) world bounds (relative to ``origin``) of the probe-volume prims (ProbeVolumeAPI) the
    extraction met, visible or not."""
    cache = UsdGeom.BBoxCache(timecode, [UsdGeom.Tokens.default_, UsdGeom.Tokens.render, UsdGeom.Tokens.proxy,
                                         UsdGeom.Tokens.guide])
    boxes = []
    for prim in prims:
        box = cache.ComputeWorldBound(prim).ComputeAlignedRange()  # invisible prims count: volumes often are
        if box.IsEmpty():
            raise StageError(str(prim.GetPath()), "ProbeVolumeAPI", "the probe volume has no extent (a "
                             "boundable prim with a size, such as a Cube, is needed)")
        boxes.append([np.array(box.GetMin()) - origin, np.array(box.GetMax()) - origin])
    return np.array(boxes, np.float64).reshape(-1, 2, 3)


def stage_site(stage: Usd.Stage) -> dict:
    """Latitude, longitude and time zone from the strongest ``usdbake sky`` layer of the stage's layer stack
    that records them (plus that layer), or {}."""
    for layer in stage.GetLayerStack(includeSessionLayers=False):
        data = dict(layer.customLayerData).get(SKY_LAYER_KEY)
        if isinstance(data, dict) and {"latitude", "longitude", "timezone"} <= set(data):
            return {"latitude": float(data["latitude"]), "longitude": float(data["longitude"]),
                    "timezone": float(data["timezone"]), "layer": layer.identifier}
    return {}


def _prim_to_world(builder: _Builder, origin: np.ndarray) -> np.ndarray:
    """(M, 4, 4) float64 world matrices per prim, translation relative to ``origin``."""
    matrices = np.array([world for _, world, _, _ in builder.meshes], np.float64).reshape(-1, 4, 4)
    matrices[:, 3, :3] -= origin
    return matrices


NORMALS_BLOCK = 1 << 18
"""Triangles per block of the float64 normal computation: bounds its temporaries to ~50 MB whatever the
scene size (10,000 flattened instances of a 1k-triangle prototype are 10M triangles)."""


def _triangle_normals(points: np.ndarray, tri_vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit geometric normals (zero for degenerate triangles) and areas, computed in float64, block by block."""
    normals = np.zeros((len(tri_vertices), 3), np.float32)
    areas = np.zeros(len(tri_vertices), np.float32)
    for lo in range(0, len(tri_vertices), NORMALS_BLOCK):
        corners = points[tri_vertices[lo:lo + NORMALS_BLOCK]].astype(np.float64)
        cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        double_area = np.linalg.norm(cross, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            normals[lo:lo + NORMALS_BLOCK] = np.where(double_area[:, None] > 0, cross / double_area[:, None], 0.0)
        areas[lo:lo + NORMALS_BLOCK] = double_area / 2
    return normals, areas


def _instances(table: _InstanceTable, origin: np.ndarray) -> Instances:
    transforms = np.array([m for _, _, m, _ in table.rows], np.float64).reshape(-1, 4, 4)
    transforms[:, 3, :3] -= origin
    times, at_times = _instance_time_samples(table, origin)
    return Instances(
        instancer_paths=tuple(table.instancer_paths), prototype_paths=tuple(table.prototype_paths),
        instance_instancer=np.array([i for i, _, _, _ in table.rows], np.int32),
        instance_prototype=np.array([p for _, p, _, _ in table.rows], np.int32),
        instance_transforms=transforms, instance_times=times, instance_transforms_at_times=at_times,
        instance_index=np.array([r for _, _, _, r in table.rows], np.int32),
        instancer_instance_count=np.array(table.instancer_counts, np.int32),
        instancer_native=np.array(table.instancer_native, bool),
        prototype_targets=tuple(tuple(targets) for targets in table.prototype_targets),
    )


MAX_INSTANCE_TIME_BYTES = 256 * 2**20
"""Cap on Instances.instance_transforms_at_times (F x I x 128 bytes); later times are dropped beyond it."""


def _instance_time_samples(table: _InstanceTable, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Instance transforms at every authored time sample of the instancers' positions/orientations/scales.

    Times at which an instancer's protoIndices or mask give a different set of instances
    than at the extraction time are left out (the instance rows must stay the same).
    """
    count = len(table.rows)
    times: set[float] = set()
    for prim, _, _, _ in table.sources:
        instancer = UsdGeom.PointInstancer(prim)
        for attr in (instancer.GetPositionsAttr(), instancer.GetOrientationsAttr(), instancer.GetScalesAttr(),
                     prim.GetAttribute("orientationsf")):
            if attr:
                times.update(attr.GetTimeSamples())
    times_kept, frames = [], []
    budget = max(1, MAX_INSTANCE_TIME_BYTES // max(1, count * 128))
    for t in sorted(times)[:budget]:
        timecode = Usd.TimeCode(t)
        frame = np.zeros((count, 4, 4), np.float64)
        ok = True
        for prim, kept, proto_indices, first in table.sources:
            instancer = UsdGeom.PointInstancer(prim)
            indices = np.asarray(instancer.GetProtoIndicesAttr().Get(timecode) or [], np.int64)
            if not np.array_equal(indices, proto_indices):
                ok = False
                break
            check_instancer_arrays(prim, timecode, len(indices), when=f" at time {t:g}")  # before OpenUSD reads them
            mask = np.asarray(instancer.ComputeMaskAtTime(timecode) or [True] * len(indices), bool)
            matrices = instancer.ComputeInstanceTransformsAtTime(
                timecode, timecode, UsdGeom.PointInstancer.IncludeProtoXform, UsdGeom.PointInstancer.IgnoreMask)
            if (matrices is None or len(matrices) != len(proto_indices)
                    or not np.array_equal(np.flatnonzero(mask), kept)):
                ok = False
                break
            _check_finite_transforms(str(prim.GetPath()), np.array(matrices, np.float64).reshape(-1, 4, 4),
                                     f" at time {t:g}")
            world = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(timecode), np.float64)
            local = np.array(matrices, np.float64).reshape(-1, 4, 4)[kept]
            frame[first:first + len(kept)] = local @ world
        for root, instance in table.native_rows.items():  # native instances follow their root's transform
            root_prim = table.stage.GetPrimAtPath(root)
            frame[instance] = np.array(UsdGeom.Xformable(root_prim).ComputeLocalToWorldTransform(timecode), np.float64)
        if ok:
            frame[:, 3, :3] -= origin
            times_kept.append(t)
            frames.append(frame)
    if not frames:
        return np.zeros(0, np.float64), np.zeros((0, count, 4, 4), np.float64)
    return np.array(times_kept, np.float64), np.stack(frames)


def _read_lights(prims: list, xforms, timecode, origin: np.ndarray) -> Lights:
    rows = []
    for prim in prims:
        kind = next(k for light_type, k in LIGHT_TYPES if prim.IsA(light_type))
        light = UsdLux.LightAPI(prim)
        world = np.array(xforms.GetLocalToWorldTransform(prim), np.float64)
        intensity = float(light.GetIntensityAttr().Get(timecode))
        exposure = float(light.GetExposureAttr().Get(timecode))
        color = np.array(light.GetColorAttr().Get(timecode), np.float64)
        if light.GetEnableColorTemperatureAttr().Get(timecode):
            color *= np.array(UsdLux.BlackbodyTemperatureAsRgb(light.GetColorTemperatureAttr().Get(timecode)))
        radiance = intensity * 2.0 ** exposure * color
        if not np.isfinite(radiance).all():
            raise StageError(str(prim.GetPath()), "inputs:intensity", f"light radiance {radiance} is not finite")
        size, area = _light_size(prim, kind, world, timecode)
        if light.GetNormalizeAttr().Get(timecode) and area > 0:
            radiance = radiance / area
        direction = -world[2, :3]
        norm = np.linalg.norm(direction)
        rows.append((str(prim.GetPath()), kind, radiance, world[3, :3] - origin,
                     direction / norm if norm > 0 else np.array([0.0, 0.0, -1.0]), size))
    texture, to_local = _dome_texture([p for p in prims if p.IsA(UsdLux.DomeLight)], xforms, timecode)
    return Lights(
        dome_source=texture, dome_to_local=to_local,
        light_paths=tuple(r[0] for r in rows),
        light_kind=np.array([r[1] for r in rows], np.int32),
        light_radiance=np.array([r[2] for r in rows], np.float32).reshape(-1, 3),
        light_position=np.array([r[3] for r in rows], np.float32).reshape(-1, 3),
        light_direction=np.array([r[4] for r in rows], np.float32).reshape(-1, 3),
        light_size=np.array([r[5] for r in rows], np.float32).reshape(-1, 2),
    )


def _dome_texture(domes: list, xforms, timecode) -> tuple[DomeTexture | None, np.ndarray]:
    """(the texture file of the first DomeLight with one, world-to-dome rotation); the file is opened here
    (its header: a missing or unreadable file fails before any compute) and its texels read when a
    processor first reads the lights (``DomeTexture``). StageError naming the light and the file when it
    cannot be read or is not a lat-long map."""
    for prim in domes:
        dome = UsdLux.DomeLight(prim)
        asset = dome.GetTextureFileAttr().Get(timecode)
        if not asset or not asset.path:
            continue
        path = str(prim.GetPath())
        layout = dome.GetTextureFormatAttr().Get(timecode) or UsdLux.Tokens.automatic
        if layout not in (UsdLux.Tokens.automatic, UsdLux.Tokens.latlong):
            raise StageError(path, "inputs:texture:format", f"{layout!r}: only lat-long dome textures are read "
                                                            f"(automatic or latlong)")
        if not asset.resolvedPath:
            raise StageError(path, "inputs:texture:file", f"{asset.path}: not found")
        texture = DomeTexture(path, asset.path, asset.resolvedPath, srgb=True)
        texture.check()
        rotation = np.array(xforms.GetLocalToWorldTransform(prim), np.float64)[:3, :3]
        rotation /= np.maximum(np.linalg.norm(rotation, axis=1, keepdims=True), 1e-300)  # drop scale
        return texture, np.linalg.inv(rotation)
    return None, np.eye(3)


def _light_size(prim, kind: int, world: np.ndarray, timecode) -> tuple[tuple[float, float], float]:
    """(size pair, world-space emitting area) of a light."""
    scale = np.linalg.norm(world[:3, :3], axis=1)  # row lengths: x, y, z axis scales
    if kind == LIGHT_SPHERE:
        radius = float(UsdLux.SphereLight(prim).GetRadiusAttr().Get(timecode)) * float(scale.max())
        return (radius, radius), 4.0 * np.pi * radius * radius
    if kind == LIGHT_DISK:
        radius = float(UsdLux.DiskLight(prim).GetRadiusAttr().Get(timecode)) * float(scale[:2].max())
        return (radius, radius), np.pi * radius * radius
    if kind == LIGHT_RECT:
        rect = UsdLux.RectLight(prim)
        width = float(rect.GetWidthAttr().Get(timecode)) * float(scale[0])
        height = float(rect.GetHeightAttr().Get(timecode)) * float(scale[1])
        return (width, height), width * height
    if kind == LIGHT_DISTANT:
        angle = float(UsdLux.DistantLight(prim).GetAngleAttr().Get(timecode))
        return (angle, angle), 0.0
    return (0.0, 0.0), 0.0
