"""Reading a daylight stage back with pxr only: its triangles and materials, and usdbake's baked results at points.

Independent of usdbake's ``stages/`` (the Radiance side must not see the geometry through the code it checks):

``stage_triangles(stage)``
    Every visible mesh as world-space, fan-triangulated triangles, with its bound UsdPreviewSurface's
    ``diffuseColor`` and its glazing VLT (``bake:transmittance`` of the prim, else of its material, else
    1 - ``inputs:opacity``): a ``StageTriangles``.
``sample_baked(stage, primvar, points, normals)``
    The values of a baked primvar at sensor points: the faces that contain each point (their mean where a
    point lies on a shared edge or corner).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Gf, Usd, UsdGeom, UsdShade

TRANSMITTANCE_ATTR = "bake:transmittance"


# --------------------------------------------------------------------------- reading stages back (pxr only)


@dataclass(frozen=True)
class StageTriangles:
    """Every mesh of a stage as world-space triangles, with the materials the Radiance side needs."""

    triangles: np.ndarray
    """(T, 3, 3) float64 world positions (metres x metersPerUnit not applied: stages here are in metres)."""
    albedo: np.ndarray
    """(T, 3) float64 diffuseColor of the bound UsdPreviewSurface (0.5 grey when none)."""
    transmittance: np.ndarray
    """(T,) float64: ``bake:transmittance`` of the prim, else of its material, else 1 - opacity; 0 opaque."""
    tri_prim: np.ndarray
    """(T,) int64 index into ``prim_paths``."""
    tri_face: np.ndarray
    """(T,) int64 the authored face each triangle comes from (fan triangulation)."""
    prim_paths: tuple


def _surface_shader(prim: Usd.Prim) -> tuple[UsdShade.Material | None, UsdShade.Shader | None]:
    material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
    if not material:
        return None, None
    source = material.ComputeSurfaceSource()
    shader = source[0] if source and source[0] else None
    return material, shader


def _input(shader: UsdShade.Shader | None, name: str, default):
    if shader is None:
        return default
    value = shader.GetInput(name)
    got = value.Get() if value else None
    return default if got is None else got


def _fan(counts: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fan triangulation of polygons: (T, 3) point ids, (T,) face ids and (T, 3) face-vertex (corner) ids."""
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    per_face = np.maximum(counts - 2, 0)
    faces = np.repeat(np.arange(len(counts)), per_face)
    k = np.arange(len(faces)) - np.repeat(np.cumsum(per_face) - per_face, per_face)
    s = starts[faces]
    corners = np.stack([s, s + k + 1, s + k + 2], axis=1)
    return indices[corners], faces, corners


def _mesh_triangles(mesh: UsdGeom.Mesh, cache: UsdGeom.XformCache, time=Usd.TimeCode.Default()):
    """(T, 3, 3) world triangles, (T,) face ids, (T, 3) point ids and (T, 3) corner ids of a mesh."""
    points = np.asarray(mesh.GetPointsAttr().Get(time), np.float64).reshape(-1, 3)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(time), np.int64)
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(time), np.int64)
    matrix = np.asarray(cache.GetLocalToWorldTransform(mesh.GetPrim()), np.float64)  # row vectors: p' = p M
    world = points @ matrix[:3, :3] + matrix[3, :3]
    tri, face, corners = _fan(counts, indices)
    return world[tri], face, tri, corners


def stage_triangles(stage: Usd.Stage, time=Usd.TimeCode.Default()) -> StageTriangles:
    """Every visible UsdGeom.Mesh of ``stage`` as world triangles with its bound material's diffuseColor and
    glazing VLT (read with pxr only, independently of usdbake's stages/)."""
    cache = UsdGeom.XformCache(time)
    tris, albedo, trans, prim_ids, faces, paths = [], [], [], [], [], []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        if UsdGeom.Imageable(prim).ComputeVisibility(time) == UsdGeom.Tokens.invisible:
            continue
        mesh = UsdGeom.Mesh(prim)
        world, face, _, _ = _mesh_triangles(mesh, cache, time)
        material, shader = _surface_shader(prim)
        color = np.asarray(_input(shader, "diffuseColor", Gf.Vec3f(0.5, 0.5, 0.5)), np.float64)
        tau = 1.0 - float(_input(shader, "opacity", 1.0))
        for holder in (material.GetPrim() if material else None, prim):
            attr = holder.GetAttribute(TRANSMITTANCE_ATTR) if holder is not None else None
            if attr and attr.HasAuthoredValue():
                tau = float(attr.Get())
        paths.append(str(prim.GetPath()))
        tris.append(world)
        faces.append(face)
        albedo.append(np.tile(color, (len(world), 1)))
        trans.append(np.full(len(world), tau))
        prim_ids.append(np.full(len(world), len(paths) - 1))
    return StageTriangles(np.concatenate(tris), np.concatenate(albedo), np.concatenate(trans),
                          np.concatenate(prim_ids).astype(np.int64), np.concatenate(faces).astype(np.int64),
                          tuple(paths))


# --------------------------------------------------------------------------- usdbake's results at the sensors


def sample_baked(stage: "Usd.Stage | str | Path", primvar: str, points: np.ndarray, normals: np.ndarray, *,
                 prims=None, time=Usd.TimeCode.Default(), max_distance: float = 0.02,
                 min_facing: float = 0.5) -> np.ndarray:
    """(N, C) float64 values of a baked primvar at sensor points: the faces that contain each point.

    ``stage``: the baked stage (or its path); ``primvar``: e.g. 'bake:daylightIrradiance' (the
    'primvars:' prefix optional); ``points`` (N, 3), ``normals`` (N, 3) world. Each point is projected onto
    the plane of every triangle of the meshes carrying the primvar (of ``prims[i]``, its prim path, when
    given) that faces its way (n_tri . n >= ``min_facing``) and lies within ``max_distance`` metres along the
    normal; the triangles whose closed interior holds the projection at the smallest distance (ties: the
    faces sharing an edge or corner the point lies on) give their values' mean. ``uniform`` primvars give
    the face's value; ``vertex`` / ``varying`` / ``faceVarying`` ones barycentric interpolation; ``constant``
    the value. NaN where no face is found.
    """
    stage = Usd.Stage.Open(str(stage)) if not isinstance(stage, Usd.Stage) else stage
    name = primvar if primvar.startswith("primvars:") else f"primvars:{primvar}"
    points = np.asarray(points, np.float64).reshape(-1, 3)
    normals = np.asarray(normals, np.float64).reshape(-1, 3)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    cache = UsdGeom.XformCache(time)
    meshes = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh) or not prim.HasAttribute(name):
            continue
        pv = UsdGeom.Primvar(prim.GetAttribute(name))
        values = pv.ComputeFlattened(time)
        if values is None:
            continue
        values = np.asarray(values, np.float64)
        values = values.reshape(len(values), -1) if values.ndim else values.reshape(1, 1)
        world, face, tri, corners = _mesh_triangles(UsdGeom.Mesh(prim), cache, time)
        cross = np.cross(world[:, 1] - world[:, 0], world[:, 2] - world[:, 0])
        norm = np.linalg.norm(cross, axis=1)
        unit = cross / np.maximum(norm, 1e-300)[:, None]
        meshes.append((str(prim.GetPath()), world, unit, norm > 0, face, tri, corners, pv.GetInterpolation(), values))
    if not meshes:
        raise ValueError(f"no mesh of the stage carries {name}")
    channels = meshes[0][-1].shape[1]
    out = np.full((len(points), channels), np.nan)
    for i, (p, n) in enumerate(zip(points, normals)):
        best, hits = np.inf, []
        for path, world, tn, valid, face, tri, corners, interpolation, values in meshes:
            if prims is not None and prims[i] != path:
                continue
            a, b, c = world[:, 0], world[:, 1], world[:, 2]
            dist = np.einsum("ij,ij->i", p - a, tn)  # signed distance of p above each plane
            near = np.flatnonzero((tn @ n >= min_facing) & (np.abs(dist) <= max_distance) & valid)
            if not len(near):
                continue
            q = p - dist[near, None] * tn[near]
            w = _barycentric(q, a[near], b[near], c[near])
            tol = 1e-6
            inside = np.all(w >= -tol, axis=1)
            for k in np.flatnonzero(inside):
                d = abs(dist[near[k]])
                if d < best - 1e-6:
                    best, hits = d, []
                if d <= best + 1e-6:
                    hits.append(_value_at(interpolation, values, face[near[k]], tri[near[k]], corners[near[k]],
                                          w[k]))
        if hits:
            out[i] = np.mean(hits, axis=0)
    return out


def _barycentric(q: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(K, 3) barycentric weights of points q (K, 3) in triangles (a, b, c) (K, 3 each)."""
    e0, e1, e2 = b - a, c - a, q - a
    d00, d01, d11 = (e0 * e0).sum(1), (e0 * e1).sum(1), (e1 * e1).sum(1)
    d20, d21 = (e2 * e0).sum(1), (e2 * e1).sum(1)
    det = d00 * d11 - d01 * d01
    det = np.where(np.abs(det) > 0, det, 1.0)
    w1, w2 = (d11 * d20 - d01 * d21) / det, (d00 * d21 - d01 * d20) / det
    return np.stack([1.0 - w1 - w2, w1, w2], axis=1)


def _value_at(interpolation: str, values: np.ndarray, face: int, tri_points: np.ndarray, tri_corners: np.ndarray,
              w: np.ndarray) -> np.ndarray:
    """The primvar's value at barycentric weights ``w`` of one triangle of a face."""
    w = np.clip(w, 0.0, None)
    w = w / w.sum()
    if interpolation == UsdGeom.Tokens.uniform:
        return values[face]
    if interpolation in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        return w @ values[tri_points]
    if interpolation == UsdGeom.Tokens.faceVarying:
        return w @ values[tri_corners]
    return values[0]



def sample_lightmap(stage: "Usd.Stage | str | Path", channel: str, points: np.ndarray, normals: np.ndarray, *,
                    prims, time=Usd.TimeCode.Default()) -> np.ndarray:
    """(N, C) float64 values of lightmap ``channel`` (``bake:lightmap:<channel>:file`` and ``:uv`` on each mesh)
    at sensor points of the meshes ``prims`` (N,) names: the UVs interpolated there (``sample_baked`` of the
    mesh's lightmap UV primvar), then the page read bilinearly (texel centres at ((x + 0.5) / W, (y + 0.5) / H),
    v up, edges clamped), as a renderer's texture lookup would. NaN where the point's mesh has no lightmap."""
    from usdbake.stages.baked_data import read_lightmap_image

    stage = Usd.Stage.Open(str(stage)) if not isinstance(stage, Usd.Stage) else stage
    points = np.asarray(points, np.float64).reshape(-1, 3)
    prims = [str(p) for p in prims]
    prefix = f"bake:lightmap:{channel}"
    sources = {}
    for path in sorted(set(prims)):
        prim = stage.GetPrimAtPath(path)
        if prim and prim.HasAttribute(f"{prefix}:file"):
            asset = prim.GetAttribute(f"{prefix}:file").Get(time if not Usd.TimeCode(time).IsDefault()
                                                            else Usd.TimeCode.EarliestTime())
            sources[path] = (prim.GetAttribute(f"{prefix}:uv").Get(), asset.resolvedPath)
    uvs = np.full((len(points), 2), np.nan)
    for name in sorted({uv for uv, _ in sources.values()}):
        mine = [p if p in sources and sources[p][0] == name else "" for p in prims]
        if any(mine):
            found = sample_baked(stage, name, points, normals, prims=mine, time=time)
            uvs = np.where(np.isnan(uvs) & ~np.isnan(found), found, uvs)
    images = {file: read_lightmap_image(file) for _, file in sources.values()}
    channels = next(iter(images.values())).shape[2] if images else 1
    out = np.full((len(points), channels), np.nan)
    for i, path in enumerate(prims):
        if path not in sources or np.isnan(uvs[i]).any():
            continue
        image = images[sources[path][1]]
        height, width = image.shape[:2]
        x = np.clip(uvs[i, 0] * width - 0.5, 0, width - 1)
        y = np.clip(uvs[i, 1] * height - 0.5, 0, height - 1)
        x0, y0 = min(int(x), width - 2) if width > 1 else 0, min(int(y), height - 2) if height > 1 else 0
        fx, fy = x - x0, y - y0
        x1, y1 = min(x0 + 1, width - 1), min(y0 + 1, height - 1)
        out[i] = ((1 - fx) * (1 - fy) * image[y0, x0] + fx * (1 - fy) * image[y0, x1]
                  + (1 - fx) * fy * image[y1, x0] + fx * fy * image[y1, x1])
    return out
