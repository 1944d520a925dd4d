"""The processor contract, output records and the processor registry.

A processor is pure compute: arrays in, arrays out, no pxr. It declares

- ``name``, ``version`` and ``requires`` (products of upstream processors),
- ``provides`` (the products it hands downstream),
- ``Params``: a frozen dataclass whose fields carry defaults, bounds and a
  one-line doc (``param()``), validated at construction,
- ``facets``: the Scene facets its fingerprint reads (see scene.FACETS),
- ``applies(scene) -> (bool, reason)`` and ``run(ctx) -> Result``.

What to author in USD is described by plain records (Primvar, Attribute,
Prim, Texture); ``usdbake.stages.bake_layer`` turns them into USD.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, Callable, ClassVar

import numpy as np

from .scene import Scene

ENTRY_POINT_GROUP = "usdbake.processors"


class ParamError(ValueError):
    """A parameter name or value a user gave is not valid."""


# ---------------------------------------------------------------------------
# Params


def param(default: Any, doc: str, *, low: float | None = None, high: float | None = None,
          choices: tuple | None = None):
    """A Params field with a default, optional bounds or choices, and one line of doc."""
    return field(default=default, metadata={"doc": doc, "low": low, "high": high, "choices": choices})


@dataclass(frozen=True)
class Params:
    """Base class of processor parameters: bounds are checked at construction."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            meta = f.metadata
            if meta.get("choices") is not None and value not in meta["choices"]:
                raise ParamError(f"{f.name}={value!r} is not one of {list(meta['choices'])}")
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                if isinstance(value, float) and math.isnan(value):
                    raise ParamError(f"{f.name}=nan is not a number")
                if meta.get("low") is not None and value < meta["low"]:
                    raise ParamError(f"{f.name}={value!r} is below the minimum {meta['low']}")
                if meta.get("high") is not None and value > meta["high"]:
                    raise ParamError(f"{f.name}={value!r} is above the maximum {meta['high']}")

    @classmethod
    def describe(cls) -> list[dict]:
        """One row per parameter: name, type, default, bounds and doc."""
        rows = []
        for f in dataclasses.fields(cls):
            rows.append({
                "name": f.name, "type": _type_name(f.type), "default": f.default,
                "low": f.metadata.get("low"), "high": f.metadata.get("high"),
                "choices": f.metadata.get("choices"), "doc": f.metadata.get("doc", ""),
            })
        return rows

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "Params":
        """Build from user values (strings from the CLI are converted to the field type)."""
        known = {f.name: f for f in dataclasses.fields(cls)}
        kwargs = {}
        for name, value in values.items():
            if name not in known:
                raise ParamError(f"unknown parameter {name!r} (known: {', '.join(known) or 'none'})")
            kwargs[name] = _convert(name, value, known[name].default)
        return cls(**kwargs)

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _type_name(annotation) -> str:
    return annotation if isinstance(annotation, str) else getattr(annotation, "__name__", str(annotation))


def _convert(name: str, value: Any, default: Any) -> Any:
    if not isinstance(value, str) or isinstance(default, str):
        return _check_type(name, value, default)
    text = value.strip()
    try:
        if isinstance(default, bool):
            lowered = text.lower()
            if lowered in ("1", "true", "yes", "on"):
                return True
            if lowered in ("0", "false", "no", "off"):
                return False
            raise ValueError(text)
        if isinstance(default, int):
            return int(text)
        if isinstance(default, float):
            return float(text)
    except ValueError:
        raise ParamError(f"{name}={value!r} is not a valid {type(default).__name__}") from None
    return value


def _check_type(name: str, value: Any, default: Any) -> Any:
    """Non-string values (TOML, Python) must have the field's type: True is not a sample count."""
    is_bool = isinstance(value, (bool, np.bool_))
    if isinstance(default, bool):
        ok, converted = is_bool, bool(value) if is_bool else value
    elif isinstance(default, int):
        ok = isinstance(value, (int, np.integer)) and not is_bool
        converted = int(value) if ok else value
    elif isinstance(default, float):
        ok = isinstance(value, (int, float, np.integer, np.floating)) and not is_bool
        converted = float(value) if ok else value
    else:
        return value
    if not ok:
        raise ParamError(f"{name}={value!r} is not a valid {type(default).__name__}")
    return converted


# ---------------------------------------------------------------------------
# Output records: what to author, described without pxr.


@dataclass(frozen=True)
class Primvar:
    """A primvar ``primvars:<name>`` on ``prim``; ``name`` is in the ``bake:`` namespace."""

    prim: str
    name: str
    values: np.ndarray
    type_name: str
    """Sdf scalar type name without []: 'float', 'color3f', 'uchar', ..."""
    interpolation: str
    """'constant', 'uniform', 'vertex', 'faceVarying'."""
    element_size: int = 1
    time: float | None = None
    """USD time code for a time sample, None for the default value."""


@dataclass(frozen=True)
class Attribute:
    """A plain attribute (array or scalar) on ``prim``."""

    prim: str
    name: str
    value: Any
    type_name: str
    """Sdf type name, with [] for arrays ('float3[]', 'asset', 'token')."""
    uniform: bool = False
    time: float | None = None
    connect_to: str | None = None
    """Path of an attribute this one connects to (shading networks)."""


@dataclass(frozen=True)
class Prim:
    """A prim to define (``type_name`` set) or to apply API schemas to (over)."""

    path: str
    type_name: str = ""
    api_schemas: tuple[str, ...] = ()


@dataclass(frozen=True)
class Texture:
    """An image written next to the bake layer with OpenImageIO (or our own writer)."""

    path: str
    """File name relative to the bake layer."""
    pixels: np.ndarray
    """(H, W, C) array; float32 -> EXR, uint8 -> PNG."""


@dataclass(frozen=True)
class File:
    """Raw bytes written next to the bake layer (formats OpenImageIO cannot write: .dds, .npz)."""

    path: str
    """File name relative to the bake layer."""
    data: bytes


Output = Primvar | Attribute | Prim | Texture | File


@dataclass
class Result:
    """What a processor hands back: products for later processors, records for USD, figures for people."""

    products: dict[str, Any] = field(default_factory=dict)
    outputs: list[Output] = field(default_factory=list)
    stats: dict[str, float] = field(default_factory=dict)
    """Figures for the summary, e.g. {'rays': 1.2e7}."""
    messages: list[str] = field(default_factory=list)
    """Warnings for people (e.g. prims that were not baked, and why)."""


# ---------------------------------------------------------------------------
# The processor contract


@dataclass
class Context:
    """Everything ``run`` may read: the scene, the shared tracer, upstream products, params."""

    scene: Scene
    params: Params
    tracer: Any
    """usdbake.processors.tracer.Tracer (built lazily by the runner)."""
    products: dict[str, Any] = field(default_factory=dict)
    progress: Callable[[float], None] = lambda fraction: None
    """Report progress in [0, 1] on long work."""


class Processor:
    """Base class: subclass, set the class attributes, implement applies and run."""

    name: ClassVar[str] = ""
    version: ClassVar[str] = "1"
    requires: ClassVar[tuple[str, ...]] = ()
    provides: ClassVar[tuple[str, ...]] = ()
    facets: ClassVar[tuple[str, ...]] = ("geometry",)
    uses_tracer: ClassVar[bool] = True
    Params: ClassVar[type[Params]] = Params
    summary: ClassVar[str] = ""

    def __init__(self, params: Params | None = None):
        self.params = params if params is not None else self.Params()
        """This step's params, so applies() can decide with them (e.g. a cost model)."""

    def applies(self, scene: Scene) -> tuple[bool, str]:
        """(True, why it runs or "") or (False, why it does not apply)."""
        return True, ""

    def run(self, ctx: Context) -> Result:  # pragma: no cover - abstract
        raise NotImplementedError


# ---------------------------------------------------------------------------
# Registry

_REGISTRY: dict[str, type[Processor]] = {}
_entry_points_loaded = False


def register(cls: type[Processor]) -> type[Processor]:
    """Class decorator: make a processor available by its name."""
    if not cls.name:
        raise ValueError(f"{cls.__name__} has no name")
    existing = _REGISTRY.get(cls.name)
    if existing is not None and existing is not cls:
        raise ValueError(f"processor name {cls.name!r} is taken by {existing.__module__}.{existing.__name__}")
    _REGISTRY[cls.name] = cls
    return cls


def registry() -> dict[str, type[Processor]]:
    """All processors: the built-in ones and those from the 'usdbake.processors' entry points."""
    from . import BUILTIN_MODULES  # noqa: F401  (importing registers the built-ins)

    if not _entry_points_loaded:
        load_entry_points()
    return dict(_REGISTRY)


def load_entry_points() -> list[str]:
    """(Re)load third-party processors from the entry-point group; returns the names found."""
    global _entry_points_loaded
    _entry_points_loaded = True
    names = []
    for entry in entry_points(group=ENTRY_POINT_GROUP):
        loaded = entry.load()
        if not (isinstance(loaded, type) and issubclass(loaded, Processor)):
            raise TypeError(f"entry point {entry.name!r} ({entry.value}) is not a usdbake Processor class")
        register(loaded)
        names.append(loaded.name)
    return names


def get(name: str) -> type[Processor]:
    processors = registry()
    if name not in processors:
        raise ParamError(f"unknown processor {name!r} (known: {', '.join(sorted(processors))})")
    return processors[name]
