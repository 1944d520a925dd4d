"""The DAG runner: resolve, order, skip, cache, time and run processors.

Processors meet only through typed products (classes, see core.products): a
processor that ``requires`` a product type depends on the one processor that
``provides`` it. The graph is checked when the pipeline is built (every
product a type, one producer per product, every
requirement produced, no cycles). Each step's cache key is its name,
version and params plus the fingerprint of the Scene facets it reads and the
keys of the steps it depends on. Every step reads the one run-time object of the run
(core.runtime.Runtime: device, threads, the scene's BVH, the chunk runner) through its Context.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from graphlib import CycleError, TopologicalSorter
from typing import Callable, Collection

import numpy as np

from .cache import ResultCache, step_key
from .errors import UsageError
from .params import ParamError, Params
from .processor import Context, Processor, Result
from .products import RefinedScene
from .records import Attribute, Prim, Primvar, Relationship
from .registry import get as get_processor
from .registry import registry as all_processors
from .runtime import Runtime
from .scene import Scene
from .version import __version__

DEFAULT_PROCESSORS = ("ambient_occlusion",)


class GraphError(UsageError):
    """The requested processors do not form a valid graph."""


class ParamsOutsideRun(ParamError):
    """Params given for a processor that is not part of the run: they would be ignored."""

    def __init__(self, processor: str, running: list[str]):
        self.processor, self.running = processor, tuple(running)
        super().__init__(f"params for {processor!r}, which is not part of this run ({', '.join(running)}); "
                         f"add it to the processors")


class ProcessorFailed(RuntimeError):
    """A processor raised; nothing was written."""

    def __init__(self, name: str, error: BaseException):
        self.name, self.error = name, error
        super().__init__(f"processor {name!r} failed: {type(error).__name__}: {error}")


@dataclass
class Step:
    """One processor in the plan, and after running, what happened to it."""

    name: str
    processor: Processor
    params: Params
    key: str = ""
    after: tuple[str, ...] = ()
    """A mesh refiner this step runs after, on its refined Scene (Processor.follows_refinement)."""
    requested: bool = True
    """Asked for by name (or a default), not only pulled in as another step's dependency."""
    asked_by: str = ""
    """The step whose ``refined_by`` added this refiner to the run (its reason says so)."""
    action: str = "run"
    """'run', 'cached' (up to date) or 'skip' (not applicable)."""
    reason: str = ""
    seconds: float = 0.0
    rays: float = 0.0
    result: Result | None = None

    @property
    def mrays_per_second(self) -> float:
        return self.rays / self.seconds / 1e6 if self.seconds > 0 and self.rays else 0.0

    def report(self) -> dict:
        return {"processor": self.name, "action": self.action, "reason": self.reason,
                "seconds": round(self.seconds, 4), "rays": self.rays,
                "mrays_per_s": round(self.mrays_per_second, 3), "fingerprint": self.key,
                "params": self.params.as_dict(),
                "messages": list(self.result.messages) if self.result else []}


def build_steps(names: list[str] | tuple[str, ...] | None, params: dict[str, dict] | None = None, *,
                allow_conflicts: bool = False, ignorable: Collection[str] = (), target: str | None = None) -> list[Step]:
    """Requested processors plus everything they depend on, in dependency order. Two of them declaring
    one property in ``writes`` is a GraphError unless ``allow_conflicts`` (``plan`` lists them instead).
    ``target`` (vertex, texture, both: ``--target``) is the ``target`` param of every step that has one and
    is not given its own in ``params``.

    The one check of ``params`` against the run: ParamError for an unknown processor, ParamsOutsideRun
    for one the run does not hold, unless ``ignorable`` names it (a shared config file's table)."""
    params = dict(params or {})
    registry = all_processors()
    for name in params:
        if name not in registry:
            raise ParamError(f"parameters given for unknown processor {name!r}")
    if target is not None:
        if target not in TARGETS:
            raise ParamError(f"target={target!r} is not one of {list(TARGETS)}")
        with_target = {name for name, cls in registry.items()
                       if any(f.name == "target" for f in dataclasses.fields(cls.Params))}
        params = {**params, **{name: {"target": target, **params.get(name, {})} for name in with_target}}
    producers: dict[str, str] = {}
    for name, cls in registry.items():
        for product in (*cls.provides, *cls.requires):
            if not isinstance(product, type):
                raise GraphError(f"{name!r}: product {product!r} is not a type (see usdbake.core.products)")
        for product in cls.provides:
            if product in producers:
                raise GraphError(f"product {product.__name__} is provided by both {producers[product]!r} and "
                                 f"{name!r}")
            producers[product] = name

    requested = set(names or DEFAULT_PROCESSORS)
    wanted, pending = [], list(requested)
    graph: dict[str, set[str]] = {}
    asked: dict[str, str] = {}
    while pending:
        name = pending.pop()
        if name in graph:
            continue
        cls = get_processor(name)
        deps = set()
        for product in cls.requires:
            if product not in producers:
                raise GraphError(f"{name!r} requires {product.__name__}, which no processor provides")
            deps.add(producers[product])
        graph[name] = deps
        wanted.append(name)
        pending.extend(deps)
        if not pending and not asked:
            asked = _refiners_asked_for(wanted, params, registry)
            pending.extend(asked)
    if not allow_conflicts and write_conflicts(wanted, registry):
        raise GraphError(write_conflicts(wanted, registry)[0])
    after = _after_refinement(wanted, graph, registry)
    for name, refiner in after.items():
        graph[name].add(refiner)
    try:
        order = list(TopologicalSorter(graph).static_order())
    except CycleError as error:
        raise GraphError(f"processors depend on each other in a cycle: {' -> '.join(error.args[1])}") from None
    steps = []
    for name in order:
        cls = registry[name]
        step_params = cls.Params.from_dict(params.get(name, {}))
        steps.append(Step(name, cls(step_params), step_params, after=(after[name],) if name in after else (),
                          requested=name in requested, asked_by=asked.get(name, "")))
    for name in outside_run(params, steps):
        if name not in ignorable and (target is None or set(params[name]) != {"target"}):
            raise ParamsOutsideRun(name, [step.name for step in steps])
    return steps


def outside_run(params: dict, steps: list[Step]) -> list[str]:
    """The processors ``params`` names that ``steps`` do not hold (their params would be ignored)."""
    running = {step.name for step in steps}
    return [name for name in params if name not in running]


def _refiners_asked_for(wanted: list[str], params: dict, registry: dict) -> dict[str, str]:
    """{refiner: the step asking for it}: for a run without a mesh refiner, the first ``refined_by`` of a
    wanted step whose ``refine`` param is true and whose results go to vertices (Processor.refined_by): the
    texture target changes no mesh."""
    if any(RefinedScene in registry[name].provides for name in wanted):
        return {}
    for name in sorted(wanted):
        cls = registry[name]
        values = cls.Params.from_dict(params.get(name, {})).as_dict()
        if cls.refined_by and values.get("refine", False) and values.get("target", "vertex") == "vertex":
            return {cls.refined_by: name}
    return {}


def _after_refinement(wanted: list[str], graph: dict[str, set[str]], registry: dict) -> dict[str, str]:
    """{step: the refiner it runs after}: processors that follow refinement, and what they require,
    in a run with a processor providing RefinedScene (not the refiner's own dependencies)."""
    refiners = [name for name in wanted if RefinedScene in registry[name].provides]
    if not refiners:
        return {}
    refiner = refiners[0]
    upstream, pending = set(), [refiner]
    while pending:
        for dep in graph[pending.pop()]:
            if dep not in upstream:
                upstream.add(dep)
                pending.append(dep)
    chosen, pending = set(), [name for name in wanted if registry[name].follows_refinement]
    while pending:
        name = pending.pop()
        if name in chosen or name == refiner or name in upstream:
            continue
        chosen.add(name)
        pending.extend(graph[name])
    return {name: refiner for name in chosen}


TARGETS = ("vertex", "texture", "both")
"""Where per-surface results go (``core.params.TextureTargetParams.target``)."""
SHARED_WRITES = ("primvars:bake:lightmapST",)
"""Properties several processors may author in one run when they author one value: the texture target's
generated lightmap UVs (every processor lays out the same atlas from the same scene and texture params)."""


def writes_overlap(a: str, b: str) -> bool:
    """Two declared property names (or ``namespace:`` prefixes) can name one property."""
    return a == b or (a.endswith(":") and b.startswith(a)) or (b.endswith(":") and a.startswith(b))


def write_conflicts(names: list[str], registry: dict) -> list[str]:
    """One line per pair of the named processors that declare a property both would author."""
    lines = []
    names = sorted(names)
    for i, first in enumerate(names):
        for second in names[i + 1:]:
            shared = [a for a in registry[first].writes for b in registry[second].writes
                      if writes_overlap(a, b) and a not in SHARED_WRITES]
            if shared:
                lines.append(f"{first} and {second} both write {shared[0]}; run one of them")
    return lines


def declared(step: Step, record, defined: set[str]) -> bool:
    """The record authors a property on a prim its step defines, or one its step declares in ``writes``."""
    if any(record.prim == path or record.prim.startswith(path + "/") for path in defined):
        return True
    name = f"primvars:{record.name}" if isinstance(record, Primvar) else record.name
    return any(name == w or (w.endswith(":") and name.startswith(w)) for w in step.processor.writes)


def checked_products(step: Step, result: Result) -> dict:
    """The step's products, each an instance of a type it declares in ``provides``."""
    for kind, value in result.products.items():
        if kind not in step.processor.provides or not isinstance(value, kind):
            raise ProcessorFailed(step.name, TypeError(
                f"product {getattr(kind, '__name__', kind)!r} ({type(value).__name__}) is not one of its declared "
                f"types {[t.__name__ for t in step.processor.provides]}"))
    return result.products


@dataclass
class Pipeline:
    """Plan and run processors on one Scene; every step reads the one Runtime of the run."""

    steps: list[Step]
    runtime: Runtime
    cache: ResultCache = field(default_factory=lambda: ResultCache(None))
    force: bool = False
    ignored_params: tuple[str, ...] = ()
    """The processors whose params were left out as ``ignorable``: they are not part of this run."""

    def context(self, step: Step, scene: Scene, products: dict | None = None, progress=None) -> Context:
        """What ``applies`` and ``run`` of ``step`` read: its params and products, and the runtime's tracer,
        chunk runner, device and threads for ``scene``."""
        runtime = self.runtime
        return Context(scene=scene, params=step.params, tracer=lambda: runtime.tracer(scene), products=products,
                       progress=progress, device=runtime.device, threads=runtime.threads,
                       chunks=runtime.scene_chunks(scene))

    @classmethod
    def build(cls, names=None, params=None, *, runtime: Runtime, cache_dir=None, force=False,
              allow_conflicts=False, ignorable: Collection[str] = (), target: str | None = None) -> "Pipeline":
        """The steps of ``names`` (see build_steps, which checks ``params`` and applies ``target``) run with
        ``runtime``."""
        steps = build_steps(names, params, allow_conflicts=allow_conflicts, ignorable=ignorable, target=target)
        return cls(steps, runtime, cache=ResultCache(cache_dir), force=force,
                   ignored_params=tuple(outside_run(params or {}, steps)))

    def conflicts(self) -> list[str]:
        """The pairs of its steps that would author one property (see Processor.writes)."""
        return write_conflicts([step.name for step in self.steps], {step.name: type(step.processor)
                                                                     for step in self.steps})

    def plan(self, scene: Scene) -> list[Step]:
        """Decide per step: run, cached (up to date) or skip (not applicable), with the reason."""
        keys: dict[str, str] = {}
        skipped: set[str] = set()
        producers = {product: step.name for step in self.steps for product in step.processor.provides}
        for step in self.steps:
            upstream = sorted({producers[p] for p in step.processor.requires})
            step.key = step_key(step, scene, [keys[name] for name in sorted({*upstream, *step.after})])
            keys[step.name] = step.key
            blocked = [name for name in upstream if name in skipped]
            applies, why = step.processor.applies(self.context(step, scene))
            if applies and step.asked_by:
                asker = next(other for other in self.steps if other.name == step.asked_by)
                applies, why = asker.processor.needs_refinement(scene)
                why = why and f"{step.asked_by} needs no refinement here: {why}"
            if blocked:
                step.action, step.reason = "skip", f"requires {', '.join(blocked)} (skipped)"
            elif not applies:
                step.action, step.reason = "skip", f"not applicable: {why}"
            elif not self.force and self.cache.has(step.name, step.key):
                step.action, step.reason = "cached", "up to date: fingerprint unchanged"
            else:
                step.action, step.reason = "run", "forced" if self.force else why
            if step.asked_by and step.action != "skip":
                step.reason = f"refines the mesh for {step.asked_by} (its refine parameter)"
            if step.action == "skip":
                skipped.add(step.name)
        self._skip_unneeded_dependencies()
        return self.steps

    def _skip_unneeded_dependencies(self) -> None:
        """Skip a step nobody asked for whose every consumer is skipped: its work would be thrown away
        (form_factors for a radiosity that does not apply, displacement_fields for a skipped instance_ao)."""
        for step in reversed(self.steps):
            if step.requested or step.action == "skip":
                continue
            consumers = [other for other in self.steps if step.name in other.after
                         or set(step.processor.provides) & set(other.processor.requires)]
            if consumers and all(other.action == "skip" for other in consumers):
                names = ", ".join(other.name for other in consumers)
                step.action, step.reason = "skip", f"needed only by {names} (skipped)"

    def run(self, scene: Scene, *, on_progress: Callable[[str, float], None] | None = None,
            before_compute: Callable[[list[Step]], None] | None = None) -> list[Step]:
        """Run the plan; raises ProcessorFailed (nothing is written by the runner itself).

        ``before_compute(steps)`` is called once the plan is made and before any step runs: the place
        for checks of the input that depend on which steps run (it raises to stop the bake).
        """
        self.plan(scene)
        if before_compute:
            before_compute(self.steps)
        products: dict = {}
        for step in self.steps:
            if step.action == "skip":
                continue
            started = time.perf_counter()
            if on_progress:
                on_progress(step.name, 0.0)
            result = None
            if step.action == "cached":  # checked against the topology its records go on (refined, once refined)
                fit = products[RefinedScene].scene if RefinedScene in products else scene
                result = self.cache.load(step.name, step.key, scene=fit, provides=step.processor.provides)
                if result is None:
                    step.reason = "cache entry unusable (see the warning); recomputed"
            if result is None:
                step.action = "run"
                step_scene = products[RefinedScene].scene if step.after and RefinedScene in products else scene
                ctx = self.context(step, step_scene, {p: products[p] for p in step.processor.requires},
                                   (lambda f, n=step.name: on_progress(n, f)) if on_progress else None)
                try:
                    result = step.processor.run(ctx)
                except UsageError:
                    raise  # the user's input (a file a parameter names), not a processor fault: exit 2
                except Exception as error:  # report which processor failed, and why
                    raise ProcessorFailed(step.name, error) from error
                self.cache.store(step.name, step.key, result)
                step.rays = float(result.stats.get("rays", 0.0))
            step.seconds = time.perf_counter() - started
            step.result = result
            products.update(checked_products(step, result))
            if on_progress:
                on_progress(step.name, 1.0)
        return self.steps

    def outputs(self) -> list:
        """Every step's output records; two steps writing the same property at the same time is an error."""
        writers: dict[tuple, str] = {}
        shared_values: dict[tuple, object] = {}
        records = []
        for step in self.steps:
            outputs = step.result.outputs if step.result else []
            defined = {record.path for record in outputs if isinstance(record, Prim) and record.type_name}
            for record in outputs:
                if isinstance(record, (Primvar, Attribute, Relationship)):
                    if not declared(step, record, defined):
                        raise ProcessorFailed(step.name, TypeError(
                            f"it wrote {record.prim}.{record.name}, which its `writes` does not declare"))
                    name = f"primvars:{record.name}" if isinstance(record, Primvar) else record.name
                    key = (record.prim, name, getattr(record, "time", None))
                    if name in SHARED_WRITES and key in shared_values:
                        if np.array_equal(shared_values[key], record.values):
                            continue
                        raise UsageError(f"{record.prim}.{name} is written with different values by "
                                         f"{writers[key]} and {step.name}; give both the same texture "
                                         f"parameters (texel_density, max_texture_size)")
                    if name in SHARED_WRITES:
                        shared_values[key] = record.values
                    if writers.setdefault(key, step.name) != step.name:
                        raise UsageError(f"{record.prim}.{name} is written by both {writers[key]} and {step.name}; "
                                         f"run one of them")
                records.append(record)
        return records

    def provenance(self, extra: dict | None = None) -> dict:
        data = {"version": __version__, "device": self.runtime.device,
                "processors": {step.name: {"action": step.action, "reason": step.reason,
                                           "params": step.params.as_dict(), "fingerprint": step.key,
                                           "seconds": round(step.seconds, 4),
                                           "messages": list(step.result.messages) if step.result else []}
                               for step in self.steps}}
        data.update(extra or {})
        return data
