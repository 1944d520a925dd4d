"""Re-open written sample stages, print a summary table and check metadata and triangle budgets."""

from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom, UsdLux, UsdShade

from instanced_props import VASES
from mesh_builder import newell_normal


def is_concave(points):
    """True if a planar polygon has a reflex corner."""
    normal = newell_normal(points)
    edges = np.roll(points, -1, axis=0) - points
    turns = np.cross(edges, np.roll(edges, -1, axis=0)) @ normal
    return bool((turns < -1e-9).any())


def mesh_stats(prim):
    """(polygons, triangles, ngons, concave polygons) of one mesh prim."""
    mesh = UsdGeom.Mesh(prim)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get())
    points = np.asarray(mesh.GetPointsAttr().Get(), dtype=float)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    concave = sum(is_concave(points[indices[s:s + n]]) for s, n in zip(starts, counts) if n > 4)
    if not UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]:
        raise AssertionError(f"{prim.GetPath()} has no bound material")
    return len(counts), int((counts - 2).sum()), int((counts > 4).sum()), concave


def stage_stats(path):
    """Summary numbers of one stage; PointInstancer prototypes are counted once, instances apart."""
    stage = Usd.Stage.Open(str(path))
    for key in ("upAxis", "metersPerUnit"):
        assert stage.HasAuthoredMetadata(key), f"{path.name}: {key} not authored"
    stats = dict(up_axis=stage.GetMetadata("upAxis"), meters_per_unit=stage.GetMetadata("metersPerUnit"),
                 default_prim=stage.GetDefaultPrim().GetPath().pathString, meshes=0, polygons=0, triangles=0,
                 ngons=0, concave=0, lights=0, instanced=0, largest_proto=(0, 0))

    def add_mesh(prim):
        """Add one mesh to the totals and return its triangle count."""
        polygons, triangles, ngons, concave = mesh_stats(prim)
        for key, value in zip(("meshes", "polygons", "triangles", "ngons", "concave"),
                              (1, polygons, triangles, ngons, concave)):
            stats[key] += value
        return triangles

    iterator = iter(Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()))
    for prim in iterator:
        if prim.IsA(UsdGeom.PointInstancer):
            iterator.PruneChildren()
            instancer = UsdGeom.PointInstancer(prim)
            proto_indices = np.asarray(instancer.GetProtoIndicesAttr().Get())
            for k, target in enumerate(instancer.GetPrototypesRel().GetTargets()):
                triangles = sum(add_mesh(p) for p in Usd.PrimRange(stage.GetPrimAtPath(target))
                                if p.IsA(UsdGeom.Mesh))
                copies = int((proto_indices == k).sum())
                stats["instanced"] += triangles * copies
                stats["largest_proto"] = max(stats["largest_proto"], (triangles, copies))
        elif prim.IsA(UsdGeom.Mesh):
            add_mesh(prim)
        stats["lights"] += prim.HasAPI(UsdLux.LightAPI)
    return stats


def verify(folder, budgets):
    """Re-open the stages of budgets ({file name: (low, high) triangles}) in `folder`, print a summary
    table and check metadata and triangle budgets."""
    header = (f"{'file':22} {'upAxis':>6} {'m/unit':>6} {'meshes':>6} {'polygons':>8} {'triangles':>9} "
              f"{'instanced':>9} {'ngons':>5} {'concave':>7} {'lights':>6} {'size':>8}")
    print(header)
    print("-" * len(header))
    stats = {}
    for name, (low, high) in budgets.items():
        path = Path(folder) / name
        s = stats[name] = stage_stats(path)
        print(f"{name:22} {s['up_axis']:>6} {s['meters_per_unit']:>6} {s['meshes']:>6} {s['polygons']:>8} "
              f"{s['triangles']:>9} {s['instanced']:>9} {s['ngons']:>5} {s['concave']:>7} {s['lights']:>6} "
              f"{path.stat().st_size / 1e6:>6.2f}MB")
        assert low <= s["triangles"] <= high, f"{name}: {s['triangles']} triangles, expected {low}..{high}"
        assert s["default_prim"] == "/World" and s["lights"] >= 1 and s["meshes"] >= 1, name
    assert stats["building.usda"]["concave"] >= 1, "building.usda needs a concave polygon"
    triangles, copies = stats["instanced_props.usda"]["largest_proto"]
    assert triangles >= 5000 and copies == VASES, "the vase prototype needs >= 5000 triangles and 60 copies"
