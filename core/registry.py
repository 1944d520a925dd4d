"""Which processors exist: the built-in list below and the 'usdbake.processors' entry points.

Built-ins are named the way entry points name plugins ("module:Class"), and
both are imported on first use, so importing the registry imports no
technique and no technique registers itself. Adding a processor is one line
in BUILTIN.
"""

from __future__ import annotations

from functools import lru_cache
from importlib import import_module
from importlib.metadata import entry_points

from .params import ParamError
from .processor import Processor

ENTRY_POINT_GROUP = "usdbake.processors"

BUILTIN = (
    "usdbake.processors.occlusion.ambient_occlusion:AmbientOcclusion",
    "usdbake.processors.daylight.sky_visibility:SkyVisibility",
    "usdbake.processors.daylight.interreflection:Interreflection",
    "usdbake.processors.daylight.daylight:Daylight",
    "usdbake.processors.daylight.annual_daylight:AnnualDaylight",
    "usdbake.processors.daylight.daylight_stream:DaylightStream",
    "usdbake.processors.instancing.displacement_fields:DisplacementFields",
    "usdbake.processors.instancing.instance_ao:InstanceAO",
    "usdbake.processors.radiosity.form_factors:FormFactors",
    "usdbake.processors.radiosity.radiosity:Radiosity",
    "usdbake.processors.light_probes.light_probes:LightProbes",
    "usdbake.processors.irradiance_grid.irradiance_grid:IrradianceGrid",
    "usdbake.processors.irradiance_grid.progressive_mesh:ProgressiveMesh",
)
"""Every technique in usdbake/processors, as "module:Class"."""

_EXTRA: dict[str, type[Processor]] = {}


def load(spec: str) -> type[Processor]:
    """The class named by "module:Class", checked to be a Processor."""
    module, _, attribute = spec.partition(":")
    loaded = getattr(import_module(module), attribute)
    if not (isinstance(loaded, type) and issubclass(loaded, Processor)):
        raise TypeError(f"{spec} is not a usdbake Processor class")
    if not loaded.name:
        raise TypeError(f"{spec} has no name")
    return loaded


@lru_cache(maxsize=1)
def builtin() -> dict[str, type[Processor]]:
    classes = [load(spec) for spec in BUILTIN]
    return {cls.name: cls for cls in classes}


def plugins() -> dict[str, type[Processor]]:
    """Third-party processors from the entry-point group (read afresh at each call)."""
    found = {}
    for entry in entry_points(group=ENTRY_POINT_GROUP):
        try:
            cls = load(entry.value)
        except TypeError as error:
            raise TypeError(f"entry point {entry.name!r}: {error}") from None
        found[cls.name] = cls
    return found


def register(cls: type[Processor]) -> type[Processor]:
    """Make a processor class available by name in this process (tests, notebooks)."""
    if not cls.name:
        raise ValueError(f"{cls.__name__} has no name")
    _check_free(cls, {**builtin(), **_EXTRA})
    _EXTRA[cls.name] = cls
    return cls


def unregister(name: str) -> None:
    _EXTRA.pop(name, None)


def registry() -> dict[str, type[Processor]]:
    """All processors by name: built-ins, entry points, then those registered in this process."""
    known = dict(builtin())
    for cls in [*plugins().values(), *_EXTRA.values()]:
        _check_free(cls, known)
        known[cls.name] = cls
    return known


def get(name: str) -> type[Processor]:
    processors = registry()
    if name not in processors:
        raise ParamError(f"unknown processor {name!r} (known: {', '.join(sorted(processors))})")
    return processors[name]


def _check_free(cls: type[Processor], known: dict[str, type[Processor]]) -> None:
    existing = known.get(cls.name)
    if existing is not None and existing is not cls:
        raise ValueError(f"processor name {cls.name!r} is taken by {existing.__module__}.{existing.__name__}")
