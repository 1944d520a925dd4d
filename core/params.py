"""Processor parameters: a frozen dataclass per processor, validated at construction.

``param()`` gives each field a default, optional bounds or choices and one
line of doc; ``Params.describe()`` is the one description that feeds
``usdbake list``, the tables in the docs and their drift test:
``Params.table_rows()`` formats it for people (the table ``usdbake list``
prints) and ``Params.markdown_table()`` renders the same rows as the Markdown
that ``python -m usdbake.cli.docs_tables`` writes into docs/.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import UsageError


class ParamError(UsageError):
    """A parameter name or value a user gave is not valid."""


def _shown(value) -> str:
    """A value as an error line shows it: a numpy scalar as its plain number (1.5, not np.float64(1.5))."""
    return repr(value.item() if isinstance(value, np.generic) else value)


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
                raise ParamError(f"{f.name}={_shown(value)} is not one of {list(meta['choices'])}")
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                if isinstance(value, float) and math.isnan(value):
                    raise ParamError(f"{f.name}=nan is not a number")
                if meta.get("low") is not None and value < meta["low"]:
                    raise ParamError(f"{f.name}={_shown(value)} is below the minimum {meta['low']}")
                if meta.get("high") is not None and value > meta["high"]:
                    raise ParamError(f"{f.name}={_shown(value)} is above the maximum {meta['high']}")

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
    def table_rows(cls) -> list[tuple[str, str, str, str, str]]:
        """``describe()`` formatted for people: one (param, type, default, range, meaning) per field.

        Defaults are written as a user types them on ``--set`` or in TOML
        (``true``, ``inf``, ``''`` for an empty string); the range is the
        choices, ``[low, high]``, ``>= low`` or ``<= high``, or empty.
        """
        return [(row["name"], row["type"], format_value(row["default"]), format_range(row), row["doc"])
                for row in cls.describe()]

    @classmethod
    def markdown_table(cls) -> str:
        """The parameter table as GitHub Markdown: the rows of ``table_rows()``, names, defaults and
        choices as code, ``|`` escaped; no trailing newline."""
        lines = ["| " + " | ".join(TABLE_COLUMNS) + " |", "|" + "---|" * len(TABLE_COLUMNS)]
        for row, (name, type_name, default, allowed, doc) in zip(cls.describe(), cls.table_rows()):
            if row["choices"] is not None:
                allowed = ", ".join(_code(format_value(choice)) for choice in row["choices"])
            cells = (_code(name), type_name, _code(default), allowed, doc)
            lines.append("| " + " | ".join(_cell(text) for text in cells) + " |")
        return "\n".join(lines)

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


@dataclass(frozen=True)
class TextureTargetParams(Params):
    """Parameters of every processor that can bake into lightmap textures (``kernels.lightmap_bake``)."""

    target: str = param("vertex", "where per-surface results go: vertex (primvars, as authored), texture "
                        "(lightmaps on the asset's UVs, no mesh changed) or both", choices=("vertex", "texture", "both"))
    texel_density: float = param(32.0, "texture target: lightmap texels per metre of surface", low=0.01, high=1e5)
    max_texture_size: int = param(4096, "texture target: largest lightmap side in texels (a mesh whose density "
                                  "needs more gets fewer texels per metre, and the bake says so)", low=8, high=16384)
    margin: int = param(16, "texture target: texels each chart is dilated by into the empty space around it",
                        low=0, high=256)
    denoise: bool = param(False, "texture target: denoise each lightmap with Intel Open Image Denoise, guided by "
                          "normals and meshes (needs the pyoidn package: pip install 'usdbake[denoise]')")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.denoise and importlib.util.find_spec("pyoidn") is None:
            raise ParamError("denoise=true needs the pyoidn package (Intel Open Image Denoise): "
                             "pip install 'usdbake[denoise]'")


TABLE_COLUMNS = ("param", "type", "default", "range", "meaning")
"""Column headers of ``Params.table_rows()`` and ``Params.markdown_table()``."""


def format_value(value: Any) -> str:
    """A default or bound as a user would type it: ``true``, ``inf``, ``0.5``, ``''``."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return value if value else "''"
    return str(value)


def format_range(row: dict) -> str:
    """The allowed values of a ``describe()`` row: its choices, or its bounds, or ''."""
    if row["choices"] is not None:
        return ", ".join(format_value(choice) for choice in row["choices"])
    low, high = row["low"], row["high"]
    if low is not None and high is not None:
        return f"[{format_value(low)}, {format_value(high)}]"
    if low is not None:
        return f">= {format_value(low)}"
    if high is not None:
        return f"<= {format_value(high)}"
    return ""


def _code(text: str) -> str:
    return f"`{text}`" if text else ""


def _cell(text: str) -> str:
    """One Markdown table cell: a pipe would end the cell, a newline the row."""
    return " ".join(str(text).split()).replace("|", "\\|")


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
        raise ParamError(f"{name}={_shown(value)} is not a valid {type(default).__name__}") from None
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
        raise ParamError(f"{name}={_shown(value)} is not a valid {type(default).__name__}")
    return converted
