"""The runner's cache: step keys (content fingerprints) and Results on disk as plain arrays + JSON.

A cache folder is often shared (a render farm's, a team's), so whoever can write to it must not be
able to run code in every process that bakes from it: entries are never pickles. An entry is a
manifest ``<name>-<key>.json`` (format, processor, key, usdbake version, the sha256 of the arrays
file, and the Result as a core.plain_data tree) and an arrays file ``<name>-<key>.<sha256[:16]>.npz``
named by its content, read with ``allow_pickle=False``. Loading builds only dataclasses of usdbake
and of registered processors' modules, and runs none of their code. An entry that is missing,
corrupt, tampered with or from another format is recomputed (with a warning, unless missing).
"""

from __future__ import annotations

import ast
import functools
import glob
import hashlib
import importlib
import importlib.util
import io
import json
import os
import re
import sys
import time
import uuid
import warnings
from pathlib import Path
from typing import Callable

import numpy as np

from . import plain_data
from .processor import Result
from .scene import Scene

FORMAT = 1
"""Version of the entry layout; an entry of another one is recomputed."""

STALE_SECONDS = 600.0
"""An arrays file no manifest names is deleted once this old: far longer than the moment between
a writer replacing its arrays file and its manifest, so a concurrent writer's file is never taken."""


def code_fingerprint(cls: type) -> str:
    """Hash of the code a processor runs: its own module and every module of its package or of
    usdbake that it imports, followed transitively; an edited kernel never serves a stale cached
    result, and an edit elsewhere (the preview renderer, the CLI) invalidates nothing. Modules are
    named by their import name, not their path: two installs of the same code in different folders
    (farm workers) share their cache entries."""
    modules = library_modules(cls.__module__)
    return _digest_files(tuple((name, str(path), path.stat().st_mtime_ns, path.stat().st_size)
                               for name, path in modules))


def library_modules(module_name: str) -> list[tuple[str, Path]]:
    """(import name, source file) of ``module_name`` and of the modules it imports from its own
    top-level package or from usdbake (read from the import statements), transitively, by name."""
    roots = {__name__.split(".")[0], module_name.split(".")[0]}
    found: dict[str, Path] = {}
    pending = [module_name]
    while pending:
        name = pending.pop()
        if name in found:
            continue
        module = sys.modules.get(name) or importlib.import_module(name)
        source = getattr(module, "__file__", None)
        if not source or not source.endswith(".py"):
            continue
        found[name] = Path(source)
        package = module.__package__ or ""
        for node in ast.walk(ast.parse(Path(source).read_text())):
            pending.extend(_imported_modules(node, package, roots))
    return sorted(found.items())


def _imported_modules(node: ast.AST, package: str, roots: set[str]) -> list[str]:
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names if alias.name.split(".")[0] in roots]
    if not isinstance(node, ast.ImportFrom):
        return []
    base = importlib.util.resolve_name("." * node.level + (node.module or ""), package) if node.level \
        else node.module or ""
    if base.split(".")[0] not in roots:
        return []
    names = [base]
    for alias in node.names:  # `from . import tetrahedra` names a module, `from .x import f` a function
        candidate = f"{base}.{alias.name}"
        if candidate in sys.modules or _is_module(candidate):
            names.append(candidate)
    return names


def _is_module(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


@functools.lru_cache(maxsize=64)
def _digest_files(stamped: tuple) -> str:
    """sha256 over (import name, source bytes) of each module; the path and stamp only key this memo."""
    digest = hashlib.sha256()
    for name, path, _, _ in stamped:
        digest.update(name.encode())
        digest.update(Path(path).read_bytes())
    return digest.hexdigest()


def step_key(step, scene: Scene, upstream_keys: list[str]) -> str:
    payload = {
        "name": step.name, "version": step.processor.version, "code": code_fingerprint(type(step.processor)),
        "params": repr(sorted(step.params.as_dict().items())),
        "scene": scene.fingerprint(step.processor.facets), "upstream": upstream_keys,
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:32]


class CacheWarning(UserWarning):
    """A cache entry could not be used and is recomputed."""


class _Unusable(Exception):
    def __init__(self, path: Path, why: str):
        super().__init__(f"usdbake cache: {path}: {why}; recomputing")


def _one_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0]}" if text else type(error).__name__


def _trust() -> Callable[[str], bool]:
    """Which modules' dataclasses an entry may name: usdbake's, and those defining a registered
    processor (a plugin's, a test's) or its products; the registry is read at most once per store or load."""
    registered: set[str] | None = None

    def trusted(module: str) -> bool:
        nonlocal registered
        if plain_data.trusted_by_default(module):
            return True
        if registered is None:
            from .registry import registry

            classes = registry().values()
            registered = {cls.__module__ for cls in classes} | {kind.__module__ for cls in classes
                                                                for kind in (*cls.provides, *cls.requires)}
        return module in registered
    return trusted


class ResultCache:
    """Results on disk, one manifest and one arrays file per step key; no directory means no caching.

    Safe for concurrent writers and readers of one entry: each file is written under a unique
    temporary name in the folder and moved into place with os.replace, arrays file first, so a
    manifest only ever names a complete arrays file, and that file is named by its content.
    """

    def __init__(self, directory: str | Path | None):
        self.directory = Path(directory) if directory else None

    def manifest_path(self, name: str, key: str) -> Path:
        return self.directory / f"{name}-{key}.json"

    def arrays_path(self, name: str, key: str, sha256: str) -> Path:
        return self.directory / f"{name}-{key}.{sha256[:16]}.npz"

    def has(self, name: str, key: str) -> bool:
        """An entry's manifest exists (whether it loads is up to ``load``)."""
        return self.directory is not None and self.manifest_path(name, key).exists()

    def load(self, name: str, key: str) -> Result | None:
        """The stored Result, or None: silently when there is none, with a CacheWarning when it is unusable."""
        if self.directory is None:
            return None
        try:
            return self._read(name, key)
        except FileNotFoundError:
            return None
        except _Unusable as unusable:
            warnings.warn(str(unusable), CacheWarning, stacklevel=2)
            return None

    def _read(self, name: str, key: str) -> Result:
        path = self.manifest_path(name, key)
        try:
            text = path.read_bytes()
        except FileNotFoundError:
            raise  # no entry: not worth a warning
        except OSError as error:
            raise _Unusable(path, f"unreadable ({_one_line(error)})") from None
        try:
            manifest = json.loads(text, parse_constant=_no_constant)
        except (ValueError, RecursionError) as error:
            raise _Unusable(path, f"not a JSON manifest ({_one_line(error)})") from None
        if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
            found = manifest.get("format") if isinstance(manifest, dict) else type(manifest).__name__
            raise _Unusable(path, f"format {found!r}, expected {FORMAT}")
        if manifest.get("processor") != name or manifest.get("key") != key:
            raise _Unusable(path, f"the manifest is for {manifest.get('processor')}-{manifest.get('key')}")
        sha256 = manifest.get("arrays_sha256")
        if not isinstance(sha256, str) or not re.fullmatch("[0-9a-f]{64}", sha256):
            raise _Unusable(path, "no arrays hash")
        arrays_path = self.arrays_path(name, key, sha256)
        try:
            data = arrays_path.read_bytes()  # hashed and loaded from these bytes: no swap in between
        except OSError as error:
            raise _Unusable(arrays_path, f"arrays file unreadable ({_one_line(error)})") from None
        if hashlib.sha256(data).hexdigest() != sha256:
            raise _Unusable(arrays_path, "content hash mismatch")
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as npz:
                arrays = {array: npz[array] for array in npz.files}
        except Exception as error:  # a truncated zip, an object array: whatever numpy refuses
            raise _Unusable(arrays_path, f"unreadable arrays ({_one_line(error)})") from None
        try:
            result = plain_data.decode(manifest.get("tree"), arrays, trusted=_trust())
        except Exception as error:  # an unknown type, a missing field: the entry is not one we wrote
            raise _Unusable(path, f"cannot decode ({_one_line(error)})") from None
        if not isinstance(result, Result):
            raise _Unusable(path, f"holds a {type(result).__name__}, not a Result")
        return result

    def store(self, name: str, key: str, result: Result) -> None:
        """Write the entry; TypeError naming where in the Result a value is that cannot be stored."""
        if self.directory is None:
            return
        from .. import __version__

        tree, arrays = plain_data.encode(result, trusted=_trust())
        self.directory.mkdir(parents=True, exist_ok=True)
        temp = self.directory / f".{name}-{key}.{os.getpid()}-{uuid.uuid4().hex}"
        temp_arrays, temp_manifest = temp.with_name(temp.name + ".npz.tmp"), temp.with_name(temp.name + ".json.tmp")
        try:
            with open(temp_arrays, "wb") as handle:
                np.savez(handle, **arrays)
            sha256 = _file_sha256(temp_arrays)
            arrays_path = self.arrays_path(name, key, sha256)
            os.replace(temp_arrays, arrays_path)
            manifest = {"format": FORMAT, "processor": name, "key": key, "usdbake": __version__,
                        "arrays_sha256": sha256, "tree": tree}
            temp_manifest.write_text(json.dumps(manifest, allow_nan=False, separators=(",", ":")))
            os.replace(temp_manifest, self.manifest_path(name, key))
        finally:
            for leftover in (temp_arrays, temp_manifest):
                leftover.unlink(missing_ok=True)
        self._prune(name, key, arrays_path)

    def _prune(self, name: str, key: str, keep: Path) -> None:
        """Delete this entry's old arrays files (an earlier run's, when results differ run to run; a tampered one)."""
        cutoff = time.time() - STALE_SECONDS
        for path in self.directory.glob(f"{glob.escape(name)}-{key}.*.npz"):
            try:
                if path != keep and path.stat().st_mtime < cutoff:
                    path.unlink()
            except OSError:
                pass  # another writer pruned it first


def _no_constant(name: str):
    raise ValueError(f"{name} is not JSON")


def _file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()
