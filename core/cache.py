"""The runner's cache: step keys (content fingerprints) and pickled Results on disk."""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib
import importlib.util
import json
import pickle
import sys
from pathlib import Path

from .processor import Result
from .scene import Scene


def code_fingerprint(cls: type) -> str:
    """Hash of the code a processor runs: its own module and every module of its package or of
    usdbake that it imports, followed transitively; an edited kernel never serves a stale cached
    result, and an edit elsewhere (the preview renderer, the CLI) invalidates nothing."""
    files = library_modules(cls.__module__)
    return _digest_files(tuple((str(f), f.stat().st_mtime_ns, f.stat().st_size) for f in files))


def library_modules(module_name: str) -> list[Path]:
    """Source files of ``module_name`` and of the modules it imports from its own top-level package
    or from usdbake (read from the import statements), transitively, sorted."""
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
    return sorted(found.values())


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
    digest = hashlib.sha256()
    for path, _, _ in stamped:
        digest.update(path.encode())
        digest.update(Path(path).read_bytes())
    return digest.hexdigest()


def step_key(step, scene: Scene, upstream_keys: list[str]) -> str:
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

    def load(self, name: str, key: str) -> Result | None:
        path = self.path(name, key)
        if path is None or not path.exists():
            return None
        try:
            with open(path, "rb") as handle:
                return pickle.load(handle)
        except (OSError, pickle.UnpicklingError, EOFError, AttributeError):
            return None  # unreadable or from an incompatible version: recompute

    def store(self, name: str, key: str, result: Result) -> None:
        path = self.path(name, key)
        if path is None:
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        temp = path.with_suffix(".tmp")
        with open(temp, "wb") as handle:
            pickle.dump(result, handle, protocol=pickle.HIGHEST_PROTOCOL)
        temp.replace(path)
