"""Progressive meshes (`progressive_mesh`): ordering time at scale, and level-of-detail error against the
pure Melax order it replaced in bulk."""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial import cKDTree

from . import harness
from usdbake.formats import mesh_stream
from usdbake.processors.irradiance_grid import progressive_mesh as pm

NAME = "progressive_mesh"
DESCRIPTION = (
    "`progressive_mesh` ordering (`progressive_order`: quadric collapses of fast-simplification with borders kept, "
    "then Melax half-edge collapses for the coarsest ~2000 vertices) on generated meshes: a height field "
    "(a welded grid with sine bumps), the same surface as an unwelded triangle soup, and a UV sphere. Seconds: "
    "wall time of the ordering; lod_ms: `lod_faces` at 10 % of the vertices. Level-of-detail error: mean "
    "distance from 20,000 area-uniform samples of the full mesh to samples of the level of detail made of the "
    "first k vertices (one fixed seed), for the two-pass order and for the pure Melax order on a mesh small "
    "enough for it (3,600 vertices). Stream (`formats/mesh_stream.py`) of the height field: packing time, bytes "
    "against a plain indexed face set (float32 positions + uint32 corners) for several packet sizes, and decoding "
    "time of whole-stream prefixes. The issue's figures: 200k vertices ordered and packed in <= 10 s; stream "
    "overhead <= 10 % with large packets.")
PACKET_SIZES = (256, 4096, 65536)
LOD_FRACTIONS = (0.02, 0.05, 0.1, 0.25)


def height_field(n: int, bumps: float = 17.0) -> tuple[np.ndarray, np.ndarray]:
    """(n^2, 3) points and (2 (n-1)^2, 3) triangles of a welded n x n grid with sine bumps."""
    x, y = np.meshgrid(np.arange(n, dtype=np.float64), np.arange(n, dtype=np.float64))
    points = np.c_[x.ravel(), y.ravel(), 3.0 * np.sin(x.ravel() / bumps) * np.cos(y.ravel() / (1.35 * bumps))]
    a = (np.arange(n - 1)[None, :] + n * np.arange(n - 1)[:, None]).ravel()
    tris = np.concatenate([np.c_[a, a + 1, a + n + 1], np.c_[a, a + n + 1, a + n]])
    return points, tris


def sphere(rings: int, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """A UV sphere of radius 1: poles plus (rings - 1) x segments points."""
    theta = np.linspace(0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, f = np.meshgrid(theta, phi, indexing="ij")
    points = np.vstack([[0, 0, 1], np.c_[np.sin(t).ravel() * np.cos(f).ravel(),
                                         np.sin(t).ravel() * np.sin(f).ravel(), np.cos(t).ravel()], [0, 0, -1]])
    ring = lambda r: 1 + r * segments + np.arange(segments)  # noqa: E731
    nxt = lambda r: 1 + r * segments + (np.arange(segments) + 1) % segments  # noqa: E731
    last = len(points) - 1
    tris = [np.c_[np.zeros(segments, int), ring(0), nxt(0)], np.c_[np.full(segments, last), nxt(rings - 2), ring(rings - 2)]]
    for r in range(rings - 2):
        tris += [np.c_[ring(r), ring(r + 1), nxt(r)], np.c_[nxt(r), ring(r + 1), nxt(r + 1)]]
    return points, np.concatenate(tris)


def surface_samples(points: np.ndarray, faces: np.ndarray, count: int, rng) -> np.ndarray:
    corners = points[faces]
    areas = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    pick = rng.choice(len(faces), count, p=areas / areas.sum())
    r1, r2 = np.sqrt(rng.random(count))[:, None], rng.random(count)[:, None]
    c = corners[pick]
    return c[:, 0] * (1 - r1) + c[:, 1] * (r1 * (1 - r2)) + c[:, 2] * (r1 * r2)


def lod_error(points, tris, order, k: int) -> float:
    rng = np.random.default_rng(0)  # fixed: the same samples for every order
    full = surface_samples(points, tris, 20_000, rng)
    lod = surface_samples(points, pm.lod_faces(tris, *order, k), 20_000, rng)
    return float(cKDTree(lod).query(full)[0].mean())


def run(quick: bool = False) -> dict:
    n = 224 if quick else 448
    grid_points, grid_tris = height_field(n)
    soup_points = grid_points[grid_tris[: len(grid_tris) // 4]].reshape(-1, 3)
    meshes = {"height field": (grid_points, grid_tris),
              "triangle soup": (soup_points, np.arange(len(soup_points)).reshape(-1, 3)),
              "sphere": sphere(100, 100 if quick else 400)}
    pm.progressive_order(*height_field(8))  # first call: library import and page-in
    points = []
    for label, (p, t) in meshes.items():
        started = time.perf_counter()
        order = pm.progressive_order(p, t)
        seconds = time.perf_counter() - started
        started = time.perf_counter()
        pm.lod_faces(t, *order, len(p) // 10)
        points.append({"label": label, "vertices": len(p), "triangles": len(t), "seconds": round(seconds, 2),
                       "lod_ms": round(1000 * (time.perf_counter() - started), 1), "error": 0.0,
                       "default": label == "height field"})
    stream_rows, order = [], pm.progressive_order(grid_points, grid_tris)
    plain = grid_points.astype(np.float32).nbytes + grid_tris.astype(np.uint32).nbytes
    for size in PACKET_SIZES:
        started = time.perf_counter()
        data = mesh_stream.encode_mesh_stream(grid_points, grid_tris, *order, packet_vertices=size)
        pack = time.perf_counter() - started
        started = time.perf_counter()
        full = mesh_stream.decode_mesh_stream(data)
        decode = time.perf_counter() - started
        stream_rows.append({"packet_vertices": size, "packets": full.packets, "bytes": len(data),
                            "overhead": round(len(data) / plain - 1.0, 4), "pack_s": round(pack, 2),
                            "decode_full_ms": round(1000 * decode, 1),
                            "decode_ms_per_packet": round(1000 * decode / max(1, full.packets), 2)})
    small_points, small_tris = height_field(60, bumps=7.0)
    started = time.perf_counter()
    melax = pm._melax_order(small_points, small_tris)
    melax_seconds = time.perf_counter() - started
    started = time.perf_counter()
    two_pass = pm.progressive_order(small_points, small_tris)
    two_pass_seconds = time.perf_counter() - started
    quality = [{"fraction": f, "melax": lod_error(small_points, small_tris, melax, int(f * len(small_points))),
                "two_pass": lod_error(small_points, small_tris, two_pass, int(f * len(small_points)))}
               for f in LOD_FRACTIONS]
    biggest = points[0]
    figures = {"height_field_vertices": biggest["vertices"], "height_field_order_seconds": biggest["seconds"],
               "height_field_lod_ms": biggest["lod_ms"],
               "soup_order_seconds": points[1]["seconds"], "sphere_order_seconds": points[2]["seconds"],
               "height_field_pack_seconds": stream_rows[1]["pack_s"],
               **{f"stream_overhead_{r['packet_vertices']}": r["overhead"] for r in stream_rows},
               "height_field_plain_bytes": plain,
               "small_melax_seconds": round(melax_seconds, 2), "small_two_pass_seconds": round(two_pass_seconds, 2),
               **{f"lod_error_{row['fraction']}_melax": round(row["melax"], 4) for row in quality},
               **{f"lod_error_{row['fraction']}_two_pass": round(row["two_pass"], 4) for row in quality}}
    table = harness.markdown_table(points, ["label", "vertices", "triangles", "seconds", "lod_ms"])
    table += ("\n\nStream of the height field against a plain indexed face set "
              f"({plain:,} bytes):\n\n")
    table += harness.markdown_table(stream_rows, ["packet_vertices", "packets", "bytes", "overhead", "pack_s",
                                                  "decode_full_ms", "decode_ms_per_packet"])
    table += ("\n\nLevel-of-detail error on a 3,600-vertex height field (Melax alone "
              f"{melax_seconds:.2f} s, two passes {two_pass_seconds:.2f} s):\n\n")
    table += harness.markdown_table(quality, ["fraction", "melax", "two_pass"])
    return harness.result(NAME, description=DESCRIPTION, settings={"quick": quick, "base_points": pm.BASE_POINTS},
                          points=points, figures=figures, table=table, knob="mesh", error_label="-")
