"""core.processor on its own: ``Context`` builds the tracer lazily, once, and shares it with its chunk
runner; it copies the products it is given and defaults progress to a no-op; ``Processor`` defaults
(params from its Params class, applies -> (True, ""), run not implemented); ``Result`` containers are
fresh per instance."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from patch_scenes import box_parts, make_scene
from usdbake.core.chunks import SceneChunks
from usdbake.core.params import ParamError, Params, param
from usdbake.core.processor import Context, Processor, Result
from usdbake.kernels.tracer import Tracer


def scene():
    return make_scene(box_parts())


def test_the_tracer_factory_runs_once_on_first_use():
    built = []
    s = scene()

    def factory():
        built.append(1)
        return Tracer(s.points, s.tri_vertices)

    ctx = Context(s, Params(), factory)
    assert built == []  # nothing built until a processor traces
    tracer = ctx.tracer
    assert isinstance(tracer, Tracer) and built == [1]
    assert ctx.tracer is tracer and built == [1]
    # The default chunk runner traces with the same tracer, and does not build another.
    assert ctx.chunks.tracer is tracer and built == [1]
    # From inside a chunk, too: one ray from the box's centre up meets the lid at 0.5.
    t = ctx.chunks.map(lambda tr, start, o, d: tr.closest_hit(o, d).hit_t,
                       (np.float32([[0.5, 0.5, 0.5]]), np.float32([[0, 0, 1]])))
    assert t.tolist() == [0.5] and built == [1]


def test_the_chunk_runner_alone_builds_the_tracer_the_context_then_reuses():
    built = []
    s = scene()
    ctx = Context(s, Params(), lambda: built.append(1) or Tracer(s.points, s.tri_vertices))
    tracer = ctx.chunks.tracer
    assert built == [1] and ctx.tracer is tracer and built == [1]


def test_a_built_tracer_and_no_tracer_are_kept_as_given():
    s = scene()
    tracer = Tracer(s.points, s.tri_vertices)
    assert Context(s, Params(), tracer).tracer is tracer
    assert Context(s, Params()).tracer is None
    chunks = SceneChunks(tracer)
    assert Context(s, Params(), chunks=chunks).chunks is chunks


def test_context_copies_products_and_defaults():
    products = {"a": 1}
    ctx = Context(scene(), Params(), products=products, threads=3)
    ctx.products["b"] = 2
    assert products == {"a": 1}  # the caller's dict is not the step's
    assert Context(scene(), Params()).products == {}
    assert ctx.progress(0.5) is None  # a no-op by default
    assert (ctx.device, ctx.threads) == ("cpu", 3)
    seen = []
    Context(scene(), Params(), progress=seen.append).progress(0.25)
    assert seen == [0.25]


@dataclass(frozen=True)
class CountParams(Params):
    count: int = param(4, "how many", low=1, high=10)


class Counter(Processor):
    name = "counter"
    Params = CountParams


def test_processor_defaults():
    p = Counter()
    assert isinstance(p.params, CountParams) and p.params.count == 4
    given = CountParams(count=7)
    assert Counter(given).params is given
    assert p.applies(Context(scene(), p.params)) == (True, "")
    with pytest.raises(NotImplementedError):
        p.run(Context(scene(), p.params))
    with pytest.raises(ParamError):
        CountParams(count=11)  # bounds checked at construction, before a processor gets them
    base = Processor()
    assert (base.name, base.version, base.requires, base.provides) == ("", "1", (), ())
    assert (base.facets, base.writes, base.follows_refinement) == (("geometry",), (), False)
    assert type(base.params) is Params


def test_results_do_not_share_their_containers():
    a, b = Result(), Result()
    a.products["x"] = 1
    a.outputs.append("o")
    a.stats["rays"] = 1.0
    a.messages.append("m")
    assert (b.products, b.outputs, b.stats, b.messages) == ({}, [], {}, [])
