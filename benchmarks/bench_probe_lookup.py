"""Light-probe lookups per second on the device walk against scipy's find_simplex, same probes, same points."""

from __future__ import annotations

import numpy as np

from . import harness
from usdbake.processors.light_probes import tetrahedra
from usdbake.processors.light_probes.lookup import ProbeLookup
from usdbake.kernels.tracer import default_threads

NAME = "probe_lookup"
DESCRIPTION = (
    "Point location in a light-probe cloud (`processors.light_probes.lookup`: start tetrahedron from a grid, then the "
    "barycentric walk, float32), lookups per second including the upload of the points and the download of "
    "tetrahedra and barycentrics, one thread and all cores; beside scipy's `Delaunay.find_simplex` (Qhull's "
    "walk, one thread) plus its barycentric transform, on the same probes and points. Probes: 1024 and 8192 "
    "uniform random in a 10 m cube; points: 1M uniform in the cube (incoherent) and the same points sorted "
    "along z-slabs and rows (coherent: neighbouring queries in neighbouring tetrahedra, as the vertices of a "
    "mesh or the pixels of a screen are).")


def coherent_order(points: np.ndarray, slab: float) -> np.ndarray:
    """Points sorted by z-slab, then y-row, then x: consecutive queries lie close together."""
    cells = np.floor(points / slab).astype(np.int64)
    return np.lexsort((points[:, 0], cells[:, 1], cells[:, 2]))


def scipy_lookup(delaunay, points: np.ndarray) -> np.ndarray:
    simplex = delaunay.find_simplex(points)
    b = np.einsum("nij,nj->ni", delaunay.transform[simplex, :3], points - delaunay.transform[simplex, 3])
    return np.c_[b, 1.0 - b.sum(axis=1)]


def run(quick: bool = False) -> dict:
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(11)  # fixed seed: the same probes and points every run
    count = 200_000 if quick else 1_000_000
    repeats = 1 if quick else 3
    threads = default_threads()
    rows, figures = [], {"threads": threads}
    for probes in ((1024,) if quick else (1024, 8192)):
        positions = rng.uniform(0.0, 10.0, (probes, 3))
        tetra = tetrahedra.tetrahedralize(positions)
        delaunay = Delaunay(positions)
        points = rng.uniform(0.0, 10.0, (count, 3))
        coherent = np.ascontiguousarray(points[coherent_order(points, 10.0 / np.cbrt(probes))])
        lookup = ProbeLookup(tetra, threads=threads)
        lookup.locate(points[:1000])  # compile/load outside the timings
        for label, queries in (("incoherent", points), ("coherent", coherent)):
            row = {"probes": probes, "points": label, "tetrahedra": tetra.num_tets}
            for n in (1, threads):
                lookup.threads = n
                seconds = min(harness.timings(lambda: lookup.locate(queries), repeats))
                row[f"mlookups_per_s_{n}_thread{'s' if n > 1 else ''}"] = round(count / seconds / 1e6, 3)
            scipy_seconds = min(harness.timings(lambda: scipy_lookup(delaunay, queries), repeats))
            row["scipy_mlookups_per_s"] = round(count / scipy_seconds / 1e6, 3)
            row["all_cores_vs_scipy"] = round(row[f"mlookups_per_s_{threads}_threads"] / row["scipy_mlookups_per_s"], 3)
            rows.append(row)
    default = [r for r in rows if r["probes"] == 1024]
    for row in default:
        figures[f"{row['points']}_mlookups_per_s"] = row[f"mlookups_per_s_{threads}_threads"]
        figures[f"{row['points']}_mlookups_per_s_1_thread"] = row["mlookups_per_s_1_thread"]
        figures[f"{row['points']}_scipy_mlookups_per_s"] = row["scipy_mlookups_per_s"]
        figures[f"{row['points']}_vs_scipy"] = row["all_cores_vs_scipy"]
    columns = ["probes", "tetrahedra", "points", "mlookups_per_s_1_thread", f"mlookups_per_s_{threads}_threads",
               "scipy_mlookups_per_s", "all_cores_vs_scipy"]
    points_out = [{"label": f"{r['probes']} probes, {r['points']}", "seconds": count / (r[columns[4]] * 1e6),
                   "error": 0.0, "default": r["probes"] == 1024 and r["points"] == "coherent", **r} for r in rows]
    return harness.result(NAME, description=DESCRIPTION, settings={"points": count, "threads": threads},
                          points=points_out, figures=figures, table=harness.markdown_table(rows, columns),
                          knob="probes", error_label="(exact)")
