"""The instances' own vertices as AO sample points for ``instance_ao`` (``instances = true``): moved
rigidly with their instance per frame, reduced to an area-weighted mean per instance, written on the
PointInstancers and native instance roots."""

from __future__ import annotations

import numpy as np

from ...core import Primvar
from ...core.scene import Scene
from ...geometry.mesh import face_means
from .transforms import invertible


class InstancePoints:
    """The instances' own vertices as AO sample points, moved rigidly with their instance per frame."""

    def __init__(self, scene: Scene, normals: np.ndarray, inward: np.ndarray, instance_field: np.ndarray):
        inst = scene.instances
        prim_instance = np.full(len(scene.prim_paths), -1, np.int32)
        prim_instance[scene.tri_prim] = scene.tri_instance
        point_instance = prim_instance[scene.point_prim]
        self.scene = scene
        self.point_ids = np.flatnonzero(point_instance >= 0)
        self.instance = point_instance[self.point_ids]
        # instances without a field are triangles in the BVH: they occlude themselves there and do not move
        self.moving = instance_field[self.instance] >= 0
        self.own = np.where(self.moving, self.instance, -1).astype(np.int32)
        self.points = scene.points[self.point_ids].astype(np.float64)
        self.normals = normals[self.point_ids].astype(np.float64)
        self.inward = inward[self.point_ids].astype(np.float64)
        """Tangents into each point's own face (the one ray-origin rule: an unwelded crease is not self-occluding)."""
        area = np.zeros(scene.num_points)
        np.add.at(area, scene.tri_vertices.ravel(), np.repeat(scene.tri_areas.astype(np.float64) / 3, 3))
        self.weights = area[self.point_ids]
        self.base_inverse = np.linalg.inv(np.where(invertible(inst.instance_transforms)[:, None, None],
                                                   inst.instance_transforms, np.eye(4)))
        count = len(inst.instancer_paths)
        self.instancer_count = (inst.instancer_instance_count if len(inst.instancer_instance_count) == count else
                                np.bincount(inst.instance_instancer, minlength=count))
        if len(inst.instance_index) == len(inst):
            self.row = np.asarray(inst.instance_index)
        else:  # scenes built without the authored rows: instances in order within each instancer
            self.row = np.zeros(len(inst), np.int64)
            for n in range(count):
                mine = np.flatnonzero(inst.instance_instancer == n)
                self.row[mine] = np.arange(len(mine))

    def at(self, transforms: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, 3) float32 positions, unit normals and unit inward tangents with each instance moved by
        transforms (I, 4, 4)."""
        relative = self.base_inverse @ np.where(invertible(transforms)[:, None, None], transforms, np.eye(4))
        per_point = relative[self.instance]
        points = np.einsum("ni,nij->nj", np.c_[self.points, np.ones(len(self.points))], per_point)[:, :3]
        normal_map = np.linalg.inv(per_point[:, :3, :3]).transpose(0, 2, 1)
        normals = np.einsum("ni,nij->nj", self.normals, normal_map)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.where(length > 0, normals / np.maximum(length, 1e-300), 0.0)
        inward = np.einsum("ni,nij->nj", self.inward, per_point[:, :3, :3])  # a tangent moves with the surface
        length = np.linalg.norm(inward, axis=1, keepdims=True)
        inward = np.where(length > 0, inward / np.maximum(length, 1e-300), 0.0)
        points = np.where(self.moving[:, None], points, self.points)
        normals = np.where(self.moving[:, None], normals, self.normals)
        inward = np.where(self.moving[:, None], inward, self.inward)
        return points.astype(np.float32), normals.astype(np.float32), inward.astype(np.float32)

    def means(self, ao: np.ndarray) -> np.ndarray:
        """(I,) float32 area-weighted mean AO per instance (1 for an instance without area)."""
        # face_means is a weighted mean per group; the groups here are instances, not faces
        return face_means(ao, self.weights, self.instance, len(self.scene.instances))

    def records(self, means: np.ndarray, frame: float | None) -> list:
        """primvars:bake:ao on each PointInstancer: one value per authored instance (vertex = per instance);
        on a native instance's root: its value, constant (its meshes inherit it)."""
        inst = self.scene.instances
        records = []
        for n, path in enumerate(inst.instancer_paths):
            values = np.ones(int(self.instancer_count[n]), np.float32)  # masked instances: 1
            mine = np.flatnonzero(inst.instance_instancer == n)
            values[self.row[mine]] = means[mine]
            interpolation = "constant" if inst.is_native(n) else "vertex"
            records.append(Primvar(path, "bake:ao", values, "float", interpolation, time=frame))
        return records
