"""The generated production-like city stage of the plan benchmark (`.usdc`, Y-up, metersPerUnit 0.01):
unwelded flat-shaded quad meshes (buildings, ground tiles) with authored faceVarying normals and st,
UsdPreviewSurface materials, native instancing and two PointInstancers; a sun and a dome light."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

TARGET_TRIANGLES = 270_000
"""The stage the plan benchmark measures; any other count keeps its density (the city's side scales)."""
STAGE_VERSION = 1
"""Bump when the generated stage changes (it is cached under benchmarks/cache by triangles and version)."""

CM = 100.0  # stage units per metre (metersPerUnit 0.01)

# ---------------------------------------------------------------------------
# Geometry: quads (Q, 4, 3), counter-clockwise seen from outside (USD's rightHanded default)


def grid_quads(origin, u, v, nu: int, nv: int) -> np.ndarray:
    """nu x nv quads tiling the parallelogram origin + [0,1] u + [0,1] v; their normal is u x v."""
    a = np.linspace(0.0, 1.0, nu + 1)
    b = np.linspace(0.0, 1.0, nv + 1)
    grid = np.asarray(origin, np.float64) + a[:, None, None] * np.asarray(u) + b[None, :, None] * np.asarray(v)
    return np.stack([grid[:-1, :-1], grid[1:, :-1], grid[1:, 1:], grid[:-1, 1:]], axis=2).reshape(-1, 4, 3)


def box_quads(lo, hi, n=(1, 1, 1), bottom: bool = False) -> np.ndarray:
    """The faces of the box [lo, hi], face i split in n (x, y, z) segments along its sides; no bottom face
    unless ``bottom`` (props stand on the ground)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    sx, sy, sz = hi - lo
    nx, ny, nz = n
    faces = [
        grid_quads((hi[0], lo[1], hi[2]), (0, 0, -sz), (0, sy, 0), nz, ny),   # +x
        grid_quads((lo[0], lo[1], lo[2]), (0, 0, sz), (0, sy, 0), nz, ny),    # -x
        grid_quads((lo[0], lo[1], hi[2]), (sx, 0, 0), (0, sy, 0), nx, ny),    # +z
        grid_quads((hi[0], lo[1], lo[2]), (-sx, 0, 0), (0, sy, 0), nx, ny),   # -z
        grid_quads((lo[0], hi[1], hi[2]), (sx, 0, 0), (0, 0, -sz), nx, nz),   # +y
    ]
    if bottom:
        faces.append(grid_quads((lo[0], lo[1], lo[2]), (sx, 0, 0), (0, 0, sz), nx, nz))  # -y
    return np.concatenate(faces)


def blob_quads(n: int, radius, center, rng, jitter: float = 0.0) -> np.ndarray:
    """A cube-sphere (n x n quads per cube face) of per-axis ``radius`` around ``center``; the corners
    pushed radially by up to ``jitter`` (a rock, a tree crown). Unwelded: every quad its own corners."""
    quads = box_quads((-1, -1, -1), (1, 1, 1), (n, n, n), bottom=True)
    directions = quads / np.linalg.norm(quads, axis=2, keepdims=True)
    if jitter:  # one radius per distinct corner position, so the unwelded quads still meet
        keys = np.round(directions.reshape(-1, 3), 6)
        _, inverse = np.unique(keys, axis=0, return_inverse=True)
        bumps = 1.0 + jitter * (rng.random(inverse.max() + 1) - 0.5)
        directions = directions * bumps[inverse.reshape(-1)].reshape(directions.shape[:2])[..., None]
    return directions * np.asarray(radius, np.float64) + np.asarray(center, np.float64)


def building_quads(width: float, depth: float, floors: int, columns_x: int, columns_z: int) -> np.ndarray:
    """A building: facades of one quad per window bay and floor (3.5 m floors), a roof of 2 x 2 quads."""
    height = floors * 3.5 * CM
    return box_quads((-width / 2, 0, -depth / 2), (width / 2, height, depth / 2), (columns_x, floors, columns_z))


def building_triangles(floors: int, columns_x: int, columns_z: int) -> int:
    return 2 * (2 * floors * (columns_x + columns_z) + columns_x * columns_z)


# ---------------------------------------------------------------------------
# The stage


def _materials(stage, root: str, specs: dict) -> dict:
    from pxr import Gf, Sdf, UsdGeom, UsdShade

    UsdGeom.Scope.Define(stage, root)
    looks = {}
    for name, (color, roughness) in specs.items():
        material = UsdShade.Material.Define(stage, f"{root}/{name}")
        shader = UsdShade.Shader.Define(stage, f"{root}/{name}/PreviewSurface")
        shader.CreateIdAttr("UsdPreviewSurface")
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
        shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
        material.CreateSurfaceOutput().ConnectToSource(shader.CreateOutput("surface", Sdf.ValueTypeNames.Token))
        looks[name] = material
    return looks


def _write_quads(stage, path: str, quads: np.ndarray, material, translate=None, rotate_y: float = 0.0):
    """An unwelded flat-shaded quad mesh as a DCC exports it: 4 points per face, faceVarying normals and
    st (1 m texture tiles), extent, no subdivision, a bound material."""
    from pxr import Gf, Sdf, UsdGeom, UsdShade, Vt

    quads = np.asarray(quads, np.float64)
    count = len(quads)
    normal = np.cross(quads[:, 1] - quads[:, 0], quads[:, 3] - quads[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    points = quads.reshape(-1, 3).astype(np.float32)
    # st: the quad's corners in its own plane, in metres
    u_axis = quads[:, 1] - quads[:, 0]
    u_axis /= np.maximum(np.linalg.norm(u_axis, axis=1, keepdims=True), 1e-12)
    v_axis = np.cross(normal, u_axis)
    local = quads - quads[:, :1]
    st = np.stack([(local * u_axis[:, None]).sum(2), (local * v_axis[:, None]).sum(2)], axis=2) / CM
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(count, 4, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.arange(4 * count, dtype=np.int32)))
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([points.min(0), points.max(0)])))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.repeat(normal, 4, axis=0).astype(np.float32)))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
                                            ).Set(Vt.Vec2fArray.FromNumpy(st.reshape(-1, 2).astype(np.float32)))
    if translate is not None:
        mesh.AddTranslateOp().Set(Gf.Vec3d(*map(float, translate)))
    if rotate_y:
        mesh.AddRotateYOp().Set(float(rotate_y))
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    return mesh


def _prop_parts(rng) -> dict[str, list[tuple[str, np.ndarray, str]]]:
    """The native-instancing prototypes: {name: [(mesh name, quads, material name)]}, in cm."""
    slats = np.concatenate([box_quads((-90, 42, z0), (90, 46, z0 + 15), (6, 1, 1)) for z0 in (-25, -7.5, 10)]
                           + [box_quads((-90, y0, 26), (90, y0 + 12, 30), (6, 1, 1)) for y0 in (60, 80)])
    frame = np.concatenate([box_quads((x0, 0, -22), (x0 + 6, 42, 22), (1, 3, 2)) for x0 in (-80, 74)]
                           + [box_quads((x0, 42, 30), (x0 + 6, 95, 34), (1, 3, 1)) for x0 in (-80, 74)])
    pole = box_quads((-6, 0, -6), (6, 450, 6), (2, 12, 2))
    head = blob_quads(3, (35, 15, 35), (0, 465, 0), rng)
    bin_body = box_quads((-30, 0, -30), (30, 95, 30), (3, 4, 3))
    return {"Bench": [("Slats", slats, "Wood"), ("Frame", frame, "Iron")],
            "Lamp": [("Pole", pole, "Iron"), ("Head", head, "Glass")],
            "Kiosk": [("Body", bin_body, "Paint"), ("Roof", blob_quads(2, (45, 12, 45), (0, 100, 0), rng),
                                                     "Iron")]}


def _tree_parts(rng, crown_n: int, trunk_segments: int) -> list[tuple[str, np.ndarray, str]]:
    trunk = box_quads((-15, 0, -15), (15, 400, 15), (1, trunk_segments, 1))
    crown = blob_quads(crown_n, (260, 320, 260), (0, 650, 0), rng, jitter=0.25)
    return [("Trunk", trunk, "Bark"), ("Crown", crown, "Leaves")]


def _triangles(parts) -> int:
    return 2 * sum(len(quads) for _, quads, _ in parts)


def build_stage(path: Path, triangles: int, seed: int = 0) -> dict:
    """Write the city stage of about ``triangles`` triangles (after flattening instances) to ``path``;
    the count of each kind of content."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, Vt

    rng = np.random.default_rng(seed)  # fixed: the same stage on every machine
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    looks = _materials(stage, "/World/Looks", {
        "Asphalt": ((0.18, 0.18, 0.19), 0.9), "Concrete": ((0.55, 0.54, 0.5), 0.8),
        "Brick": ((0.55, 0.3, 0.22), 0.85), "Plaster": ((0.8, 0.76, 0.68), 0.7),
        "Bark": ((0.3, 0.22, 0.15), 0.9), "Leaves": ((0.2, 0.4, 0.15), 0.8), "Rock": ((0.45, 0.44, 0.42), 0.9)})
    side = 40000.0 * np.sqrt(triangles / TARGET_TRIANGLES)  # the city's side in cm: same density at any size
    counts = {}

    # ground: tiles of 20 x 20 quads (~5% of the triangles)
    tiles = max(1, int(round(np.sqrt(0.05 * triangles / 800))))
    UsdGeom.Xform.Define(stage, "/World/Ground")
    step = side / tiles
    for i in range(tiles):
        for j in range(tiles):
            origin = (-side / 2 + i * step, 0.0, -side / 2 + (j + 1) * step)
            _write_quads(stage, f"/World/Ground/Tile_{i}_{j}", grid_quads(origin, (step, 0, 0), (0, 0, -step), 20, 20),
                         looks["Asphalt"])
    counts["ground_triangles"] = tiles * tiles * 800

    # native instancing: prototypes under the class /Library, instanceable internal references (~15%)
    stage.CreateClassPrim("/Library")
    props = _prop_parts(rng)
    prop_triangles = {}
    for name, parts in props.items():
        UsdGeom.Xform.Define(stage, f"/Library/{name}")
        prop_looks = _materials(stage, f"/Library/{name}/Looks", {
            "Wood": ((0.5, 0.34, 0.2), 0.75), "Iron": ((0.15, 0.15, 0.16), 0.5),
            "Glass": ((0.9, 0.9, 0.85), 0.1), "Paint": ((0.1, 0.35, 0.2), 0.6)})
        for mesh_name, quads, look in parts:
            _write_quads(stage, f"/Library/{name}/{mesh_name}", quads, prop_looks[look])
        prop_triangles[name] = _triangles(parts)
    mean_prop = float(np.mean(list(prop_triangles.values())))
    native = max(3, int(round(0.15 * triangles / mean_prop)))
    UsdGeom.Xform.Define(stage, "/World/Props")
    kinds = list(props)
    native_triangles = 0
    for k in range(native):
        name = kinds[k % len(kinds)]
        prim = UsdGeom.Xform.Define(stage, f"/World/Props/{name}_{k:04d}")
        x, z = rng.uniform(-side / 2, side / 2, 2)
        prim.AddTranslateOp().Set(Gf.Vec3d(float(x), 0.0, float(z)))
        prim.AddRotateYOp().Set(float(rng.uniform(0, 360)))
        prim.GetPrim().GetReferences().AddInternalReference(Sdf.Path(f"/Library/{name}"))
        prim.GetPrim().SetInstanceable(True)
        native_triangles += prop_triangles[name]
    counts["native_instances"] = native
    counts["native_instance_triangles"] = native_triangles

    # PointInstancers with their prototypes under the instancer: trees (~18%) and rocks (~5%)
    instanced_triangles, point_instances = 0, 0
    for instancer_name, share, prototypes in (
            ("Trees", 0.18, {"TreeA": _tree_parts(rng, 6, 6), "TreeB": _tree_parts(rng, 5, 4)}),
            ("Rocks", 0.05, {f"Rock{r}": [("Rock", blob_quads(3, tuple(rng.uniform(40, 120, 3)), (0, 20, 0), rng,
                                                              jitter=0.4), "Rock")] for r in range(3)})):
        base = f"/World/{instancer_name}"
        instancer = UsdGeom.PointInstancer.Define(stage, base)
        UsdGeom.Scope.Define(stage, f"{base}/Prototypes")
        targets, proto_triangles = [], []
        for proto, parts in prototypes.items():
            root = UsdGeom.Xform.Define(stage, f"{base}/Prototypes/{proto}")
            for mesh_name, quads, look in parts:
                _write_quads(stage, f"{base}/Prototypes/{proto}/{mesh_name}", quads, looks[look])
            targets.append(root.GetPath())
            proto_triangles.append(_triangles(parts))
        n = max(2, int(round(share * triangles / np.mean(proto_triangles))))
        indices = rng.integers(0, len(targets), n).astype(np.int32)
        positions = np.c_[rng.uniform(-side / 2, side / 2, n), np.zeros(n), rng.uniform(-side / 2, side / 2, n)]
        angles = rng.uniform(0, np.pi, n)  # half-angles of a rotation about +Y
        orientations = np.c_[np.cos(angles), np.zeros(n), np.sin(angles), np.zeros(n)]
        instancer.CreatePrototypesRel().SetTargets(targets)
        instancer.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(indices))
        instancer.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(positions.astype(np.float32)))
        instancer.CreateOrientationsAttr(Vt.QuathArray([Gf.Quath(*map(float, q)) for q in orientations]))
        instancer.CreateScalesAttr(Vt.Vec3fArray.FromNumpy(np.repeat(rng.uniform(0.7, 1.3, (n, 1)), 3, axis=1)
                                                          .astype(np.float32)))
        instanced_triangles += int(np.asarray(proto_triangles)[indices].sum())
        point_instances += n
    counts["point_instances"] = point_instances
    counts["point_instance_triangles"] = instanced_triangles

    # buildings fill the rest of the budget, on a jittered grid of lots
    budget = triangles - counts["ground_triangles"] - native_triangles - instanced_triangles
    UsdGeom.Xform.Define(stage, "/World/Buildings")
    building_total, b = 0, 0
    while building_total < budget:
        width, depth = rng.uniform(8, 30, 2) * CM
        floors = int(rng.integers(3, 16))
        cx, cz = max(1, int(width / (3 * CM))), max(1, int(depth / (3 * CM)))
        tris = building_triangles(floors, cx, cz)
        _write_quads(stage, f"/World/Buildings/Building_{b:04d}", building_quads(width, depth, floors, cx, cz),
                     looks[("Concrete", "Brick", "Plaster")[b % 3]],
                     translate=(rng.uniform(-side / 2, side / 2), 0.0, rng.uniform(-side / 2, side / 2)),
                     rotate_y=float(rng.choice([0.0, 90.0, rng.uniform(0, 360)])))
        building_total += tris
        b += 1
    counts["buildings"] = b
    counts["building_triangles"] = building_total

    UsdGeom.Scope.Define(stage, "/World/Lights")
    sun = UsdLux.DistantLight.Define(stage, "/World/Lights/Sun")
    sun.CreateIntensityAttr(50000.0)
    sun.CreateAngleAttr(0.53)
    sun.AddRotateXYZOp().Set(Gf.Vec3f(-50.0, 30.0, 0.0))
    UsdLux.DomeLight.Define(stage, "/World/Lights/Sky").CreateIntensityAttr(0.3)
    stage.GetRootLayer().Save()
    counts["triangles"] = (counts["ground_triangles"] + native_triangles + instanced_triangles + building_total)
    counts["mesh_prims_authored"] = sum(1 for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)) + sum(
        len(parts) for parts in props.values())
    return counts


def cached_stage(triangles: int) -> Path:
    """The generated stage of ``triangles``, built once under benchmarks/cache."""
    from . import harness

    path = harness.CACHE / f"plan_city_{triangles}_v{STAGE_VERSION}.usdc"
    if not path.exists():
        harness.CACHE.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f"{path.stem}.{os.getpid()}.partial.usdc")
        try:
            build_stage(partial, triangles)
            os.replace(partial, path)
        finally:
            if partial.exists():
                partial.unlink()
    return path
