"""Bake one stage file into an output layer file: what ``usdbake bake IN -o OUT`` does, as a function.

The command, ``usdbake.bake_many`` and a farm worker all call ``bake_file``; it returns a plain,
picklable ``BakeReport`` (what ran, timings, messages, warnings) instead of printing, so each caller
shows it its own way. Every input is checked before any compute; on failure nothing is written.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ..core.errors import UsageError
from ..core.pipeline import Pipeline
from ..core.records import Prim
from ..core.scene import Scene
from .bake_layer import save_atomically
from .composition import check_composition, quiet_composition_warnings
from .extract import extract_scene
from .inputs import check_output, empty_bake_message, open_source
from .refined_mesh import complete_outputs, refinement_guard

READING, WRITING = "reading stage", "writing layer"
"""Progress names of the two phases around the processors (``on_progress(name, fraction)``)."""


@dataclass
class BakeReport:
    """What one bake did (plain data: it crosses process boundaries)."""

    input: str
    output: str
    seconds: float
    steps: list[dict]
    """``Step.report()`` of every processor, in run order."""
    warnings: list[str] = field(default_factory=list)
    """Missing assets allowed, unreadable textures and their fallback, faces left out."""
    messages: list[str] = field(default_factory=list)
    """'processor: message' lines for people."""
    deinstanced: int = 0
    """Native instances the bake layer sets instanceable = false on."""
    distributed: dict = field(default_factory=dict)
    """Tasks and bytes sent to a Dask cluster (empty for an in-process bake)."""

    @property
    def up_to_date(self) -> bool:
        """Every processor that applies was served from the cache."""
        return all(step["action"] in ("cached", "skip") for step in self.steps) and \
            any(step["action"] == "cached" for step in self.steps)


def default_output(input_path: str, source: str) -> str:
    """IN.baked.usdc beside the input; re-baking a usdbake output replaces it."""
    if Path(input_path).resolve() != Path(source).resolve():
        return input_path
    path = Path(source)
    return str(path.with_name(f"{path.stem}.baked.usdc"))


def compute_outputs(stage, pipeline: Pipeline, *, time_code: float | None, allow_missing: bool, deinstance: bool,
                    on_progress: Callable[[str, float], None] | None = None) -> tuple[Scene, list]:
    """Read ``stage`` into a Scene, run ``pipeline`` on it, and return the scene and the records to author
    (refined meshes completed): the bake both the file bake and the hook run. ``on_progress(name,
    fraction)`` hears READING and each processor. Raises UsageError when every processor skipped (an
    empty layer would only hide that)."""
    if on_progress:
        on_progress(READING, 0.0)
    scene = extract_scene(stage, time=time_code, allow_missing=allow_missing, deinstance=deinstance)
    if on_progress:
        on_progress(READING, 1.0)
    pipeline.run(scene, on_progress=on_progress, before_compute=refinement_guard(stage, scene))
    outputs = complete_outputs(stage, pipeline.outputs())
    if not outputs:
        raise UsageError(empty_bake_message(pipeline.steps))
    return scene, outputs


def bake_file(input_path: str, output: str | None, pipeline: Pipeline, *, time_code: float | None = None,
              allow_missing: bool = False, deinstance: bool = False,
              on_progress: Callable[[str, float], None] | None = None,
              before_compute: Callable[[], None] | None = None) -> BakeReport:
    """Bake ``input_path`` with ``pipeline`` into ``output`` (default: ``default_output``).

    ``on_progress(name, fraction)`` hears READING, each processor and WRITING. ``before_compute()``
    runs once the input and output are checked, before the stage is read (the command opens its
    progress display there). Raises UsageError (bad input, nothing to bake) or ProcessorFailed.
    """
    report_progress = on_progress or (lambda name, fraction: None)
    with quiet_composition_warnings():  # extract_scene reports each missing asset in one line
        source, stage = open_source(input_path)
    check_composition(stage, allow_missing=allow_missing)  # a missing asset fails before any progress
    output = output or default_output(input_path, source)
    check_output(output, source, stage.GetUsedLayers())  # extension, folder, writable, not an input layer
    if before_compute:
        before_compute()
    started = time.perf_counter()
    scene, outputs = compute_outputs(stage, pipeline, time_code=time_code, allow_missing=allow_missing,
                                     deinstance=deinstance, on_progress=report_progress)
    report_progress(WRITING, 0.0)
    save_atomically(output, source, outputs,
                    pipeline.provenance({"source": os.path.relpath(source, Path(output).resolve().parent)}))
    report_progress(WRITING, 1.0)
    return BakeReport(
        input=input_path, output=output, seconds=time.perf_counter() - started,
        steps=[step.report() for step in pipeline.steps], warnings=list(scene.warnings),
        messages=[f"{step.name}: {message}" for step in pipeline.steps
                  for message in (step.result.messages if step.result else [])],
        deinstanced=sum(1 for r in outputs if isinstance(r, Prim) and r.instanceable is False),
        distributed=dict(getattr(pipeline.runtime.chunks, "stats", {}) or {}))
