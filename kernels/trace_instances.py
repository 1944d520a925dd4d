"""Two-level tracing of a Scene's instances: one bottom-level tree per prototype, not per instance.

The Scene flattens instances into its triangle arrays (every instance occludes), listing each
instance's triangles consecutively in its prototype's order. The ray core instead traces each
prototype once, through per-instance transforms (``bvh_build.two_level``), so its memory grows with
authored triangles. A prototype's tree is built from its first instance's triangles (in that
instance's world space); every other instance is checked to be exactly that geometry under its
relative transform (within float32 rounding) and traced flat with the static triangles otherwise,
so the two-level scene always traces the Scene's own triangles.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .bvh_build import TraceArrays, build_triangle_bvh, two_level

INSTANCING_CHOICES = ("auto", "always", "never")
AUTO_MIN_SAVING = 4.0
"""``instancing="auto"`` traces two-level when instanced triangles outnumber the prototypes' own by this."""
SINGULAR = 1e-9
"""An instance transform whose determinant is below this fraction of its largest entry cubed is singular."""
MATCH_TOLERANCE = 1e-5
"""Instance geometry must match its prototype's to this fraction of the scene diagonal."""


def instanced_arrays(scene, instancing: str = "auto") -> TraceArrays | None:
    """The two-level scene of ``scene``'s instances, or None to trace it flat (no instances worth it)."""
    if instancing not in INSTANCING_CHOICES:
        raise ValueError(f"instancing {instancing!r}: expected one of {', '.join(INSTANCING_CHOICES)}")
    tri_instance = np.asarray(scene.tri_instance)
    if instancing == "never" or len(scene.instances) == 0 or not (tri_instance >= 0).any():
        return None
    runs = _instance_runs(tri_instance, len(scene.instances))
    prototypes = np.asarray(scene.instances.instance_prototype)
    transforms = np.asarray(scene.instances.instance_transforms, np.float64)
    tolerance = MATCH_TOLERANCE * max(scene.diagonal, 1e-30)

    reference: dict[int, int] = {}  # prototype -> its first instance with triangles
    reference_corners: dict[int, np.ndarray] = {}
    traced = []  # (instance, bottom index, to_world (3, 4), mirrored)
    flat = np.ones(len(tri_instance), bool)  # triangles traced as they are, with the static ones
    linear = transforms[:, :3, :3]
    scale = np.abs(linear).max(axis=(1, 2)) if len(linear) else np.zeros(0)
    invertible = np.abs(np.linalg.det(linear)) > SINGULAR * np.maximum(scale, 1e-300) ** 3
    for instance, (first, count) in enumerate(runs):
        if count == 0 or not invertible[instance]:  # a flattened (singular) instance is traced as triangles
            continue
        proto = int(prototypes[instance])
        if proto not in reference:
            reference[proto] = instance
            reference_corners[proto] = _corners(scene, first, count)
        ref = reference[proto]
        ref_count = runs[ref][1]
        relative = np.linalg.solve(transforms[ref], transforms[instance])  # inv(T_ref) @ T_i (row vectors)
        to_world = relative.T[:3]  # column form: x_world = A x + b
        mirrored = bool(np.linalg.det(relative[:3, :3]) < 0)
        if count != ref_count or not _matches(reference_corners[proto], _corners(scene, first, count), to_world,
                                              mirrored, tolerance):
            continue
        flat[first:first + count] = False
        traced.append((instance, proto, to_world, mirrored))
    if not traced:
        return None
    instanced_triangles = sum(runs[i][1] for i, *_ in traced)
    prototype_triangles = sum(runs[reference[p]][1] for p in {p for _, p, _, _ in traced})
    if instancing == "auto" and instanced_triangles < AUTO_MIN_SAVING * prototype_triangles:
        return None

    bottoms, bottom_of = [], {}
    for proto in sorted({p for _, p, _, _ in traced}):
        first, count = runs[reference[proto]]
        bottom_of[proto] = len(bottoms)
        bottoms.append(build_triangle_bvh(scene.points, scene.tri_vertices[first:first + count]))
    instance_bottom = [bottom_of[p] for _, p, _, _ in traced]
    to_world = [m for _, _, m, _ in traced]
    faces = [runs[i][0] for i, *_ in traced]
    mirrored = [int(m) for *_, m in traced]
    flat_triangles = np.flatnonzero(flat)
    if len(flat_triangles):  # the static (and unmatched) triangles: one identity instance, lanes = scene triangles
        static = build_triangle_bvh(scene.points, scene.tri_vertices[flat_triangles])
        lanes = np.where(static.packet_triangle >= 0, flat_triangles[static.packet_triangle], -1)
        static = replace(static, packet_triangle=lanes.astype(np.int32))
        instance_bottom.append(len(bottoms))
        bottoms.append(static)
        to_world.append(np.eye(3, 4))
        faces.append(0)
        mirrored.append(0)
    return two_level(bottoms, np.asarray(instance_bottom), np.asarray(to_world), np.asarray(faces),
                     np.asarray(mirrored))


def _instance_runs(tri_instance: np.ndarray, instances: int) -> list[tuple[int, int]]:
    """(first triangle, count) per instance; an instance whose triangles are not consecutive gets count 0."""
    runs = [(0, 0)] * instances
    ids = np.flatnonzero(tri_instance >= 0)
    if not len(ids):
        return runs
    inst = tri_instance[ids]
    boundaries = np.flatnonzero(np.diff(inst) != 0) + 1
    starts = np.concatenate([[0], boundaries])
    ends = np.concatenate([boundaries, [len(ids)]])
    seen = set()
    for start, end in zip(starts, ends):
        instance = int(inst[start])
        consecutive = ids[end - 1] - ids[start] == end - 1 - start
        runs[instance] = (int(ids[start]), int(end - start)) if consecutive and instance not in seen else (0, 0)
        seen.add(instance)
    return runs


def _corners(scene, first: int, count: int) -> np.ndarray:
    """(count, 3, 3) float64 corners of the scene's triangles first .. first + count - 1 (one instance's:
    never the whole scene's, which for 10,000 instances would be gigabytes)."""
    return scene.points[scene.tri_vertices[first:first + count]].astype(np.float64)


def _matches(reference: np.ndarray, ours: np.ndarray, to_world: np.ndarray, mirrored: bool, tolerance: float) -> bool:
    """Triangles ``ours`` (n, 3, 3) are ``reference`` under ``to_world`` (winding reversed if mirrored)."""
    moved = reference @ to_world[:, :3].T + to_world[:, 3]
    if mirrored:
        moved = moved[:, ::-1]
    return bool(np.abs(moved - ours).max(initial=0.0) <= tolerance)
