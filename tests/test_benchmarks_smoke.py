"""Smoke run of every benchmark's quick sweep (issue #6): ``python -m usdbake.benchmarks --quick --results DIR``.

Checks that every bench_*.py runs to completion, writes its JSON with finite figures, leaves the committed results (benchmarks/results/*.json,
docs/benchmarks.md) untouched, and meets the few error bounds that are properties of correctness
(not tuning targets): AO converges to its 16x reference, form-factor rows sum to at most 1. Its time
is printed against the 3-minute budget for ``--quick``, not asserted: a busy CI machine must not
refuse a correct submission (issue 27).

Measured on the 2-core dev machine: 47 s with warm caches, 68 s cold (no reference cache in
benchmarks/cache, empty Warp kernel cache).
"""

from __future__ import annotations

from repo_paths import REPO
import hashlib
import itertools
import json
import math
import subprocess
import sys
import time

import pytest
from tolerances import AO_RMS_BOUND, FLOAT32_STORAGE


QUICK_BUDGET_S = 180.0
"""The budget for ``--quick`` the run's time is printed against (measured 47-136 s on the 2-core machine)."""
HANG_GUARD_S = 1800
"""Only a hung run is stopped: far above any time measured, loaded or not."""


def _numbers(value, path=""):
    """(path, number) for every int/float nested in a JSON value (bools excluded)."""
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return
    if isinstance(value, (int, float)):
        yield path, value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from _numbers(item, f"{path}.{key}")
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _numbers(item, f"{path}[{index}]")


def _digest(paths) -> dict[str, str]:
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in paths if p.is_file()}


@pytest.mark.slow
def test_quick_benchmarks_run_and_write_finite_figures(tmp_path):
    from usdbake.benchmarks.__main__ import available  # the bench modules, by NAME

    names = sorted(available())
    assert names, "no bench_*.py modules found"
    committed = sorted((REPO / "benchmarks" / "results").glob("*.json")) + [REPO / "docs" / "benchmarks.md"]
    before = _digest(committed)

    started = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "benchmarks", "--quick", "--results", str(tmp_path)],
                         check=False, cwd=REPO, capture_output=True, text=True, timeout=HANG_GUARD_S)
    elapsed = time.perf_counter() - started
    print(run.stdout[-4000:])
    assert run.returncode == 0, f"python -m usdbake.benchmarks --quick failed:\n{run.stderr[-4000:]}"
    print(f"benchmark smoke run: --quick took {elapsed:.0f} s (budget {QUICK_BUDGET_S:.0f} s)")
    assert _digest(committed) == before, "a quick run modified the committed benchmark results or report"
    assert (tmp_path / "benchmarks.md").is_file(), "the report was not written to --results"

    results = {}
    for name in names:
        path = tmp_path / f"{name}.json"
        assert path.is_file(), f"benchmark {name} wrote no {path.name}"
        data = json.loads(path.read_text())
        assert data["quick"] is True
        numbers = list(_numbers(data["figures"], "figures")) + list(_numbers(data["points"], "points"))
        assert numbers, f"{name}: no numeric figures"
        bad = [(where, value) for where, value in numbers if not math.isfinite(value)]
        assert not bad, f"{name}: non-finite figures {bad}"
        for point in data["points"]:
            assert point["seconds"] >= 0, f"{name}: negative time in {point}"
        results[name] = data

    if "ambient_occlusion" in results:
        ao = results["ambient_occlusion"]
        assert ao["figures"]["rms_at_default_vs_16x"] < AO_RMS_BOUND
        errors = [p["error"] for p in ao["points"]]  # rays x4 per point: Monte Carlo error must fall
        assert all(later < earlier for earlier, later in itertools.pairwise(errors)), f"AO error not converging: {errors}"
    if "radiosity" in results:
        assert results["radiosity"]["figures"]["row_sum_max"] <= 1.0 + FLOAT32_STORAGE
