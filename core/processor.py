"""The processor contract: Result, Context and the Processor base class.

A processor is pure compute: arrays in, arrays out, no pxr. It declares

- ``name``, ``version``, ``summary``,
- ``requires`` / ``provides``: product *types* (classes in a technique's products.py, or core.products),
- ``Params``: a frozen dataclass of ``param()`` fields (core.params),
- ``facets``: the Scene facets its fingerprint reads (see scene.FACETS),
- ``applies(ctx) -> (bool, reason)`` and ``run(ctx) -> Result``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar

from .chunks import SceneChunks
from .params import Params
from .records import Output
from .scene import Scene


@dataclass
class Result:
    """What a processor hands back: products for later processors, records for USD, figures for people."""

    products: dict[str, Any] = field(default_factory=dict)
    outputs: list[Output] = field(default_factory=list)
    stats: dict[str, float] = field(default_factory=dict)
    """Figures for the summary, e.g. {'rays': 1.2e7}."""
    messages: list[str] = field(default_factory=list)
    """Warnings for people (e.g. prims that were not baked, and why)."""


class Context:
    """Everything ``applies`` and ``run`` may read: the scene, params, upstream products, and what the run's
    ``core.runtime.Runtime`` holds for the scene (tracer, chunk runner, device, threads).

    ``tracer`` is either a built Tracer or a zero-argument factory; the factory
    runs on first access, so a processor that never traces never builds a BVH,
    and ``applies()`` and ``run()`` of every step share one.
    """

    def __init__(self, scene: Scene, params: Params, tracer: Any = None, products: dict | None = None,
                 progress: Callable[[float], None] | None = None, *, device: str = "cpu", threads: int | None = None,
                 chunks: SceneChunks | None = None):
        self.scene = scene
        self.device, self.threads = device, threads
        """Where kernels run, and CPU threads (None: every core); for processors that build BVHs of their own."""
        self.params = params
        self.products = dict(products or {})
        self.progress = progress or (lambda fraction: None)
        """Report progress in [0, 1] on long work."""
        self._tracer = tracer
        self.chunks = chunks if chunks is not None else SceneChunks(lambda: self.tracer)
        """Where work split by receivers runs (core.chunks): in process, or on a Dask cluster."""

    @property
    def tracer(self) -> Any:
        """The scene's usdbake.kernels.tracer.Tracer, one per scene and run."""
        if callable(self._tracer):
            self._tracer = self._tracer()
        return self._tracer


class Processor:
    """Base class: subclass, set the class attributes, implement applies and run."""

    name: ClassVar[str] = ""
    version: ClassVar[str] = "1"
    requires: ClassVar[tuple[str, ...]] = ()
    provides: ClassVar[tuple[str, ...]] = ()
    facets: ClassVar[tuple[str, ...]] = ("geometry",)
    writes: ClassVar[tuple[str, ...]] = ()
    """Properties it authors on prims it does not define itself (the receivers' meshes, prototypes,
    materials): full names (``primvars:bake:ao``), or a namespace ending in ``:`` (``bake:field:``).
    Two processors in one run may not share one; the runner checks before any compute."""
    follows_refinement: ClassVar[bool] = False
    """It writes per-vertex or per-face results on receiver meshes: in a run with a processor that
    provides RefinedScene (a mesh refiner), it runs after it on the refined Scene, and so does
    everything it requires, so its results fit the re-authored topology."""
    refined_by: ClassVar[str] = ""
    """A mesh refiner (a processor providing RefinedScene) the run adds when this step's ``refine`` param
    is true and no refiner is in the run: per-vertex light on a floor of two triangles cannot follow a
    window's light across it. The refiner's own ``applies`` still decides (a closed box is not refined)."""
    Params: ClassVar[type[Params]] = Params
    summary: ClassVar[str] = ""

    def __init__(self, params: Params | None = None):
        self.params = params if params is not None else self.Params()
        """This step's params, so applies() can decide with them (e.g. a cost model)."""

    def applies(self, ctx: Context) -> tuple[bool, str]:
        """(True, why it runs or "") or (False, why it does not apply)."""
        return True, ""

    def needs_refinement(self, scene) -> tuple[bool, str]:
        """Whether the ``refined_by`` refiner this step added to the run should refine ``scene``: (True, "")
        or (False, why not)."""
        return True, ""

    def run(self, ctx: Context) -> Result:  # pragma: no cover - abstract
        raise NotImplementedError
