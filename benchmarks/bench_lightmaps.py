"""AO lightmaps (the texture target) on the furnished room: accuracy against Embree, seams, coverage, untouched
meshes, throughput, and time against error beside Blender's Cycles baking the same texels."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from . import harness

NAME = "lightmaps"
DESCRIPTION = (
    "ambient_occlusion's texture target on the furnished daylight room (issue 29's, Z-up metres, open windows; "
    "its ground and exterior skins marked `bake:skip`: they occlude but get no texels; the floor given a planar "
    "faceVarying `st`, every other mesh charted by xatlas). Accuracy: 1000 random texels whose centre lies inside "
    "their triangle, against Embree (embreex) tracing 4096 float64 cosine-weighted rays per texel at the texel's "
    "world point and shading normal (origin: the point 1e-5 of the scene diagonal along the face normal). Noise: half "
    "the mean squared difference of two seeds at the same texels, plus the reference's own binomial variance. Seams: texel pairs of different charts whose "
    "world points lie within a quarter texel and whose normals agree (cos > 0.99). Cycles: Blender 5's Cycles "
    "AO bake (CPU, 2 threads, Sobol sampling, the same mesh, UVs, corner normals and texel count, unlimited "
    "distance), its bake call only; ours: rasterization, texel points and the AO pass (the layout is given to "
    "both). Error of both against the Embree reference at the same texels. The accuracy figure again on the plan "
    "benchmark's city, built like a user's stage (270k triangles, Y-up centimetres, faceVarying normals and st "
    "in 1 m tiles: every mesh charted by xatlas), at 1 texel per metre.")
ROOM_CELL = 0.1
THROUGHPUT_CELL = 0.035
"""Shell cell (m) of the throughput room (368k triangles: walls, floor and ceiling in 3.5 cm cells)."""
REFERENCE_RAYS = 4096
DEFAULT_SAMPLES = 256
TEXELS_CHECKED = 1000


def room_scene(cell: float):
    """(stage, scene): the furnished room with the bench's UVs and skips (module DESCRIPTION)."""
    from pxr import Sdf, UsdGeom, Vt

    from usdbake.benchmarks.furnished_daylight_room import room_stage
    from usdbake.stages.extract import extract_scene

    stage = room_stage(cell=cell, glazed=False)
    for path in ("/World/Ground", "/World/Room/Exterior"):
        stage.GetPrimAtPath(path).CreateAttribute("bake:skip", Sdf.ValueTypeNames.Bool).Set(True)
    floor = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Room/Floor"))
    points = np.asarray(floor.GetPointsAttr().Get(), np.float64)
    indices = np.asarray(floor.GetFaceVertexIndicesAttr().Get(), np.int64)
    lo, hi = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    uv = (points[indices, :2] - lo) / (hi - lo).max()
    primvar = UsdGeom.PrimvarsAPI(floor).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                       UsdGeom.Tokens.faceVarying)
    primvar.Set(Vt.Vec2fArray.FromNumpy(uv.astype(np.float32)))
    return stage, extract_scene(stage)


def prepared(scene, density: float, max_size: int = 4096):
    """(layout, pages, seconds of layout, seconds of texel rasterization and points)."""
    from usdbake.geometry.mesh import receiver_prims, vertex_normals
    from usdbake.kernels.lightmap_bake import texel_samples
    from usdbake.kernels.lightmap_layout import lightmap_layout

    started = time.perf_counter()
    layout = lightmap_layout(scene, receiver_prims(scene), density=density, max_size=max_size)
    layout_seconds = time.perf_counter() - started
    started = time.perf_counter()
    normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
    pages = texel_samples(scene, layout, normals)
    return layout, pages, layout_seconds, time.perf_counter() - started


def texel_ao(tracer, page, samples: int, seed: int) -> tuple[np.ndarray, float]:
    from usdbake.processors.occlusion.ambient_occlusion import texel_ao_chunk

    started = time.perf_counter()
    values = texel_ao_chunk(tracer, 0, page.points, page.normals, page.corners, samples=samples,
                            max_distance=math.inf, seed=seed)
    return values, time.perf_counter() - started


def interior(page) -> np.ndarray:
    """Indices of the page's texels whose centre lies inside their triangle, away from its edges (the point
    is the centre itself, and the ray origin is the point pushed along the face normal)."""
    corners = page.corners.astype(np.float64)
    ab, ac = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    rel = page.points.astype(np.float64) - corners[:, 0]
    d00, d01, d11 = (ab * ab).sum(1), (ab * ac).sum(1), (ac * ac).sum(1)
    d20, d21 = (rel * ab).sum(1), (rel * ac).sum(1)
    denominator = d00 * d11 - d01 * d01
    with np.errstate(invalid="ignore", divide="ignore"):
        v = (d11 * d20 - d01 * d21) / denominator
        w = (d00 * d21 - d01 * d20) / denominator
    smallest = np.minimum(np.minimum(1 - v - w, v), w)
    return np.flatnonzero(np.nan_to_num(smallest, nan=-1.0) > 0.02)


def comparison_noise(noise: float, reference: np.ndarray) -> float:
    """The RMS a difference from the reference shows from sampling alone: our texels' noise (two seeds) and the
    reference's own, a mean of REFERENCE_RAYS independent Bernoulli rays (variance AO (1 - AO) / rays, which is
    not small beside our stratified estimate where AO is near 1/2: 0.0078 at 4096 rays)."""
    return math.sqrt(noise ** 2 + float(np.mean(reference * (1.0 - reference))) / REFERENCE_RAYS)


def embree_ao(scene, points: np.ndarray, normals: np.ndarray, face_normals: np.ndarray, rays: int,
              seed: int, up: np.ndarray | None = None) -> np.ndarray:
    """AO at points: the share of ``rays`` float64 cosine-weighted directions about each normal that Embree
    finds unoccluded (origin: point + 1e-5 diagonal * face normal). Independent of usdbake's ray core and
    sampling. With ``up``, only unoccluded directions above the horizon count: the sky exposure
    (1/pi) integral over the sky of V cos, as sky_visibility defines it."""
    from .bench_tracer import embree_scene

    embree = embree_scene(scene.points, scene.tri_vertices)
    offset = 1e-5 * scene.diagonal
    rng = np.random.default_rng(seed)
    out = np.zeros(len(points))
    for i, (point, normal, face) in enumerate(zip(points.astype(np.float64), normals.astype(np.float64),
                                                  face_normals.astype(np.float64))):
        helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        t1 = np.cross(normal, helper)
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(normal, t1)
        r, phi = np.sqrt(rng.random(rays)), 2 * np.pi * rng.random(rays)
        local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1 - r * r))], axis=1)
        directions = local[:, :1] * t1 + local[:, 1:2] * t2 + local[:, 2:] * normal
        origins = np.repeat((point + offset * face)[None], rays, axis=0)
        hit = embree.run(origins.astype(np.float32), directions.astype(np.float32), query="OCCLUDED")
        escaped = hit == -1
        if up is not None:
            escaped &= directions @ np.asarray(up, np.float64) > 0.0
        out[i] = float(escaped.mean())
    return out


def seam_pairs(page, density: float) -> np.ndarray:
    """(M, 2) texel indices of pairs on different charts at one world point (module DESCRIPTION)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(page.points.astype(np.float64))
    pairs = tree.query_pairs(0.25 / density, output_type="ndarray")
    if not len(pairs):
        return pairs
    cos = (page.normals[pairs[:, 0]] * page.normals[pairs[:, 1]]).sum(1)
    texel_distance = np.hypot(page.texel[pairs[:, 0]] % page.width - page.texel[pairs[:, 1]] % page.width,
                              page.texel[pairs[:, 0]] // page.width - page.texel[pairs[:, 1]] // page.width)
    return pairs[(cos > 0.99) & (texel_distance > 2.5)]  # adjacent texels of one chart are not a seam


def uncovered_inside(layout, page) -> int:
    """Texels whose centre lies inside a triangle's UVs (float64, written here) but that were not baked."""
    tris = np.flatnonzero(layout.tri_page == page.page)
    covered = np.zeros(page.width * page.height, bool)
    covered[page.texel] = True
    missing = 0
    scale = np.array([page.width, page.height], np.float64)
    for tri in layout.tri_uv[tris].astype(np.float64) * scale:
        lo, hi = np.floor(tri.min(axis=0)).astype(int), np.ceil(tri.max(axis=0)).astype(int)
        xs, ys = np.meshgrid(np.arange(max(lo[0], 0), min(hi[0], page.width)),
                             np.arange(max(lo[1], 0), min(hi[1], page.height)))
        centres = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], axis=1)
        a, b, c = tri
        def edge(u, v):
            return (v[0] - u[0]) * (centres[:, 1] - u[1]) - (v[1] - u[1]) * (centres[:, 0] - u[0])
        e1, e2, e3 = edge(a, b), edge(b, c), edge(c, a)
        inside = ((e1 > 0) & (e2 > 0) & (e3 > 0)) | ((e1 < 0) & (e2 < 0) & (e3 < 0))
        index = ys.ravel()[inside] * page.width + xs.ravel()[inside]
        missing += int((~covered[index]).sum())
    return missing


def composed_meshes(stage) -> dict:
    """{(prim, attribute): bytes} of every mesh's composed topology, points, st and normals."""
    from pxr import UsdGeom

    return {(str(prim.GetPath()), attr.GetName()): np.asarray(attr.Get()).tobytes()
            for prim in stage.Traverse() if prim.IsA(UsdGeom.Mesh) for attr in prim.GetAttributes()
            if attr.GetName() in ("points", "faceVertexCounts", "faceVertexIndices", "primvars:st", "normals")
            and attr.HasValue()}


def meshes_unchanged(stage, folder: Path) -> bool:
    """Bake the texture target through the hook and compare every mesh's composed geometry before/after."""
    import usdbake

    before = composed_meshes(stage)
    usdbake.bake(stage, "ambient_occlusion", {"ambient_occlusion": {"samples": 16}}, target="texture",
                 texture_dir=str(folder))
    return composed_meshes(stage) == before


def has_embree() -> bool:
    return importlib.util.find_spec("embreex") is not None


def blender_python() -> str | None:
    candidate = os.environ.get("USDBAKE_BLENDER_PYTHON", "/work/bpyvenv/bin/python")
    return candidate if Path(candidate).exists() else None


BLENDER_IMPORT = r"""
import json, sys
import bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.wm.usd_import(filepath=sys.argv[1])
floor = bpy.data.objects["Floor"]
uv = floor.data.uv_layers.get("st")
images = [node.image.filepath for mat in bpy.data.materials if mat.node_tree
          for node in mat.node_tree.nodes if node.bl_idname == "ShaderNodeTexImage" and node.image]
print("RESULT", json.dumps({"uvs": [list(loop.uv) for loop in uv.data] if uv else [], "images": images}))
"""


def blender_import(python: str) -> dict:
    """Bake a floor beside a wall into an AO texture, import the output in Blender (its USD importer,
    headless) and check what arrives: the floor's UVs as written (1/0), the AO texture in a material (1/0)."""
    from pxr import Sdf, Usd, UsdGeom, UsdShade

    from usdbake.cli.main import main

    with tempfile.TemporaryDirectory() as folder:
        stage = Usd.Stage.CreateNew(str(Path(folder) / "in.usda"))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        floor = UsdGeom.Mesh.Define(stage, "/World/Floor")
        floor.CreatePointsAttr([(0.25, 0, 0), (0.25, 0, 1), (1.25, 0, 1), (1.25, 0, 0)])
        floor.CreateFaceVertexCountsAttr([4])
        floor.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        written = [(0, 0), (0, 1), (1, 1), (1, 0)]
        UsdGeom.PrimvarsAPI(floor).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                 UsdGeom.Tokens.faceVarying).Set(written)
        wall = UsdGeom.Mesh.Define(stage, "/World/Wall")
        wall.CreatePointsAttr([(0, 0, -5), (0, 5, -5), (0, 5, 5), (0, 0, 5)])
        wall.CreateFaceVertexCountsAttr([4])
        wall.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        material = UsdShade.Material.Define(stage, "/World/Looks/Floor")
        surface = UsdShade.Shader.Define(stage, "/World/Looks/Floor/Surface")
        surface.CreateIdAttr("UsdPreviewSurface")
        material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
        UsdShade.MaterialBindingAPI.Apply(floor.GetPrim()).Bind(material)
        stage.Save()
        out = Path(folder) / "out.usda"
        main(["bake", str(Path(folder) / "in.usda"), "-o", str(out), "--target", "texture", "--set",
              "ambient_occlusion.samples=16", "--cache", str(Path(folder) / "cache")])
        baked = Usd.Stage.Open(str(out))
        ao_file = baked.GetPrimAtPath("/World/Floor").GetAttribute("bake:lightmap:ao:file").Get().resolvedPath
        run = subprocess.run([python, "-c", BLENDER_IMPORT, str(out)], capture_output=True, text=True)
    line = next((text for text in run.stdout.splitlines() if text.startswith("RESULT ")), None)
    if line is None:
        return {}
    found = json.loads(line[len("RESULT "):])
    uvs_as_written = sorted(map(tuple, np.round(found["uvs"], 5).tolist())) == sorted(map(tuple, np.asarray(
        written, float).tolist())) and len(found["uvs"]) == 4
    connected = any(Path(image).name == Path(ao_file).name for image in found["images"])
    return {"blender_uvs_as_written": int(uvs_as_written), "blender_ao_texture_connected": int(connected)}


def cycles_bake(python: str, scene, layout, page, vertex_normals: np.ndarray, samples: int,
                folder: Path) -> tuple[np.ndarray, float]:
    """Cycles' AO of the page's triangles (cycles_ao.py in Blender's venv): (H, W) values, bake seconds."""
    tris = np.flatnonzero(layout.tri_page == page.page)
    others = np.setdiff1d(np.arange(scene.num_triangles), tris)
    request = folder / "cycles_in.npz"
    np.savez(request, positions=scene.points, triangles=scene.tri_vertices[tris], uvs=layout.tri_uv[tris],
             normals=vertex_normals[scene.tri_vertices[tris]], smooth=1, width=page.width, height=page.height,
             samples=samples, margin=0, threads=2, occluder_positions=scene.points,
             occluder_triangles=scene.tri_vertices[others])
    answer = folder / "cycles_out.npz"
    subprocess.run([python, str(Path(__file__).with_name("cycles_ao.py")), str(request), str(answer)], check=True,
                   capture_output=True)
    with np.load(answer) as data:
        return data["ao"], float(data["bake_seconds"])


def denoised_rows(tracer, scene, page, chosen: np.ndarray, reference: np.ndarray, raster_seconds: float
                  ) -> list[dict]:
    """The texture target with ``denoise`` (Intel Open Image Denoise through pyoidn) at a few ray counts: its time
    includes the denoiser; rows are skipped without pyoidn."""
    from usdbake.kernels.lightmap_bake import page_image

    if importlib.util.find_spec("pyoidn") is None:
        return []
    rows = []
    meshes = scene.tri_prim[page.triangle]
    page_image(page, np.ones(len(page.texel)), 16, 1.0, denoise_meshes=meshes)  # load the denoiser's weights
    for samples in (4, 16, 64):
        values, seconds = texel_ao(tracer, page, samples, 0)
        started = time.perf_counter()
        image = page_image(page, values, 16, 1.0, denoise_meshes=meshes)[:, :, 0].reshape(-1)
        seconds += time.perf_counter() - started
        error = math.sqrt(np.mean((image[page.texel[chosen]] - reference) ** 2))
        rows.append({"label": f"usdbake+oidn 1024 {samples}", "baker": "usdbake+oidn", "size": 1024,
                     "samples": samples, "seconds": seconds + raster_seconds, "error": error,
                     "texels": len(page.texel), "mtexels_per_s": len(page.texel) / (seconds + raster_seconds) / 1e6,
                     "default": False})
    return rows


def error_at_equal_time(curve: list[dict], rows: list[dict]) -> float:
    """The largest ratio of a row's error to ``curve``'s error at the same time (log-log interpolated), over the
    rows whose time the curve brackets; nan when none is."""
    seconds = np.log([row["seconds"] for row in curve])
    errors = np.log([row["error"] for row in curve])
    order = np.argsort(seconds)
    ratios = [row["error"] / math.exp(np.interp(math.log(row["seconds"]), seconds[order], errors[order]))
              for row in rows if seconds.min() <= math.log(row["seconds"]) <= seconds.max()]
    return float(max(ratios)) if ratios else math.nan


def equal_error_speedup(ours: list[dict], theirs: list[dict]) -> float:
    """Cycles' time / ours at Cycles' error, log-log interpolated on our curve, at the Cycles point whose error
    our curve brackets with the smallest ratio (the least favourable for us); nan when none is bracketed."""
    errors = np.log([row["error"] for row in ours])
    seconds = np.log([row["seconds"] for row in ours])
    order = np.argsort(errors)
    ratios = []
    for row in theirs:
        e = math.log(row["error"])
        if errors.min() <= e <= errors.max():
            ratios.append(row["seconds"] / math.exp(np.interp(e, errors[order], seconds[order])))
    return float(min(ratios)) if ratios else math.nan


def run(quick: bool = False) -> dict:
    from usdbake.geometry.mesh import vertex_normals
    from usdbake.kernels.tracer import Tracer

    stage, scene = room_scene(ROOM_CELL)
    tracer = Tracer.from_scene(scene)
    normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
    density = 8.0 if quick else 32.0  # the quick sweep: a sixteenth of the texels
    layout, pages, layout_s, raster_s = prepared(scene, density)
    page = max(pages, key=lambda p: len(p.texel))
    texel_ao(tracer, pages[0], 4, 0)  # compile outside the timing
    ao, _ = texel_ao(tracer, page, DEFAULT_SAMPLES, 0)
    ao_other, _ = texel_ao(tracer, page, DEFAULT_SAMPLES, 1)

    rng = np.random.default_rng(31)
    pairs = seam_pairs(page, density)
    seam_rms = math.sqrt(np.mean((ao[pairs[:, 0]] - ao[pairs[:, 1]]) ** 2)) if len(pairs) else math.nan
    seam_noise = math.sqrt(np.mean((ao[pairs].ravel() - ao_other[pairs].ravel()) ** 2) / 2) if len(pairs) else math.nan
    figures = {
        "triangles": scene.num_triangles, "texels_per_m": density, "pages": len(pages),
        "texels": int(sum(len(p.texel) for p in pages)),
        "layout_seconds": round(layout_s, 3), "raster_seconds": round(raster_s, 3),
        "seam_pairs": int(len(pairs)),
        "uncovered_texels_inside_charts": int(sum(uncovered_inside(layout, p) for p in pages)),
        "split_faces": int(sum(m.split_faces for m in layout.meshes)),
    }
    if len(pairs):
        figures["seam_rms_over_pair_noise"] = round(seam_rms / (math.sqrt(2) * seam_noise), 3)
    rows: list[dict] = []
    cycles_rows: list[dict] = []
    if not has_embree():  # the independent reference is a bench extra (".[bench]"); the quick sweep runs without
        return harness.result(NAME, description=DESCRIPTION, settings={"embree": False}, points=rows,
                              figures=figures, knob="rays per texel")
    candidates = interior(page)
    chosen = rng.choice(candidates, min(TEXELS_CHECKED, len(candidates)), replace=False)
    reference = harness.cached_reference(
        "lightmap_ao_room", {"rays": REFERENCE_RAYS, "texels": len(chosen), "cell": ROOM_CELL, "seed": 31,
                             "density": density, "version": 2},
        lambda: {"ao": embree_ao(scene, page.points[chosen], page.normals[chosen],
                                 scene.tri_normals[page.triangle[chosen]], REFERENCE_RAYS, seed=5)})["ao"]
    noise = math.sqrt(np.mean((ao[chosen] - ao_other[chosen]) ** 2) / 2)
    rms = math.sqrt(np.mean((ao[chosen] - reference) ** 2))
    figures.update({"rms_vs_embree_at_256": round(rms, 5), "noise_at_256": round(noise, 5),
                    "rms_over_noise": round(rms / comparison_noise(noise, reference), 3)})
    if quick:
        return harness.result(NAME, description=DESCRIPTION, settings={"embree": True}, points=rows,
                              figures=figures, knob="rays per texel")
    with tempfile.TemporaryDirectory() as folder:
        figures["meshes_identical"] = int(meshes_unchanged(stage, Path(folder)))
    figures.update(city_accuracy())
    python = blender_python()
    if python is not None:
        figures.update(blender_import(python))
    for size in (1024, 4096):
        density = 32.0 * size / max(layout.page_sizes[page.page])
        size_layout, size_pages, _, size_raster = prepared(scene, density, max_size=size)
        size_page = max(size_pages, key=lambda p: len(p.texel))
        chosen_here = rng.choice(interior(size_page), min(TEXELS_CHECKED, len(size_page.texel)), replace=False)
        reference_here = harness.cached_reference(
            f"lightmap_ao_room_{size}", {"rays": REFERENCE_RAYS, "texels": len(chosen_here), "cell": ROOM_CELL,
                                         "seed": 31, "size": size, "pages": len(size_pages), "version": 2},
            lambda: {"ao": embree_ao(scene, size_page.points[chosen_here], size_page.normals[chosen_here],
                                     scene.tri_normals[size_page.triangle[chosen_here]], REFERENCE_RAYS, seed=6),
                     "texel": size_page.texel[chosen_here]})
        for samples in ([4, 16, 64] if size > 1024 else [4, 16, 64, 256]):
            values, seconds = texel_ao(tracer, size_page, samples, 0)
            error = math.sqrt(np.mean((values[chosen_here] - reference_here["ao"]) ** 2))
            rows.append({"label": f"usdbake {size} {samples}", "baker": "usdbake", "size": size, "samples": samples,
                         "seconds": seconds + size_raster, "error": error, "texels": len(size_page.texel),
                         "mtexels_per_s": len(size_page.texel) / (seconds + size_raster) / 1e6,
                         "default": samples == DEFAULT_SAMPLES and size == 1024})
        if size == 1024:
            rows += denoised_rows(tracer, scene, size_page, chosen_here, reference_here["ao"], size_raster)
        if python is not None:
            for samples in ([4, 16, 64] if size > 1024 else [4, 16, 64, 256]):
                def bake(samples=samples):
                    with tempfile.TemporaryDirectory() as folder:
                        image, seconds = cycles_bake(python, scene, size_layout, size_page, normals, samples,
                                                     Path(folder))
                    return {"ao": image.reshape(-1)[reference_here["texel"]], "seconds": np.array(seconds)}
                # Cycles' run is kept like a reference (its bake time included): a rerun of this bench on the
                # same scene and machine reuses it
                cycles = harness.cached_reference(f"lightmap_cycles_{size}_{samples}", {
                    "size": size, "samples": samples, "cell": ROOM_CELL, "texels": len(size_page.texel),
                    "version": 1}, bake)
                picked, seconds = cycles["ao"], float(cycles["seconds"])
                error = math.sqrt(np.mean((picked - reference_here["ao"]) ** 2))
                cycles_rows.append({"label": f"cycles {size} {samples}", "baker": "cycles", "size": size,
                                    "samples": samples, "seconds": seconds, "error": error,
                                    "texels": len(size_page.texel),
                                    "mtexels_per_s": len(size_page.texel) / seconds / 1e6, "default": False})
            figures[f"speedup_vs_cycles_at_equal_error_{size}"] = round(equal_error_speedup(
                [r for r in rows if r["size"] == size and r["baker"] == "usdbake"],
                [r for r in cycles_rows if r["size"] == size]), 3)
    plain = [r for r in rows if r["baker"] == "usdbake" and r["size"] == 1024]
    for row in (r for r in rows if r["baker"] == "usdbake+oidn"):
        ratio = error_at_equal_time(plain, [row])
        if math.isfinite(ratio):
            figures[f"oidn_error_ratio_{row['samples']}"] = round(ratio, 3)
    figures.update(throughput())
    table = harness.markdown_table(rows + cycles_rows, ["baker", "size", "samples", "texels", "seconds", "error",
                                                        "mtexels_per_s"])
    return harness.result(NAME, description=DESCRIPTION, settings={"reference_rays": REFERENCE_RAYS,
                                                                   "texels_checked": TEXELS_CHECKED},
                          points=rows + cycles_rows, figures=figures, table=table, knob="rays per texel",
                          error_label="AO RMS vs Embree (4096 rays) at interior texels")


def city_accuracy(density: float = 1.0) -> dict:
    """The accuracy figure again on a scene built like a user's: the plan benchmark's city (270k triangles,
    Y-up centimetres, unwelded quads with faceVarying normals and st in 1 m tiles, so every mesh gets a
    generated layout), at ``density`` texels per metre and 256 rays, against Embree at 1000 interior texels."""
    from pxr import Usd

    from usdbake.kernels.tracer import Tracer
    from usdbake.stages.extract import extract_scene

    from .city_stage import cached_stage

    scene = extract_scene(Usd.Stage.Open(str(cached_stage(270_000))))
    tracer = Tracer.from_scene(scene)
    layout, pages, layout_s, _ = prepared(scene, density)
    page = max(pages, key=lambda p: len(p.texel))
    ao, _ = texel_ao(tracer, page, DEFAULT_SAMPLES, 0)
    ao_other, _ = texel_ao(tracer, page, DEFAULT_SAMPLES, 1)
    candidates = interior(page)
    chosen = np.random.default_rng(37).choice(candidates, min(TEXELS_CHECKED, len(candidates)), replace=False)
    reference = harness.cached_reference(
        "lightmap_ao_city", {"rays": REFERENCE_RAYS, "texels": len(chosen), "density": density, "seed": 37,
                             "version": 1},
        lambda: {"ao": embree_ao(scene, page.points[chosen], page.normals[chosen],
                                 scene.tri_normals[page.triangle[chosen]], REFERENCE_RAYS, seed=7)})["ao"]
    noise = math.sqrt(np.mean((ao[chosen] - ao_other[chosen]) ** 2) / 2)
    rms = math.sqrt(np.mean((ao[chosen] - reference) ** 2))
    return {"city_noise_at_256": round(noise, 5),"city_triangles": scene.num_triangles, "city_texels": int(sum(len(p.texel) for p in pages)),
            "city_layout_seconds": round(layout_s, 2), "city_rms_vs_embree_at_256": round(rms, 5),
            "city_rms_over_noise": round(rms / comparison_noise(noise, reference), 3)}


def throughput() -> dict:
    """Texels per second and peak memory of the texture target on the ~370k-triangle room at 32 texels/m at
    the default 256 rays, in a child process (its own peak resident set: VmHWM, which an exec resets, where
    getrusage's maximum would carry the parent's)."""
    code = ("import json, re, sys, time\n"
            "from usdbake.benchmarks.bench_lightmaps import room_scene, prepared, texel_ao\n"
            "from usdbake.kernels.tracer import Tracer\n"
            f"stage, scene = room_scene({THROUGHPUT_CELL})\n"
            "tracer = Tracer.from_scene(scene)\n"
            "layout, pages, layout_s, raster_s = prepared(scene, 32.0)\n"
            "texel_ao(tracer, pages[0], 4, 0)\n"
            f"seconds = sum(texel_ao(tracer, page, {DEFAULT_SAMPLES}, 0)[1] for page in pages)\n"
            "texels = sum(len(p.texel) for p in pages)\n"
            "print(json.dumps({'triangles': scene.num_triangles, 'texels': texels, 'layout_s': layout_s,\n"
            "    'raster_s': raster_s, 'ao_s': seconds,\n"
            "    'peak_mb': int(re.search(r'VmHWM:\\s+(\\d+)', open('/proc/self/status').read())[1]) / 1024}))\n")
    output = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    data = json.loads(output.strip().splitlines()[-1])
    total = data["layout_s"] + data["raster_s"] + data["ao_s"]
    return {"throughput_triangles": data["triangles"], "throughput_texels": data["texels"],
            "throughput_ktexels_per_s": round(data["texels"] / total / 1e3, 1),
            "throughput_seconds": round(total, 2), "throughput_layout_seconds": round(data["layout_s"], 2),
            "throughput_peak_mb": round(data["peak_mb"], 1)}
