"""Shared benchmark helpers: sample scenes and test points, timing, peak memory, machine info, cached
references, result files."""

from __future__ import annotations

import hashlib
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable

import numpy as np
import warp as wp

from usdbake.geometry.mesh import receiver_prims
from usdbake.kernels.sampling import triangle_point
from usdbake.kernels.tracer import launch_chunked

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

ROOT = Path(__file__).resolve().parent
RESULTS = ROOT / "results"
CACHE = ROOT / "cache"
REPO = ROOT.parent
SAMPLES = REPO / "samples"


# ---------------------------------------------------------------------------
# Scenes and test points


def load_scene(name: str):
    """The Scene of ``samples/<name>.usda`` at its default time."""
    from pxr import Usd

    from usdbake.stages.extract import extract_scene

    return extract_scene(Usd.Stage.Open(str(SAMPLES / f"{name}.usda")))


def receiver_points(scene) -> np.ndarray:
    """(R,) int64 ids of the points the per-receiver processors bake (the points of ``receiver_prims``)."""
    return np.flatnonzero(np.isin(scene.point_prim, receiver_prims(scene)))


@wp.kernel
def triangle_points_kernel(start: int, points: wp.array(dtype=wp.vec3), tri_vertices: wp.array(dtype=wp.vec3i),
                           sample_tri: wp.array(dtype=int), sample_u: wp.array(dtype=wp.vec2),
                           out: wp.array(dtype=wp.vec3)):
    """Sample i: the point of triangle sample_tri[i] at the uniforms sample_u[i] (``triangle_point``)."""
    i = start + wp.tid()
    tri = tri_vertices[sample_tri[i]]
    u = sample_u[i]
    out[i] = triangle_point(points[tri[0]], points[tri[1]], points[tri[2]], u[0], u[1])


def surface_points(scene, count: int, *, seed: int, triangles: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(count, 3) float32 area-uniform random points on the receivers' triangles (or on ``triangles``, a bool
    mask over the scene's), and their (count, 3) face normals: triangles picked in proportion to their area,
    then ``triangle_point`` (Osada et al. 2002)."""
    chosen = np.isin(scene.tri_prim, receiver_prims(scene)) if triangles is None else triangles
    tris = np.flatnonzero(chosen & (scene.tri_areas > 0))
    rng = np.random.default_rng(seed)  # the caller's fixed seed: the same points for every setting compared
    pick = rng.choice(tris, count, p=scene.tri_areas[tris] / scene.tri_areas[tris].sum())
    u = np.stack([rng.random(count), rng.random(count)], axis=1).astype(np.float32)
    out = wp.empty(count, dtype=wp.vec3, device="cpu")
    launch_chunked(triangle_points_kernel, count, [
        wp.array(np.ascontiguousarray(scene.points, np.float32), dtype=wp.vec3, device="cpu"),
        wp.array(np.ascontiguousarray(scene.tri_vertices, np.int32), dtype=wp.vec3i, device="cpu"),
        wp.array(pick.astype(np.int32), dtype=int, device="cpu"), wp.array(u, dtype=wp.vec2, device="cpu"), out],
        device="cpu", threads=1)
    return out.numpy(), scene.tri_normals[pick]


def relative_rms(estimate: np.ndarray, reference: np.ndarray, weights: np.ndarray | None = None) -> float:
    """sqrt(sum w (estimate - reference)^2 / sum w reference^2): the RMS error relative to the reference's
    RMS; ``weights`` (N,) weigh the rows (e.g. face areas), default 1."""
    e, r = np.asarray(estimate, np.float64), np.asarray(reference, np.float64)
    w = np.ones(len(r)) if weights is None else np.asarray(weights, np.float64)
    w = w.reshape((-1,) + (1,) * (r.ndim - 1))
    return float(np.sqrt((w * (e - r) ** 2).sum() / max(float((w * r ** 2).sum()), 1e-300)))


# ---------------------------------------------------------------------------
# Machine, timing and memory


def machine_info() -> dict:
    """CPU, cores, memory, Python and library versions, for every result file."""
    from pxr import Usd

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
        "numpy": np.__version__, "warp": wp.__version__, "usd": ".".join(map(str, Usd.GetVersion())),
        "platform": platform.platform(),
    }


class Timer:
    """Wall time and growth of peak RSS of a block: ``with measure() as m: ...; m.seconds, m.peak_mb``."""

    seconds: float = 0.0
    peak_mb: float = 0.0


@contextmanager
def measure():
    timer = Timer()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    started = time.perf_counter()
    try:
        yield timer
    finally:
        timer.seconds = time.perf_counter() - started
        timer.peak_mb = max(0, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024.0


def timings(function: Callable[[], object], repeats: int) -> list[float]:
    """Wall seconds of ``repeats`` calls of ``function`` (the caller warms it up first if it must)."""
    seconds = []
    for _ in range(repeats):
        started = time.perf_counter()
        function()
        seconds.append(time.perf_counter() - started)
    return seconds


def bake_wall_seconds(sample: Path, *processors: str) -> float:
    """Wall time of the ``usdbake bake`` command on ``sample`` at defaults (all processors, or ``-p`` each of
    ``processors``), with a fresh cache so it really runs."""
    with tempfile.TemporaryDirectory() as folder:
        command = [sys.executable, "-m", "usdbake.cli.main", "bake", str(sample), "-o",
                   str(Path(folder) / f"{sample.stem}.baked.usdc"), "--cache", str(Path(folder) / "cache")]
        for name in processors:
            command += ["-p", name]
        started = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True, env={**os.environ})
        return time.perf_counter() - started


# ---------------------------------------------------------------------------
# References and results


def cached_reference(name: str, settings: dict, compute: Callable[[], dict]) -> dict:
    """A reference our fast path did not produce, computed once per settings and kept on disk (.npz)."""
    key = hashlib.sha256(json.dumps(settings, sort_keys=True, default=str).encode()).hexdigest()[:16]
    path = CACHE / f"{name}-{key}.npz"
    if path.exists():
        with np.load(path) as data:
            return {k: data[k] for k in data.files}
    arrays = compute()
    CACHE.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **arrays)
    (CACHE / f"{name}-{key}.json").write_text(json.dumps(settings, indent=2, default=str))
    return arrays


def result(name: str, *, description: str, settings: dict, points: list[dict], figures: dict,
           table: str = "", knob: str = "", error_label: str = "error") -> dict:
    """A benchmark result.

    points : one dict per setting of the quality knob, each with 'label', 'seconds', 'error'
        and 'default' (bool), plus anything else worth keeping (rays, peak_mb, ...).
    figures : the named figures the issue asks for, e.g. {'threads_speedup': 1.97}.
    table : a Markdown fragment for docs/benchmarks.md (tables of the figures).
    """
    return {"name": name, "description": description, "machine": machine_info(),
            "date": time.strftime("%Y-%m-%d %H:%M:%S"), "settings": settings, "points": points,
            "figures": figures, "table": table, "knob": knob, "error_label": error_label}


def save(data: dict) -> Path:
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{data['name']}.json"
    path.write_text(json.dumps(data, indent=2, default=_jsonable))
    return path


def _jsonable(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def markdown_table(rows: list[dict], columns: list[str]) -> str:
    """A Markdown table of ``rows`` restricted to ``columns`` (floats to 4 significant digits)."""
    def cell(value):
        return f"{value:.4g}" if isinstance(value, float) else "" if value is None else str(value)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell(row.get(c, "")) for c in columns) + " |" for row in rows]
    return "\n".join(lines)
