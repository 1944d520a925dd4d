"""Light probes against path-traced irradiance: placed cloud, conforming cloud and a uniform grid."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from . import harness
from usdbake.processors.light_probes.products import ProbeCloud

NAME = "light_probes"
DESCRIPTION = (
    "Light probe clouds against a dense path-traced reference (`benchmarks/probe_reference.py`: direct light "
    "by 256 samples per light and 1024 sky rays, plus 1024 paths of 4 bounces of indirect light) at free-space "
    "points (6 axis normals each, >= 0.1 m from surfaces), near-surface points (5 cm off a surface, its "
    "normal) and leak points (within 10 cm of a wall on its dark side), on atrium, the furnished room of "
    "`furnished_room.py` (uniform sky through four windows, 200 m ground) and two thin-walled rooms lit by "
    "lamps of 2000 and 100 W/sr. Error = relative RMS of the irradiance luminance. Three ways to fill the "
    "space with the same number of probes: `delaunay` (the placed cloud at default settings: error-driven "
    "placement, Delaunay tetrahedra, leak rule), `conforming` (fTetWild's mesh of the empty space sized by the "
    "error-driven placement, a probe per vertex and side) and `grid` (a uniform lattice over the "
    "same box with trilinear interpolation, as engines' irradiance volumes, captured the same way; `grid + "
    "visibility`: its corners hidden from the point drop out, the cloud's lookup rule). All leave the lights' "
    "direct light to the lookup (`direct_lights=lookup`) unless a row says `probes`; the cloud's lookup tests "
    "its four probes for visibility (a tracer is given).")

SCENE_BUDGETS = {"atrium": (256, 512, 1024, 2048), "furnished_room": (128, 256, 512, 1024),
                 "thin_wall": (128, 256, 512, 1024)}
DEFAULT_PROBES = 1024
QUICK = {"scenes": ("thin_wall",), "budgets": (256,), "free": 150, "near": 100, "leak": 100, "paths": 64}
FULL = {"free": 6000, "near": 4000, "leak": 500, "paths": 1024}


def run(quick: bool = False) -> dict:
    from usdbake.core import Context
    from usdbake.kernels.sh import sh_basis_np
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.light_probes import light_probes as lp
    from usdbake.processors.light_probes.capture import compute_probe_sh, direct_light_irradiance
    from usdbake.processors.light_probes.interpolation import irradiance_at, segment_blocked

    from . import probe_reference as ref

    settings = QUICK if quick else FULL
    scenes = QUICK["scenes"] if quick else ref.SCENES
    processor = lp.LightProbes()
    rows, figures = [], {}
    for name in scenes:
        scene = ref.load(name)
        if name == "furnished_room":  # probes where the grid and the test points are: the room (a probe volume)
            scene = dataclasses.replace(scene, probe_volumes=np.array([ref.grid_box(name, scene)]))
        tracer = Tracer.from_scene(scene)
        tests = ref.test_set(name, scene, tracer, free=settings["free"], near=settings["near"],
                             leak=settings["leak"])
        reference = ref.reference(name, scene, tracer, tests, paths=settings["paths"])
        kinds = {kind: tests.rows(k) for k, kind in enumerate(ref.KIND_NAMES)}

        def errors(estimate) -> dict:
            out = {"error": ref.relative_error(estimate, reference, tests.kind != ref.LEAK)}
            for kind, rows_of_kind in kinds.items():
                if rows_of_kind.any():
                    out[kind] = ref.relative_error(estimate, reference, rows_of_kind)
            return out

        def bake(**params):
            started = time.perf_counter()
            result = processor.run(Context(scene, processor.Params(**params), tracer))
            seconds = time.perf_counter() - started
            cloud = result.products[ProbeCloud]
            estimate = irradiance_at(cloud, tests.positions, tests.normals, tracer=tracer, scene=scene)
            return {"probes": len(cloud.probe_positions), "seconds": seconds,
                    "placement_seconds": result.stats["placement_seconds"],
                    "capture_seconds": result.stats["capture_seconds"], **errors(estimate)}

        def grid(count: int, direct_lights: str = "lookup", rays: int = 256, bounces: int = 3,
                 visibility: bool = False):
            lo, hi = ref.grid_box(name, scene)
            positions, dims = ref.grid_positions(lo, hi, count)
            started = time.perf_counter()
            sh = compute_probe_sh(tracer, scene, positions, rays=rays, seed=1_000_003, bounces=bounces,
                                     direct_lights=direct_lights == "probes")
            seconds = time.perf_counter() - started
            index, weights = ref.grid_weights(lo, hi, dims, tests.positions)
            if visibility:  # the cloud's lookup rule on the lattice: corners hidden from the point drop out
                hidden = segment_blocked(tracer, np.repeat(tests.positions, 8, axis=0),
                                            positions[index].reshape(-1, 3)).reshape(-1, 8)
                seen = np.where(hidden, 0.0, weights)
                total = seen.sum(axis=1, keepdims=True)
                weights = np.where(total > 0, seen / np.maximum(total, 1e-300), weights)
            interpolated = np.einsum("nv,nvkc->nkc", weights, sh[index].astype(np.float64))
            estimate = np.einsum("nk,nkc->nc", sh_basis_np(tests.normals.astype(np.float64)), interpolated)
            if direct_lights == "lookup":
                estimate = estimate + direct_light_irradiance(tracer, scene, tests.positions, tests.normals)
            return {"probes": len(positions), "seconds": seconds, **errors(estimate)}

        processor.run(Context(scene, processor.Params(probes=16, rays=4, placement_rays=4, iterations=1), tracer))
        budgets = QUICK["budgets"] if quick else SCENE_BUDGETS[name]
        default = budgets[-1] if quick else DEFAULT_PROBES if name == "atrium" else budgets[-2]

        def with_grid(method: str, budget: int, measured: dict) -> None:
            """The cloud's row and a grid row of the same probe count (the curve's points)."""
            same = grid(measured["probes"])
            rows.append(_row(name, "grid", budget, same))
            rows.append({**_row(name, method, budget, measured), "grid_error": round(same["error"], 4),
                         "vs_grid": round(measured["error"] / same["error"], 3)})

        for budget in budgets:
            with_grid("delaunay", budget, bake(probes=budget))
            rows.append(_row(name, "grid + visibility", budget, grid(rows[-1]["probes"], visibility=True)))
            rows.append(_row(name, "delaunay, no leak handling", budget, bake(probes=budget, leak_fix=False)))
            if not quick and (name != "atrium" or budget == default):  # atrium: fTetWild takes minutes
                with_grid("conforming", budget, bake(probes=budget, tetrahedra="conforming"))
        for count in ([] if quick else [2 * budgets[-1], 4 * budgets[-1]]):  # the grid's curve goes on
            rows.append(_row(name, "grid", count, grid(count)))
        variants = {"delaunay, thesis placement": dict(placement="thesis")}
        if not quick:
            variants["delaunay, direct in probes"] = dict(direct_lights="probes")
            variants["delaunay, 1 bounce"] = dict(bounces=1)
        for label, params in variants.items():
            rows.append(_row(name, label, default, bake(probes=default, **params)))
        if not quick:
            placed = next(r for r in rows if r["scene"] == name and r["method"] == "delaunay"
                          and r["budget"] == default)
            rows.append(_row(name, "grid, direct in probes", default, grid(placed["probes"], "probes")))
        figures.update(_scene_figures(name, rows, default, quick))
        figures[f"{name}_test_points"] = tests.points
        figures[f"{name}_test_points_per_kind"] = tests.counts
        figures[f"{name}_reference_noise"] = round(ref.reference_noise(name, scene, tracer, tests,
                                                                       paths=settings["paths"]), 4)
    curves_plot(rows)
    table = harness.markdown_table(rows, ["scene", "method", "budget", "probes", "seconds", "error", "free", "near",
                                          "leak", "vs_grid", "grid_ratio"])
    return harness.result(NAME, description=DESCRIPTION, settings={**settings, "scenes": list(scenes)},
                          points=rows, figures={k: v for k, v in figures.items() if v is not None}, table=table,
                          knob="probe budget", error_label="relative RMS irradiance vs path tracer")


def curves_plot(rows: list[dict]):
    """docs/benchmarks/light_probes_curves.png: error against probe count per scene, grid and clouds."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        import matplotlib.ticker
    except ImportError:
        return None
    from . import report

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    figure, axes = plt.subplots(1, len(scenes), figsize=(4.2 * len(scenes), 3.6), squeeze=False)
    for axis, scene in zip(axes[0], scenes):
        for method, style in (("grid", "s-"), ("delaunay", "o-"), ("conforming", "^-")):
            points = sorted((r["probes"], r["error"]) for r in rows if r["scene"] == scene and r["method"] == method)
            if points:
                axis.loglog(*zip(*points), style, label=method, ms=4)
        axis.set_title(scene)
        axis.set_xlabel("probes")
        axis.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        axis.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("relative RMS irradiance vs path tracer")
    axes[0][0].legend(fontsize=8)
    figure.tight_layout()
    path = report.DOCS / "benchmarks" / "light_probes_curves.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def _row(scene: str, method: str, budget: int, measured: dict) -> dict:
    row = {"scene": scene, "method": method, "budget": budget, "probes": measured["probes"],
           "seconds": round(measured["seconds"], 3), "error": round(measured["error"], 4)}
    for part in ("placement_seconds", "capture_seconds"):
        if part in measured:
            row[part] = round(measured[part], 3)
    for kind in ("free", "near", "leak"):
        if kind in measured:
            row[kind] = round(measured[kind], 4)
    return row


def _scene_figures(name: str, rows: list[dict], default: int, quick: bool) -> dict:
    """At the default budget: cloud / grid error at equal probe counts, how many more probes the grid needs
    for the cloud's error (each budget: the ``grid_ratio`` column), leak reductions vs no leak handling."""
    mine = [r for r in rows if r["scene"] == name]

    def at(method: str, budget: int = default) -> dict | None:
        return next((r for r in mine if r["method"] == method and r["budget"] == budget), None)

    figures = {}
    grid_curve = sorted({(r["probes"], r["error"]) for r in mine if r["method"] == "grid"})
    for method in ("delaunay", "conforming"):
        for row in (r for r in mine if r["method"] == method):
            row["grid_ratio"] = _probes_for_error(grid_curve, row)
        row = at(method)
        if row is None:
            continue
        figures[f"{name}_{method}_over_grid_error"] = row["vs_grid"]
        seen = at("grid + visibility", row["budget"]) if method == "delaunay" else None  # same count
        if seen:
            figures[f"{name}_{method}_over_visibility_grid_error"] = round(row["error"] / seen["error"], 3)
        figures[f"{name}_{method}_probes"] = row["probes"]
        if row["grid_ratio"] is not None:
            figures[f"{name}_grid_probes_for_{method}_error"] = row["grid_ratio"]
        elif grid_curve and row["error"] < min(e for _, e in grid_curve):  # no grid of the sweep is as good
            figures[f"{name}_grid_probes_for_{method}_error_at_least"] = round(
                max(c for c, _ in grid_curve) / row["probes"], 3)
        ratios = [r["grid_ratio"] for r in mine if r["method"] == method and r["grid_ratio"] is not None]
        if ratios:
            figures[f"{name}_grid_probes_for_{method}_error_min_over_budgets"] = min(ratios)
        leaky = at("delaunay, no leak handling")
        if leaky and "leak" in row:
            figures[f"{name}_leak_reduction_{method}"] = round(leaky["leak"] / max(row["leak"], 1e-12), 3)
            figures[f"{name}_overall_error_{method}_vs_no_leak_handling"] = round(row["error"] / leaky["error"], 3)
    return figures


def _probes_for_error(grid_curve: list[tuple[int, float]], row: dict) -> float | None:
    """Grid probes needed for ``row``'s error / the row's probes: the fewest grid probes of the sweep whose
    error is at most the row's, interpolated log-log with the grid point before it; None when no grid of
    the sweep is as good (the grid's error is not monotonic in its count: its planes fall in walls or not)."""
    for k, (count, error) in enumerate(grid_curve):
        if error <= row["error"]:
            if k == 0:
                return round(count / row["probes"], 3)
            (c0, e0), (c1, e1) = grid_curve[k - 1], (count, error)
            if e0 <= e1:
                return round(count / row["probes"], 3)
            t = np.log(row["error"] / e0) / np.log(e1 / e0)
            return round(float(np.exp(np.log(c0) + t * (np.log(c1) - np.log(c0)))) / row["probes"], 3)
    return None
