"""Many stages, one task each: ``usdbake bake A.usd B.usd ... -o OUTDIR/`` and ``usdbake.bake_many``.

Each stage is baked by ``stages.bake_file`` in a worker process: a local process pool by default
(spawned, so Warp and USD start clean; one CPU thread per worker share of the cores), or a Dask
cluster (``scheduler="tcp://host:port"``). The result cache is one folder shared by every worker
(entries are written atomically, core.cache), so unchanged assets report "up to date" on any
worker. A stage that fails is reported with its reason and never stops the others; a worker that
dies (out of memory, a crash in native code) is reported by the stage it was baking.
"""

from __future__ import annotations

import glob
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Callable

from ..core.errors import UsageError
from ..core.pipeline import Pipeline, ProcessorFailed, build_steps
from ..core.runtime import Runtime, check_threads
from ..kernels.startup import start_warp_quietly
from ..kernels.tracer import Tracer
from ..stages.bake_file import BakeReport, bake_file
from .cluster import WORKER_THREADS_VARIABLE, connect, worker_threads

BAKED, UP_TO_DATE, FAILED = "baked", "up to date", "failed"
WORKER_DIED = ("the worker process died while baking it (out of memory, or a crash in native code); "
               "nothing was written")


@dataclass(frozen=True)
class BatchOptions:
    """How every stage of a batch is baked (plain data: it is sent to each worker)."""

    processors: tuple[str, ...] | None = None
    params: dict = field(default_factory=dict)
    device: str = "cpu"
    cache_dir: str | None = None
    force: bool = False
    threads: int | None = None
    """CPU threads per stage; None: the worker's share of the cores."""
    time_code: float | None = None
    allow_missing: bool = False
    deinstance: bool = False
    target: str | None = None
    """Where per-surface results go (vertex, texture, both) for every processor without its own target param."""

    def check(self) -> None:
        """Refuse, before any stage is sent, what would fail every stage: processors, params, threads."""
        build_steps(self.names(), self.params, target=self.target)
        check_threads(self.threads)

    def pipeline(self) -> Pipeline:
        """The pipeline of one stage in this worker: its run-time object uses ``threads``, else the worker's
        share of the cores."""
        threads = self.threads if self.threads is not None else worker_threads()
        runtime = Runtime(Tracer.from_scene, device=self.device, threads=threads)
        return Pipeline.build(self.names(), self.params, runtime=runtime, cache_dir=self.cache_dir, force=self.force,
                              target=self.target)

    def names(self) -> list[str] | None:
        return list(self.processors) if self.processors else None


@dataclass
class StageOutcome:
    """What became of one stage of a batch."""

    input: str
    output: str
    status: str
    """BAKED, UP_TO_DATE or FAILED."""
    error: str = ""
    report: BakeReport | None = None

    @property
    def seconds(self) -> float:
        return self.report.seconds if self.report else 0.0


def expand_inputs(patterns: list[str], list_file: str | None = None) -> list[str]:
    """Stage paths from arguments (a glob pattern the shell left alone is expanded here) and from a list
    file (one path or pattern per line; blank lines and # comments skipped), relative to the list
    file's folder. UsageError for a pattern that matches nothing or a list file that cannot be read."""
    entries = list(patterns)
    if list_file:
        try:
            lines = Path(list_file).read_text().splitlines()
        except OSError as error:
            raise UsageError(f"--list {list_file}: {error.strerror}") from None
        base = Path(list_file).parent
        entries += [line if os.path.isabs(line) else str(base / line)
                    for line in (raw.strip() for raw in lines) if line and not line.startswith("#")]
    paths: list[str] = []
    for entry in entries:
        if glob.has_magic(entry) and not Path(entry).exists():
            matches = sorted(glob.glob(entry, recursive=True))
            if not matches:
                raise UsageError(f"{entry}: matches no file")
            paths += matches
        else:
            paths.append(entry)
    unique = list(dict.fromkeys(paths))
    if not unique:
        raise UsageError("no stages to bake")
    return unique


def batch_outputs(inputs: list[str], output_dir: str | None) -> list[str]:
    """Each input's output layer: OUTDIR/<stem>.baked.usdc, or beside the input without OUTDIR.
    UsageError when two inputs would write one output."""
    outputs = []
    for path in inputs:
        folder = Path(output_dir) if output_dir else Path(path).parent
        stem = Path(path).name.split(".")[0] if Path(path).name.endswith(".baked.usdc") else Path(path).stem
        outputs.append(str(folder / f"{stem}.baked.usdc"))
    seen: dict[str, str] = {}
    for path, out in zip(inputs, outputs):
        key = str(Path(out).resolve())
        if key in seen:
            raise UsageError(f"{seen[key]} and {path} would both write {out}; bake them into different folders")
        seen[key] = path
    return outputs


def bake_stage(input_path: str, output: str, options: BatchOptions) -> StageOutcome:
    """Bake one stage in a worker; a failure is returned as the outcome, never raised."""
    start_warp_quietly(options.device)
    try:
        report = bake_file(input_path, output, options.pipeline(), time_code=options.time_code,
                           allow_missing=options.allow_missing, deinstance=options.deinstance)
    except (UsageError, ProcessorFailed) as error:
        return StageOutcome(input_path, output, FAILED, error=str(error))
    except Exception as error:  # any fault of this stage is this stage's failure, not the batch's
        return StageOutcome(input_path, output, FAILED, error=f"{type(error).__name__}: {error}")
    return StageOutcome(input_path, output, UP_TO_DATE if report.up_to_date else BAKED, report=report)


def bake_many(paths: list[str], output_dir: str | None = None, *, processors=None, params=None,
              device: str = "cpu", cache_dir: str | None = None, force: bool = False, threads: int | None = None,
              time: float | None = None, allow_missing: bool = False, deinstance: bool = False,
              scheduler: str | None = None, workers: int | None = None, target: str | None = None,
              on_outcome: Callable[[StageOutcome], None] | None = None) -> list[StageOutcome]:
    """Bake every stage of ``paths`` (paths or glob patterns) into ``output_dir`` (default: beside each).

    One task per stage: on a local pool of ``workers`` processes (default: one per core, at most one
    per stage), or on the Dask cluster at ``scheduler``. Processors and params are checked once, before
    any work (UsageError); each stage's own failure is its outcome's ``error``. ``on_outcome`` hears
    each stage as it ends. ``target``: as ``usdbake.bake``'s. Returns the outcomes in the order of the inputs.
    """
    inputs = expand_inputs([str(path) for path in paths])
    outputs = batch_outputs(inputs, output_dir)
    options = BatchOptions(tuple(processors) if processors else None, dict(params or {}), device, cache_dir, force,
                           threads, time, allow_missing, deinstance, target)
    options.check()  # before any work
    jobs = list(zip(inputs, outputs))
    report = on_outcome or (lambda outcome: None)
    if scheduler:
        client = connect(scheduler)
        try:
            done = _run_on_dask(client, jobs, options, report)
        finally:
            client.close()
    else:
        done = _run_on_pool(jobs, options, workers, report)
    return [done[job] for job in jobs]


def _run_on_pool(jobs: list[tuple[str, str]], options: BatchOptions, workers: int | None,
                 report: Callable[[StageOutcome], None]) -> dict:
    """Stages on a spawned process pool. A dead worker breaks the whole pool (and every stage in flight),
    so the stages that were in flight are re-run one by one in pools of their own: a stage that kills
    its worker again is the one reported."""
    cores = os.cpu_count() or 1
    workers = max(1, min(workers or cores, len(jobs)))
    done: dict = {}
    broken = _pool_pass(jobs, options, workers, max(1, cores // workers), done, report)
    for job in broken:
        if _pool_pass([job], options, 1, cores, done, report):
            outcome = StageOutcome(job[0], job[1], FAILED, error=WORKER_DIED)
            done[job] = outcome
            report(outcome)
    return done


def _pool_pass(jobs, options, workers: int, threads: int, done: dict, report) -> list:
    """Run jobs on one pool; the jobs lost to a broken pool are returned."""
    broken = []
    context = get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_set_worker_threads,
                             initargs=(threads,)) as pool:
        futures = {pool.submit(bake_stage, source, output, options): (source, output)
                   for source, output in largest_first(jobs)}
        for future in as_completed(futures):
            job = futures[future]
            try:
                outcome = future.result()
            except BrokenProcessPool:
                broken.append(job)
                continue
            done[job] = outcome
            report(outcome)
    return broken


def largest_first(jobs: list[tuple[str, str]]) -> list[tuple[str, str]]:
    """Stages in the order to start them: the largest files first (a cheap stand-in for the longest
    bakes), so the long ones do not end up last on one worker while the others wait."""
    def size(job):
        try:
            return os.path.getsize(job[0])
        except OSError:
            return 0
    return sorted(jobs, key=size, reverse=True)


def _set_worker_threads(threads: int) -> None:
    """Pool worker initializer: its share of the cores (read by cluster.worker_threads)."""
    os.environ[WORKER_THREADS_VARIABLE] = str(threads)


def _run_on_dask(client, jobs: list[tuple[str, str]], options: BatchOptions,
                 report: Callable[[StageOutcome], None]) -> dict:
    """Stages as Dask tasks; a worker that keeps dying on one (KilledWorker) fails that stage alone."""
    from distributed import as_completed as dask_completed

    futures = {client.submit(bake_stage, source, output, options, pure=False,
                             key=f"usdbake-stage-{index}-{Path(source).stem}"): (source, output)
               for index, (source, output) in enumerate(largest_first(jobs))}
    done: dict = {}
    for future in dask_completed(list(futures), loop=client.loop):
        job = futures[future]
        try:
            outcome = future.result()
        except Exception as error:  # KilledWorker, or a worker lost for good: this stage's failure
            killed = type(error).__name__ == "KilledWorker"
            outcome = StageOutcome(job[0], job[1], FAILED,
                                   error=WORKER_DIED if killed else f"{type(error).__name__}: {error}")
        done[job] = outcome
        report(outcome)
    return done
