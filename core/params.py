"""Processor parameters: a frozen dataclass per processor, validated at construction.

``param()`` gives each field a default, optional bounds or choices and one
line of doc; ``Params.describe()`` is the one description that feeds
``usdbake list``, the tables in the docs and their drift test.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import UsageError


class ParamError(UsageError):
    """A parameter name or value a user gave is not valid."""


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
