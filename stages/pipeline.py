"""The DAG runner: resolve, order, skip, cache, time and run processors.

Processors meet only through named products: a processor that ``requires``
a product depends on the one processor that ``provides`` it. The graph is
checked when the pipeline is built (one producer per product, every
requirement produced, no cycles). Each step's cache key is its name,
version and params plus the fingerprint of the Scene facets it reads and the
keys of the steps it depends on.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import json
import pickle
import time
from dataclasses import dataclass, field
from graphlib import CycleError, TopologicalSorter
from pathlib import Path
from typing import Callable

from ..processors import base
from ..processors.scene import Scene
from ..processors.tracer import shared_tracer
from .errors import UsageError

DEFAULT_PROCESSORS = ("ambient_occlusion",)


class GraphError(UsageError):
    """The requested processors do not form a valid graph."""


class ProcessorFailed(RuntimeError):
    """A processor raised; nothing was written."""

    def __init__(self, name: str, error: BaseException):
        self.name, self.error = name, error
        super().__init__(f"processor {name!r} failed: {type(error).__name__}: {error}")


@dataclass
class Step:
    """One processor in the plan, and after running, what happened to it."""

    name: str
    processor: base.Processor
    params: base.Params
    key: str = ""
    action: str = "run"
    """'run', 'cached' (up to date) or 'skip' (not applicable)."""
    reason: str = ""
    seconds: float = 0.0
    rays: float = 0.0
    result: base.Result | None = None

    @property
    def mrays_per_second(self) -> float:
        return self.rays / self.seconds / 1e6 if self.seconds > 0 and self.rays else 0.0

    def report(self) -> dict:
        return {"processor": self.name, "action": self.action, "reason": self.reason,
                "seconds": round(self.seconds, 4), "rays": self.rays,
                "mrays_per_s": round(self.mrays_per_second, 3), "fingerprint": self.key,
                "params": self.params.as_dict(),
                "messages": list(self.result.messages) if self.result else []}


def build_steps(names: list[str] | tuple[str, ...] | None, params: dict[str, dict] | None = None) -> list[Step]:
    """Requested processors plus everything they depend on, in dependency order."""
    params = dict(params or {})
    registry = base.registry()
    for name in params:
        if name not in registry:
            raise base.ParamError(f"parameters given for unknown processor {name!r}")
    producers: dict[str, str] = {}
    for name, cls in registry.items():
        for product in cls.provides:
            if product in producers:
                raise GraphError(f"product {product!r} is provided by both {producers[product]!r} and {name!r}")
            producers[product] = name

    wanted, pending = [], list(names or DEFAULT_PROCESSORS)
    graph: dict[str, set[str]] = {}
    while pending:
        name = pending.pop()
        if name in graph:
            continue
        cls = base.get(name)
        deps = set()
        for product in cls.requires:
            if product not in producers:
                raise GraphError(f"{name!r} requires {product!r}, which no processor provides")
            deps.add(producers[product])
        graph[name] = deps
        wanted.append(name)
        pending.extend(deps)
    try:
        order = list(TopologicalSorter(graph).static_order())
    except CycleError as error:
        raise GraphError(f"processors depend on each other in a cycle: {' -> '.join(error.args[1])}") from None
    steps = []
    for name in order:
        cls = registry[name]
        step_params = cls.Params.from_dict(params.get(name, {}))
        steps.append(Step(name, cls(step_params), step_params))
    return steps


def code_fingerprint(cls: type) -> str:
    """Hash of the code a processor runs: the processors package plus the class's own module
    (third-party processors live elsewhere), so an edited kernel never serves a stale cached result."""
    files = sorted(Path(base.__file__).parent.rglob("*.py"))
    own = inspect.getsourcefile(cls)
    if own and Path(own).is_file() and Path(own) not in files:
        files.append(Path(own))
    return _digest_files(tuple((str(f), f.stat().st_mtime_ns, f.stat().st_size) for f in files))


@functools.lru_cache(maxsize=64)
def _digest_files(stamped: tuple) -> str:
    digest = hashlib.sha256()
    for path, _, _ in stamped:
        digest.update(path.encode())
        digest.update(Path(path).read_bytes())
    return digest.hexdigest()


def step_key(step: Step, scene: Scene, upstream_keys: list[str]) -> str:
    payload = {
        "name": step.name, "version": step.processor.version, "code": code_fingerprint(type(step.processor)),
        "params": repr(sorted(step.params.as_dict().items())),
        "scene": scene.fingerprint(step.processor.facets), "upstream": upstream_keys,
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:32]


class ResultCache:
    """Pickled Results on disk, one file per step key; no directory means no caching."""

    def __init__(self, directory: str | Path | None):
        self.directory = Path(directory) if directory else None

    def path(self, name: str, key: str) -> Path | None:
        return self.directory / f"{name}-{key}.pkl" if self.directory else None

    def load(self, name: str, key: str) -> base.Result | None:
        path = self.path(name, key)
        if path is None or not path.exists():
            return None
        try:
            with open(path, "rb") as handle:
                return pickle.load(handle)
        except (OSError, pickle.UnpicklingError, EOFError, AttributeError):
            return None  # unreadable or from an incompatible version: recompute

    def store(self, name: str, key: str, result: base.Result) -> None:
        path = self.path(name, key)
        if path is None:
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        temp = path.with_suffix(".tmp")
        with open(temp, "wb") as handle:
            pickle.dump(result, handle, protocol=pickle.HIGHEST_PROTOCOL)
        temp.replace(path)


@dataclass
class Pipeline:
    """Plan and run processors on one Scene, sharing one Tracer."""

    steps: list[Step]
    device: str = "cpu"
    cache: ResultCache = field(default_factory=lambda: ResultCache(None))
    force: bool = False
    threads: int | None = None

    @classmethod
    def build(cls, names=None, params=None, *, device="cpu", cache_dir=None, force=False, threads=None):
        return cls(build_steps(names, params), device=device, cache=ResultCache(cache_dir), force=force,
                   threads=threads)

    def plan(self, scene: Scene) -> list[Step]:
        """Decide per step: run, cached (up to date) or skip (not applicable), with the reason."""
        keys: dict[str, str] = {}
        skipped: set[str] = set()
        producers = {product: step.name for step in self.steps for product in step.processor.provides}
        for step in self.steps:
            upstream = sorted({producers[p] for p in step.processor.requires})
            step.key = step_key(step, scene, [keys[name] for name in upstream])
            keys[step.name] = step.key
            blocked = [name for name in upstream if name in skipped]
            applies, why = step.processor.applies(scene)
            if blocked:
                step.action, step.reason = "skip", f"requires {', '.join(blocked)} (skipped)"
            elif not applies:
                step.action, step.reason = "skip", f"not applicable: {why}"
            elif not self.force and self.cache.path(step.name, step.key) and \
                    self.cache.path(step.name, step.key).exists():
                step.action, step.reason = "cached", "up to date: fingerprint unchanged"
            else:
                step.action, step.reason = "run", "forced" if self.force else why
            if step.action == "skip":
                skipped.add(step.name)
        return self.steps

    def run(self, scene: Scene, *, on_progress: Callable[[str, float], None] | None = None) -> list[Step]:
        """Run the plan; raises ProcessorFailed (nothing is written by the runner itself)."""
        self.plan(scene)
        products: dict = {}
        tracer = None
        for step in self.steps:
            if step.action == "skip":
                continue
            started = time.perf_counter()
            if on_progress:
                on_progress(step.name, 0.0)
            result = self.cache.load(step.name, step.key) if step.action == "cached" else None
            if result is None:
                step.action = "run"
                if tracer is None and step.processor.uses_tracer:
                    tracer = shared_tracer(scene, device=self.device, threads=self.threads)
                ctx = base.Context(scene=scene, params=step.params, tracer=tracer,
                                   products={p: products[p] for p in step.processor.requires},
                                   progress=(lambda f, n=step.name: on_progress(n, f)) if on_progress else
                                   (lambda f: None))
                try:
                    result = step.processor.run(ctx)
                except Exception as error:  # report which processor failed, and why
                    raise ProcessorFailed(step.name, error) from error
                self.cache.store(step.name, step.key, result)
                step.rays = float(result.stats.get("rays", 0.0))
            step.seconds = time.perf_counter() - started
            step.result = result
            products.update(result.products)
            if on_progress:
                on_progress(step.name, 1.0)
        return self.steps

    def outputs(self) -> list:
        """Every step's output records; two steps writing the same property at the same time is an error."""
        writers: dict[tuple, str] = {}
        records = []
        for step in self.steps:
            for record in step.result.outputs if step.result else []:
                if isinstance(record, (base.Primvar, base.Attribute)):
                    name = f"primvars:{record.name}" if isinstance(record, base.Primvar) else record.name
                    key = (record.prim, name, record.time)
                    if writers.setdefault(key, step.name) != step.name:
                        raise UsageError(f"{record.prim}.{name} is written by both {writers[key]} and {step.name}; "
                                         f"run one of them")
                records.append(record)
        return records

    def provenance(self, extra: dict | None = None) -> dict:
        from .. import __version__

        data = {"version": __version__, "device": self.device,
                "processors": {step.name: {"action": step.action, "reason": step.reason,
                                           "params": step.params.as_dict(), "fingerprint": step.key,
                                           "seconds": round(step.seconds, 4)} for step in self.steps}}
        data.update(extra or {})
        return data
