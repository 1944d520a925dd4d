"""Plain data: a tree of dataclasses, containers and numpy arrays as JSON plus named arrays, and back.

The result cache (core.cache) stores processor Results this way instead of pickling them. Decoding
builds only the types it names that are dataclasses defined in a trusted module (usdbake's own, or
one that defines a registered processor or its products), and runs none of their code: no
``__init__``, ``__post_init__`` or ``__setstate__``; each field is set as it was stored.

Tree nodes (JSON):

- None, bool, int, str, a finite float: themselves; a list: a JSON array of nodes;
- ``{"$": "float", "value": "nan" | "inf" | "-inf"}`` (JSON has no non-finite numbers);
- ``{"$": "array", "name", "dtype", "shape", "readonly"}``: a numpy array stored as ``name``;
- ``{"$": "scalar", "name"}``: a numpy scalar, stored as a 0-d array (keeps its dtype);
- ``{"$": "bytes", "name"}``: bytes, stored as a (N,) uint8 array;
- ``{"$": "tuple", "items"}``, ``{"$": "dict", "items": [[key, value], ...]}`` (keys of any hashable node);
- ``{"$": "type", "name": "module:qualname"}``,
  ``{"$": "dataclass", "type": "module:qualname", "fields": {name: node}}``.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import sys
from typing import Any, Callable

import numpy as np

_NON_FINITE = ("nan", "inf", "-inf")


def trusted_by_default(module: str) -> bool:
    return module == "usdbake" or module.startswith("usdbake.")


def resolve(name: str, trusted: Callable[[str], bool] = trusted_by_default) -> type:
    """The dataclass type named "module:qualname"; ValueError unless it is defined in a trusted module."""
    module_name, _, qualname = name.partition(":")
    if not trusted(module_name):
        raise ValueError(f"type {name} is not from usdbake or a registered processor's module")
    module = sys.modules.get(module_name)
    if module is None and trusted_by_default(module_name):
        module = importlib.import_module(module_name)  # our own package: no foreign code runs
    parts = qualname.split(".")
    if module is None or not all(part.isidentifier() for part in parts):
        raise ValueError(f"unknown type {name}")
    found = module
    for part in parts:
        found = getattr(found, part, None)
    if not (isinstance(found, type) and dataclasses.is_dataclass(found) and found.__module__ == module_name):
        raise ValueError(f"{name} is not a dataclass type of {module_name}")
    return found


def _reset(f: dataclasses.Field) -> bool:
    """A memo field (``field(default_factory=..., compare=False)``, e.g. ``_cache``): not stored, made afresh."""
    return not f.compare and f.default_factory is not dataclasses.MISSING


def encode(value: Any, *, trusted: Callable[[str], bool] = trusted_by_default) -> tuple[Any, dict[str, np.ndarray]]:
    """(JSON-ready tree, {name: array}); TypeError naming the path of the first value it cannot store."""
    encoder = _Encoder(trusted)
    return encoder.node(value, ""), encoder.arrays


def decode(tree: Any, arrays: dict[str, np.ndarray], *, trusted: Callable[[str], bool] = trusted_by_default) -> Any:
    """The value ``encode`` was given; ValueError, KeyError or TypeError when the tree is not one it wrote."""
    return _Decoder(arrays, trusted).node(tree)


def _child(where: str, key: Any) -> str:
    """Where a value sits, as people write it: ``products.SkyVisibilityProduct.patches``, ``outputs[3].value``."""
    if isinstance(key, type):
        key = key.__name__
    elif not isinstance(key, str) or not key.isidentifier():
        return f"{where}[{key!r}]"
    return f"{where}.{key}" if where else key


def _unstorable(where: str, what: str) -> TypeError:
    return TypeError(f"{where or 'value'}: cannot store {what}")


class _Encoder:
    def __init__(self, trusted: Callable[[str], bool]):
        self.trusted = trusted
        self.arrays: dict[str, np.ndarray] = {}
        self.seen: dict[int, dict] = {}
        """id(array) -> its node: an array two fields share is stored once and shared again on decode."""

    def add(self, array: np.ndarray) -> str:
        name = f"a{len(self.arrays)}"
        self.arrays[name] = array
        return name

    def node(self, value: Any, where: str) -> Any:
        kind = type(value)
        if value is None or kind in (bool, int, str):
            return value
        if kind is float:
            return value if math.isfinite(value) else {"$": "float", "value": repr(value)}
        if kind is list:
            return [self.node(item, f"{where}[{k}]") for k, item in enumerate(value)]
        if kind is tuple:
            return {"$": "tuple", "items": [self.node(item, f"{where}[{k}]") for k, item in enumerate(value)]}
        if kind is dict:
            return {"$": "dict", "items": [[self.node(k, f"{where} key {k!r}"), self.node(item, _child(where, k))]
                                           for k, item in value.items()]}
        if kind is bytes:
            return {"$": "bytes", "name": self.add(np.frombuffer(value, np.uint8))}
        if kind is np.ndarray and not value.dtype.hasobject:
            if id(value) not in self.seen:
                self.seen[id(value)] = {"$": "array", "name": self.add(value), "dtype": value.dtype.str,
                                        "shape": list(value.shape), "readonly": not value.flags.writeable}
            return self.seen[id(value)]
        if isinstance(value, np.generic) and not value.dtype.hasobject:
            return {"$": "scalar", "name": self.add(np.array(value))}
        if isinstance(value, type):
            return {"$": "type", "name": self.type_name(value, where)}
        if dataclasses.is_dataclass(value):
            return self.dataclass(value, where)
        described = f"an array of dtype {value.dtype}" if kind is np.ndarray \
            else f"{kind.__module__}.{kind.__qualname__}"
        raise _unstorable(where, described)

    def type_name(self, cls: type, where: str) -> str:
        name = f"{cls.__module__}:{cls.__qualname__}"
        try:
            if resolve(name, self.trusted) is cls:
                return name
        except ValueError as error:
            raise _unstorable(where, f"{name}: {error}") from None
        raise _unstorable(where, f"{name}: the name does not lead back to the type")

    def dataclass(self, value: Any, where: str) -> dict:
        fields = dataclasses.fields(value)
        extra = set(getattr(value, "__dict__", ())) - {f.name for f in fields}
        if extra:  # state a decode could not restore (it sets fields only)
            raise _unstorable(where, f"{type(value).__qualname__}: attributes that are not fields {sorted(extra)}")
        return {"$": "dataclass", "type": self.type_name(type(value), where),
                "fields": {f.name: self.node(getattr(value, f.name), _child(where, f.name))
                           for f in fields if not _reset(f)}}


class _Decoder:
    def __init__(self, arrays: dict[str, np.ndarray], trusted: Callable[[str], bool]):
        self.arrays, self.trusted = arrays, trusted

    def node(self, node: Any) -> Any:
        if node is None or type(node) in (bool, int, float, str):
            return node
        if type(node) is list:
            return [self.node(item) for item in node]
        tag = node["$"]
        if tag == "float" and node["value"] in _NON_FINITE:
            return float(node["value"])
        if tag == "tuple":
            return tuple(self.node(item) for item in node["items"])
        if tag == "dict":
            return {self.node(key): self.node(item) for key, item in node["items"]}
        if tag == "array":
            array = self.arrays[node["name"]]
            if array.dtype.str != node["dtype"] or list(array.shape) != node["shape"]:
                raise ValueError(f"array {node['name']} is {array.dtype.str} {array.shape}, the manifest says "
                                 f"{node['dtype']} {tuple(node['shape'])}")
            if node["readonly"]:
                array.flags.writeable = False
            return array
        if tag == "scalar":
            return self.arrays[node["name"]].reshape(())[()]
        if tag == "bytes":
            return self.arrays[node["name"]].astype(np.uint8, casting="no").reshape(-1).tobytes()
        if tag == "type":
            return resolve(node["name"], self.trusted)
        if tag == "dataclass":
            return self.dataclass(node)
        raise ValueError(f"unknown node {tag!r}")

    def dataclass(self, node: dict) -> Any:
        cls = resolve(node["type"], self.trusted)
        stored = dict(node["fields"])
        value = object.__new__(cls)
        for f in dataclasses.fields(cls):
            if _reset(f):
                item = f.default_factory()
            elif f.name in stored:
                item = self.node(stored.pop(f.name))
            else:
                raise ValueError(f"{node['type']}: field {f.name} is not in the entry")
            object.__setattr__(value, f.name, item)  # frozen dataclasses too; no __init__ runs
        if stored:
            raise ValueError(f"{node['type']} has no fields {sorted(stored)}")
        return value
