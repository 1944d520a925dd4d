"""The runner's cache: step keys (content fingerprints) and Results on disk as plain arrays + JSON.

A cache folder is often shared (a render farm's, a team's), so whoever can write to it must not be
able to run code in every process that bakes from it: entries are never pickles. An entry is a
manifest ``<name>-<key>.json`` (format, processor, key, usdbake version, the sha256 of the arrays
file, the Result as a core.plain_data tree, and ``sha256``: the entry's hash, over all of the
manifest but itself, so over the arrays too) and an arrays file ``<name>-<key>.<sha256[:16]>.npz``
named by its content, read with ``allow_pickle=False``. Loading builds only dataclasses of usdbake
and of registered processors' modules, and runs none of their code; a loaded Result is then checked
against the scene it is for (``misfit``: record sizes against points, faces and instances) before
use. An entry that is missing, corrupt, hand-edited, tampered with, from another format or that
does not fit the scene is recomputed (with one warning, unless missing).

The cache is an optimisation: an entry that cannot be written (a full disk, ``ulimit -f``, a
read-only folder) is one warning for the run, which goes on without storing results.
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
from .products import RefinedScene
from .records import Attribute, Output, Primvar, RefinedMesh
from .scene import Scene

FORMAT = 2
"""Version of the entry layout; an entry of another one is recomputed. 2: the manifest holds the
entry's hash (``sha256``); 1 hashed only the arrays."""

STALE_SECONDS = 600.0
"""An arrays file no manifest names is deleted once this old: far longer than the moment between
a writer replacing its arrays file and its manifest, so a concurrent writer's file is never taken."""


def code_fingerprint(cls: type) -> str:
    """Hash of the code a processor runs: its own module and every module of its package or of
    usdbake that it imports, followed transitively; an edited kernel never serves a stale cached
    result, and an edit elsewhere (the preview renderer, the CLI) invalidates nothing. Modules are
    named by their import name, not their path: two installs of the same code in different folders
    (farm workers) share their cache entries. A module's ``NATIVE_SOURCES`` (files it reads as code, the
    ray core's C++) count as its code too."""
    modules = library_modules(cls.__module__)
    files = modules + [(f"{name}:{path.name}", Path(path)) for name, _ in modules
                       for path in getattr(sys.modules.get(name), "NATIVE_SOURCES", ())]
    return _digest_files(tuple((name, str(path), path.stat().st_mtime_ns, path.stat().st_size)
                               for name, path in files))


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
        pending.extend(_file_imports(source, os.stat(source).st_mtime_ns, module.__package__ or "",
                                     tuple(sorted(roots))))
    return sorted(found.items())


@functools.lru_cache(maxsize=4096)
def _file_imports(source: str, mtime_ns: int, package: str, roots: tuple[str, ...]) -> tuple[str, ...]:
    """The library modules a source file imports, parsed once per file and modification time (every step's
    cache key follows the same modules)."""
    tree = ast.parse(Path(source).read_text())
    return tuple(name for node in ast.walk(tree) for name in _imported_modules(node, package, set(roots)))


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
    """A cache entry could not be used and is recomputed, or could not be written (once a run)."""


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
    A write that fails (OSError: no space, a file size limit, a read-only folder) warns once; this
    cache then writes nothing more, and the run goes on.
    """

    def __init__(self, directory: str | Path | None):
        self.directory = Path(directory) if directory else None
        self.unwritable = ""
        """Why an entry could not be written ('' while none failed): no more writes this run."""

    def manifest_path(self, name: str, key: str) -> Path:
        return self.directory / f"{name}-{key}.json"

    def arrays_path(self, name: str, key: str, sha256: str) -> Path:
        return self.directory / f"{name}-{key}.{sha256[:16]}.npz"

    def has(self, name: str, key: str) -> bool:
        """An entry's manifest exists (whether it loads is up to ``load``)."""
        if self.directory is None:
            return False
        try:
            return self.manifest_path(name, key).exists()
        except OSError:  # a folder we may not search: nothing to serve
            return False

    def load(self, name: str, key: str, *, scene: Scene | None = None,
             provides: tuple[type, ...] | None = None) -> Result | None:
        """The stored Result, or None: silently when there is none, with a CacheWarning when it is unusable.

        With ``scene`` (the topology the step's records are authored on: the refined Scene in a run
        with a mesh refiner) the Result must fit it, and with ``provides`` hold only those products
        (``misfit``); one that does not is unusable too.
        """
        if self.directory is None:
            return None
        try:
            result = self._read(name, key)
            try:
                why = misfit(result, scene, provides=provides) if scene is not None else ""
            except Exception as error:  # a value of a type no processor writes: the entry is not one we wrote
                why = _one_line(error)
            if why:
                raise _Unusable(self.manifest_path(name, key), f"does not fit the scene ({why})")
            return result
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
        try:
            sealed = entry_sha256(manifest) == manifest.get("sha256")
        except (ValueError, RecursionError):  # a number JSON cannot hold again (1e999)
            sealed = False
        if not sealed:
            raise _Unusable(path, "entry hash mismatch (the manifest was edited)")
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
        """Write the entry; TypeError naming where in the Result a value is that cannot be stored.

        An OSError writing it is a CacheWarning, once: this cache then writes nothing more.
        """
        if self.directory is None or self.unwritable:
            return
        from .version import __version__

        tree, arrays = plain_data.encode(result, trusted=_trust())
        temp = self.directory / f".{name}-{key}.{os.getpid()}-{uuid.uuid4().hex}"
        temp_arrays, temp_manifest = temp.with_name(temp.name + ".npz.tmp"), temp.with_name(temp.name + ".json.tmp")
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            with open(temp_arrays, "wb") as handle:
                np.savez(handle, **arrays)
            sha256 = _file_sha256(temp_arrays)
            arrays_path = self.arrays_path(name, key, sha256)
            os.replace(temp_arrays, arrays_path)
            manifest = {"format": FORMAT, "processor": name, "key": key, "usdbake": __version__,
                        "arrays_sha256": sha256, "tree": tree}
            manifest["sha256"] = entry_sha256(manifest)
            temp_manifest.write_text(json.dumps(manifest, allow_nan=False, separators=(",", ":")))
            os.replace(temp_manifest, self.manifest_path(name, key))
        except OSError as error:  # the cache is an optimisation: the bake goes on without it
            self.unwritable = error.strerror or _one_line(error)
            warnings.warn(f"usdbake cache: cannot write in {self.directory} ({self.unwritable}); "
                          f"results of this run are not cached", CacheWarning, stacklevel=2)
            return
        finally:
            for leftover in (temp_arrays, temp_manifest):
                try:
                    leftover.unlink(missing_ok=True)
                except OSError:
                    pass  # a folder that refuses the write may refuse the cleanup: nothing was made there
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


def entry_sha256(manifest: dict) -> str:
    """The entry's hash: sha256 of the manifest without its ``sha256`` field, as canonical JSON (keys
    sorted, no spaces, ASCII); the manifest holds the arrays file's sha256, so this covers both files.
    ValueError for a value JSON cannot hold (a non-finite float)."""
    body = {name: value for name, value in manifest.items() if name != "sha256"}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


# ---------------------------------------------------------------------------
# Does a cached Result fit the scene it is for?

INTERPOLATIONS = ("constant", "uniform", "varying", "vertex", "faceVarying")


def misfit(result: Result, scene: Scene, *, provides: tuple[type, ...] | None = None) -> str:
    """Why ``result`` cannot serve a bake of ``scene`` ('' when it can), in a few words for people.

    A cache entry's hash says only that the entry is the one written; this says that it fits the
    scene its key was computed from (an entry written by hand, or by a bug, would author data that
    does not fit the meshes). Checked: the Result's fields have their types; each product is one
    of ``provides`` (when given); every output is a record; each primvar has a known interpolation,
    an elementSize of at least 1 and, times elementSize, the values its prim needs: vertex/varying
    one per point of a mesh in ``scene`` (per instance on a PointInstancer), uniform one per
    authored face, faceVarying one per face-vertex corner, constant exactly one. ``scene`` is the
    topology records are authored on: a Result providing a RefinedScene is measured against its
    own refined Scene (which must have the prims of ``scene``, its RefinedMesh records the authored
    points). Primvars on prims the Scene does not hold (materials, prims a step defines) are
    checked for constant size only: their topology is not known here.
    """
    fields = {"products": dict, "outputs": list, "stats": dict, "messages": list}
    for name, kind in fields.items():
        if not isinstance(getattr(result, name), kind):
            return f"its {name} are a {type(getattr(result, name)).__name__}, not a {kind.__name__}"
    for kind, value in result.products.items():
        if provides is not None and (kind not in provides or not isinstance(value, kind)):
            return f"product {getattr(kind, '__name__', kind)!r} is not one the processor provides"
    refined = getattr(result.products.get(RefinedScene), "scene", scene)
    if not isinstance(refined, Scene) or refined.prim_paths != scene.prim_paths:
        return "its refined Scene does not have this scene's prims"
    topology = _Topology(refined, result.outputs)
    for k, record in enumerate(result.outputs):
        if not isinstance(record, Output):
            return f"outputs[{k}] is a {type(record).__name__}, not an output record"
        if not isinstance(getattr(record, "prim", getattr(record, "path", "")), str):
            return f"outputs[{k}] names no prim path"
        why = _primvar_misfit(record, topology) if isinstance(record, Primvar) else \
            _refined_misfit(record, scene, topology) if isinstance(record, RefinedMesh) else ""
        if why:
            return why
    return ""


def _primvar_misfit(record: Primvar, topology: "_Topology") -> str:
    values, size = record.values, record.element_size
    if not _is_array(values):
        return f"{record.prim}.primvars:{record.name}: its values are not an array"
    if record.interpolation not in INTERPOLATIONS:
        return f"{record.prim}.primvars:{record.name}: interpolation {record.interpolation!r}"
    if type(size) is not int or size < 1:
        return f"{record.prim}.primvars:{record.name}: elementSize {size!r}"
    expected, unit, exact = topology.expected(record.prim, record.interpolation)
    count = len(values)
    if expected is None or count == expected * size or (not exact and count > expected * size
                                                         and count % size == 0):
        return ""
    of_size = f" of elementSize {size}" if size != 1 else ""
    if record.interpolation == "constant":
        return f"{record.prim}: {count} constant values{of_size}, not one element"
    return (f"{record.prim}: {count} {record.interpolation} values{of_size} for "
            f"{'' if exact else 'at least '}{expected} {unit}")


def _refined_misfit(record: RefinedMesh, scene: Scene, topology: "_Topology") -> str:
    """A RefinedMesh keeps its prim's authored points first and has one triangle per refined face."""
    m = topology.prims.get(record.prim)  # the refined Scene has the prims of ``scene``, in its order
    if m is None:
        return f"{record.prim}: a refined mesh of no mesh in the scene"
    points = int(scene.prim_point_start[m + 1] - scene.prim_point_start[m])
    if record.point_count != points:
        return f"{record.prim}: a refined mesh of {record.point_count} authored points, the scene has {points}"
    faces, _, _ = topology.expected(record.prim, "uniform")
    triangles = record.triangles
    if not isinstance(triangles, np.ndarray) or triangles.shape[1:] != (3,) or len(triangles) != faces:
        return f"{record.prim}: a refined mesh whose triangles are not its refined faces"
    return ""


class _Topology:
    """Points, faces and face-vertex corners per prim of a Scene, as primvars of each interpolation need
    them; topology attributes a Result authors itself (``points``, ``faceVertexCounts``,
    ``faceVertexIndices`` on a prim it defines) take precedence, as they do in the bake layer."""

    def __init__(self, scene: Scene, outputs: list):
        self.scene = scene
        self.prims: dict[str, int] = {}
        for m, path in enumerate(scene.prim_paths):
            self.prims.setdefault(path, m)  # an instanced prototype is listed once per instance, alike
        instances = scene.instances
        authored_rows = len(instances.instance_index) == len(instances) and \
            len(instances.instancer_instance_count) == len(instances.instancer_paths)
        self.instancers = {path: int(instances.instancer_instance_count[n])
                           for n, path in enumerate(instances.instancer_paths)
                           if authored_rows and not instances.is_native(n)}
        self.authored: dict[tuple[str, str], int] = {}
        for record in outputs:
            if isinstance(record, Attribute) and record.name in _AUTHORED and _is_array(record.value):
                self.authored[record.prim, _AUTHORED[record.name]] = len(record.value)
        self._corners: tuple[np.ndarray, np.ndarray] | None = None

    def expected(self, prim: str, interpolation: str) -> tuple[int | None, str, bool]:
        """(elements the prim needs, what they are one per, whether exactly that many or at least);
        (None, '', False) when not known here."""
        if interpolation == "constant":
            return 1, "", True
        unit = {"vertex": "points", "varying": "points", "uniform": "faces",
                "faceVarying": "face-vertex corners"}[interpolation]
        if (prim, unit) in self.authored:
            return self.authored[prim, unit], unit, True
        m = self.prims.get(prim)
        if m is None:
            if unit == "points" and prim in self.instancers:  # a PointInstancer: one value per instance
                return self.instancers[prim], "instances", True
            return None, "", False
        scene = self.scene
        if unit == "points":
            return int(scene.prim_point_start[m + 1] - scene.prim_point_start[m]), unit, True
        if unit == "faces":
            return int(scene.prim_face_count[m]), unit, True
        reached, complete = self.corners()
        if reached[m] == 0:
            return None, "", False  # no triangle says where its corners are (a Scene not read from USD)
        return int(reached[m]), unit, bool(complete[m])

    def corners(self) -> tuple[np.ndarray, np.ndarray]:
        """(M,) int64 face-vertex corners each prim's triangles reach (last slot + 1) and (M,) bool: every
        authored face has triangles, so that is all of them (a face left out may hide the last ones)."""
        if self._corners is None:
            scene, count = self.scene, len(self.scene.prim_paths)
            reached = np.zeros(count, np.int64)
            np.maximum.at(reached, scene.tri_prim, scene.tri_corner.max(axis=1, initial=-1).astype(np.int64) + 1)
            faces = np.unique(np.stack([scene.tri_prim, scene.tri_face], axis=1), axis=0)
            complete = np.bincount(faces[:, 0], minlength=count)[:count] == scene.prim_face_count
            self._corners = reached, complete
        return self._corners


def _is_array(values) -> bool:
    """An array of values (a list or tuple of them too): something with a length."""
    return isinstance(values, (list, tuple)) or (isinstance(values, np.ndarray) and values.ndim >= 1)


_AUTHORED = {"points": "points", "faceVertexCounts": "faces", "faceVertexIndices": "face-vertex corners"}


def _no_constant(name: str):
    raise ValueError(f"{name} is not JSON")


def _file_sha256(path: Path) -> str:
    with open(path, "rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()
