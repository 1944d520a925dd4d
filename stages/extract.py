"""Stage -> Scene: traverse a composed Usd.Stage once and flatten it into arrays.

Honours visibility, purpose (default/render only), active state, instance
proxies of instanceable prims, and UsdGeom.PointInstancer (prototypes are
flattened per instance so they occlude, and the instances are also kept as
transforms in Scene.instances). Polygons are triangulated (fan for convex,
ear clipping for concave), holes are skipped with a warning, winding follows
``orientation`` and the sign of the transform's determinant (as Hydra does).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom

from ..core.errors import StageError
from ..core.scene import Scene
from .composition import check_composition
from .instancers import InstanceTable, add_point_instancer, instance_roots, scene_instances
from .light_prims import LIGHT_TYPES, read_lights
from .materials import MaterialReader
from .mesh_prims import LocalMesh, SceneBuilder, read_mesh, renderable
from .sky_dome import SKY_LAYER_KEY


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
    A texture that cannot be read becomes a warning naming the fallback albedo used. A glazing value
    (``bake:transmittance``, a UsdPreviewSurface's opacity) that is not a float in [0, 1] raises StageError
    too (``stages.materials``).
    """
    timecode = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    xforms = UsdGeom.XformCache(timecode)
    builder = SceneBuilder(warnings=check_composition(stage, allow_missing=allow_missing))
    materials = MaterialReader(timecode, warnings=builder.warnings)
    local_meshes: dict[str, LocalMesh] = {}
    light_prims: list[Usd.Prim] = []
    volume_prims: list[Usd.Prim] = []
    instances = InstanceTable()

    def local_mesh(prim: Usd.Prim) -> LocalMesh:
        key = str(prim.GetPath())
        if key not in local_meshes:
            local_meshes[key] = read_mesh(prim, timecode, materials, builder.warnings)
        return local_meshes[key]

    predicate = Usd.TraverseInstanceProxies(Usd.PrimIsActive & Usd.PrimIsDefined & ~Usd.PrimIsAbstract)
    iterator = iter(Usd.PrimRange.Stage(stage, predicate))
    for prim in iterator:
        if prim.HasAPI("ProbeVolumeAPI"):  # before the visibility test: a volume is often an invisible cube
            volume_prims.append(prim)
        if not renderable(prim, timecode):
            iterator.PruneChildren()
            continue
        if prim.IsA(UsdGeom.PointInstancer):
            add_point_instancer(prim, timecode, xforms, local_mesh, builder, instances)
            iterator.PruneChildren()
        elif prim.IsA(UsdGeom.Mesh):
            world = np.array(xforms.GetLocalToWorldTransform(prim), np.float64)
            roots = instance_roots(prim) if prim.IsInstanceProxy() else ()
            instance = instances.native(stage.GetPrimAtPath(roots[0]), xforms) if roots and not deinstance else -1
            builder.add(local_mesh(prim), world, writable=not roots or deinstance, instance=instance, roots=roots)
        elif any(prim.IsA(light_type) for light_type, _ in LIGHT_TYPES):
            light_prims.append(prim)

    return _assemble(stage, builder, light_prims, volume_prims, instances, xforms, timecode, time)


def _assemble(stage, builder: SceneBuilder, light_prims, volume_prims, instances: InstanceTable, xforms, timecode,
              time) -> Scene:
    with np.errstate(over="ignore", invalid="ignore"):  # an overflowing transform is named just below
        world_points = [np.c_[m.points, np.ones(len(m.points))] @ world for m, world, _, _ in builder.meshes]
    for (mesh, world, _, _), points in zip(builder.meshes, world_points):
        _check_world_points(mesh.path, world, points[:, :3])
    all_points = np.concatenate([p[:, :3] for p in world_points]) if world_points else np.zeros((0, 3))
    origin = ((all_points.min(axis=0) + all_points.max(axis=0)) / 2) if len(all_points) else np.zeros(3)
    _check_extent(stage, all_points)

    point_start = np.zeros(len(builder.meshes) + 1, np.int64)
    tri_parts, corner_parts, face_parts, prim_parts, st_parts, lightmap_parts = [], [], [], [], [], []
    for m_index, ((mesh, world, _, _), points) in enumerate(zip(builder.meshes, world_points)):
        point_start[m_index + 1] = point_start[m_index] + len(points)
        flip = mesh.left_handed ^ (np.linalg.det(world[:3, :3]) < 0)
        triangles = mesh.triangles[:, ::-1] if flip else mesh.triangles
        tri_parts.append(triangles + point_start[m_index])
        corner_parts.append(mesh.tri_corner[:, ::-1] if flip else mesh.tri_corner)
        for parts, uvs in ((st_parts, mesh.tri_st), (lightmap_parts, mesh.tri_lightmap_uv)):
            uvs = np.zeros((len(triangles), 3, 2), np.float32) if uvs is None else uvs
            parts.append(uvs[:, ::-1] if flip else uvs)
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
        tri_transmittance=per_tri("tri_transmittance", 0),
        tri_prim=tri_prim, tri_face=cat(face_parts, 0, np.int32), tri_corner=cat(corner_parts, (0, 3), np.int32),
        tri_instance=np.array([inst for _, _, _, inst in builder.meshes], np.int32)[tri_prim]
        if len(tri_prim) else np.zeros(0, np.int32),
        tri_double_sided=np.array([m.double_sided for m in meshes], bool)[tri_prim]
        if len(tri_prim) else np.zeros(0, bool),
        point_prim=np.repeat(np.arange(len(meshes), dtype=np.int32), np.diff(point_start)),
        prim_paths=tuple(m.path for m in meshes),
        prim_point_start=point_start,
        prim_face_count=np.array([m.face_count for m in meshes], np.int32),
        prim_corner_count=np.array([m.corner_count for m in meshes], np.int64),
        prim_writable=np.array([w for _, _, w, _ in builder.meshes], bool),
        prim_skip=np.array([m.skip for m in meshes], bool),
        prim_instance_roots=tuple(builder.instance_roots),
        prim_surface=tuple(m.surface for m in meshes),
        prim_subset_surfaces=tuple(m.subset_surfaces for m in meshes),
        tri_st=cat(st_parts, (0, 3, 2), np.float32), prim_st=tuple(m.st_name for m in meshes),
        tri_lightmap_uv=cat(lightmap_parts, (0, 3, 2), np.float32),
        prim_lightmap_uv=tuple(m.lightmap_uv_name for m in meshes),
        lights=read_lights(light_prims, xforms, timecode, origin),
        instances=scene_instances(instances, origin),
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


def _prim_to_world(builder: SceneBuilder, origin: np.ndarray) -> np.ndarray:
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
