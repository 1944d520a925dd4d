"""Shared benchmark helpers: timing, peak memory, machine info, cached references, result files."""

from __future__ import annotations

import hashlib
import json
import os
import platform
import resource
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parent
RESULTS = ROOT / "results"
CACHE = ROOT / "cache"
REPO = ROOT.parent
SAMPLES = REPO / "samples"


def machine_info() -> dict:
    """CPU, cores, memory, Python and library versions, for every result file."""
    import warp as wp
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
        return f"{value:.4g}" if isinstance(value, float) else str(value)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell(row.get(c, "")) for c in columns) + " |" for row in rows]
    return "\n".join(lines)
