"""PointInstancers and native instances: their prototypes' meshes placed per instance (so they occlude),
and the instances kept as transforms, at the bake's time and at every authored time sample, for
``Scene.instances``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pxr import Gf, Usd, UsdGeom

from ..core.errors import StageError
from ..core.scene import Instances
from .mesh_prims import SceneBuilder, renderable


def instance_roots(prim: Usd.Prim) -> tuple[str, ...]:
    """The native instances an instance proxy lies under (nested ones too), outermost first."""
    roots = []
    parent = prim.GetParent()
    while parent:
        if parent.IsInstance():
            roots.append(str(parent.GetPath()))
        parent = parent.GetParent()
    return tuple(reversed(roots))


class InstanceTable:
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


def add_point_instancer(prim, timecode, xforms, local_mesh, builder: SceneBuilder, instances: InstanceTable) -> None:
    """Every unmasked instance of a PointInstancer into ``instances``, and its prototype's meshes, placed, into
    ``builder`` (read-only); StageError for prototypes, protoIndices or transforms that cannot be baked."""
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
        if prim != root and not renderable(prim, timecode):
            iterator.PruneChildren()
        elif prim.IsA(UsdGeom.Mesh):
            relative = Gf.Matrix4d(1.0) if prim == root else xforms.ComputeRelativeTransform(prim, root)[0]
            found.append((local_mesh(prim), np.array(relative, np.float64)))
    return found


def scene_instances(table: InstanceTable, origin: np.ndarray) -> Instances:
    """The table as ``Scene.instances``, translations relative to ``origin``."""
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


def _instance_time_samples(table: InstanceTable, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
