"""Output records -> USD: the non-destructive bake layer.

The bake layer sublayers the untouched input (relative path) and holds only
bake opinions, all under the ``bake:`` namespace. Every edit is prepared
first (values converted, sidecar files written under temporary names) and
then authored with the Sdf API inside one ``Sdf.ChangeBlock``. Saves are
atomic: the layer and its sidecars are written to temporary names in the
destination folder, then renamed, sidecars first and the layer last, so a
layer on disk never names a file that is not there.

Sidecar files (textures, .dds, .npz, stream files) are named
``<layer stem>_<record name>_<content hash>.<ext>``: no output can overwrite
another's. The provenance records each with the SHA-256 of the bytes written
(``sidecars``, ``sidecarDigests``), and a re-bake removes a file the previous
version recorded and the new one does not only if it is still that file: in
the output's own folder, named as usdbake names sidecars, a plain file (not a
link) with the recorded digest. Nothing a layer says can make a bake delete
anything else; a layer without digests removes nothing. Temporary files are named
``.<output name>.usdbake-tmp-<pid>-<token>...`` and removed on failure; a
later bake into the same output removes those a killed process left.

A bake layer holds exactly the results of the last bake into it: re-baking
replaces its content, it never nests or duplicates.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import secrets
import stat
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from pxr import Sdf, Tf, Vt

from ..core.errors import OutputError, UsageError
from ..core.records import Attribute, Block, File, Prim, Primvar, RefinedMesh, Texture

PROVENANCE_KEY = "usdbake"

LAYER_SUFFIXES = (".usd", ".usda", ".usdc")
"""Output layer types usdbake writes (.usdz is refused: a package would have to hold its sidecars)."""

TEMP_TAG = ".usdbake-tmp-"
"""Marks usdbake's temporary files: ``.<output name>.usdbake-tmp-<pid>-<token>...``."""


def is_bake_layer(layer: Sdf.Layer) -> bool:
    """The layer's customLayerData holds usdbake's provenance dictionary (something else under that key,
    written by hand or corrupted, does not make a layer ours)."""
    return isinstance(dict(layer.customLayerData).get(PROVENANCE_KEY), dict)


def provenance_of(layer: Sdf.Layer) -> dict:
    """The provenance dictionary of a bake layer ({} for any other layer)."""
    value = dict(layer.customLayerData).get(PROVENANCE_KEY)
    return dict(value) if isinstance(value, dict) else {}


def bake_source(path: str) -> str:
    """The layer a bake should read: ``path`` itself, or the input a usdbake output sublayers."""
    layer = Sdf.Layer.FindOrOpen(path)
    if layer is None:
        raise UsageError(f"{path}: cannot be opened as a USD layer")
    while is_bake_layer(layer) and layer.subLayerPaths:
        source = layer.ComputeAbsolutePath(layer.subLayerPaths[0])
        layer = Sdf.Layer.FindOrOpen(source)
        if layer is None:
            raise UsageError(f"{path}: its source layer {source} cannot be opened")
    return layer.realPath or layer.identifier


def author(layer: Sdf.Layer, outputs: list, provenance: dict, *, texture_dir: str | None = None,
           sidecar_prefix: str | None = None, owner: str | None = None, commit: bool = True) -> "StagedFiles":
    """Author output records into ``layer`` (replacing what an earlier bake put there).

    Texture and File records become sidecar files in ``texture_dir`` (default: the layer's folder),
    named ``<sidecar_prefix>_<record name>_<hash8>.<ext>`` (prefix default: the layer's file stem),
    and asset attributes naming a record are rewritten to the file's path relative to the layer
    (absolute for an anonymous layer). The files are written under temporary names before any USD
    edit. With ``commit`` (an in-memory layer: its edits are live at once) they are renamed into
    place before the layer names them, and the sidecars the layer named before and no longer does
    are removed after (only files it still owns: ``owned_sidecars``); without, the caller commits the
    returned StagedFiles once the layer is saved (see save_atomically). The sidecars are listed in the
    provenance under ``sidecars``, with the SHA-256 of each file's bytes under ``sidecarDigests``.
    """
    check_topology(outputs)
    directory = Path(texture_dir or Path(layer.realPath or ".").parent).resolve()
    anchor = Path(layer.realPath).resolve().parent if layer.realPath else None
    prefix = sidecar_prefix or (Path(layer.realPath).stem if layer.realPath else "usdbake")
    outputs, sidecars = assign_sidecars(outputs, prefix, directory, anchor)
    prepared = _prepare(outputs)  # convert every value first: a bad record fails before any edit
    previous = owned_sidecars(layer, folder=directory, prefix=prefix) if is_bake_layer(layer) else {}
    staged = StagedFiles(owner or prefix)
    try:
        for sidecar in sidecars:
            staged.write(sidecar)
        if commit:
            staged.commit()
        # string[] (Vt.StringArray): a Python list would be a VtValue vector, which usdc cannot store
        provenance = {**provenance,
                      "sidecars": Vt.StringArray([sidecar.asset_path for sidecar in sidecars]),
                      "sidecarDigests": Vt.StringArray([staged.digests[sidecar.path] for sidecar in sidecars])}
        with Sdf.ChangeBlock():
            if is_bake_layer(layer):
                _clear_opinions(layer)
            for record in outputs:
                if isinstance(record, Prim):
                    _author_prim(layer, record)
            for record, value in prepared:
                if isinstance(record, Primvar):
                    _author_primvar(layer, record, value)
                else:
                    _author_attribute(layer, record, value)
            _cover_time_samples(layer, outputs)
            data = dict(layer.customLayerData)
            data[PROVENANCE_KEY] = _sanitize(provenance)
            layer.customLayerData = data
        if commit:
            remove_sidecars({path: sha for path, sha in previous.items() if path not in staged.finals})
    except BaseException:  # KeyboardInterrupt too: no temporary file outlives a failed bake
        staged.discard()
        if commit:
            staged.take_back()
        raise
    return staged


def _prepare(outputs: list) -> list[tuple]:
    """(record, Vt/Gf value or None) for every Primvar and Attribute, converted before authoring."""
    prepared = []
    for record in outputs:
        if isinstance(record, Primvar):
            prepared.append((record, to_vt(record.values, record.type_name + "[]")))
        elif isinstance(record, Attribute):
            value = to_vt(record.value, record.type_name) if record.value is not None else None
            prepared.append((record, value))
    return prepared


# ---------------------------------------------------------------------------
# Sidecar files: named by output and content, staged under temporary names


@dataclass(frozen=True)
class Sidecar:
    """A Texture or File record with the file it becomes."""

    record: Texture | File
    path: Path
    """Absolute final path."""
    asset_path: str
    """What the layer's asset attributes hold: './name' relative to the layer, or absolute."""


def sidecar_name(record: Texture | File, prefix: str) -> str:
    """``<prefix>_<record path made file-safe, without extension>_<hash8><ext>``.

    The hash is of the content (for a texture: dtype, shape and bytes), so two outputs, or two
    parameter sets, never share a name unless they share the bytes.
    """
    digest = hashlib.sha256()
    if isinstance(record, Texture):
        pixels = np.ascontiguousarray(record.pixels)
        digest.update(f"{pixels.dtype.str}{pixels.shape}".encode())
        digest.update(pixels.tobytes())
    else:
        digest.update(record.data)
    relative = Path(_asset_key(record.path))
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", relative.with_suffix("").as_posix()).strip("_") or "data"
    return f"{prefix}_{stem}_{digest.hexdigest()[:8]}{relative.suffix}"


def assign_sidecars(outputs: list, prefix: str, directory: Path, anchor: Path | None) -> tuple[list, list[Sidecar]]:
    """Name every Texture/File record's file and point the asset attributes that name it there.

    ``anchor`` is the layer's folder (asset paths relative to it), None for an anonymous layer
    (absolute paths: an anonymous layer anchors nothing).
    """
    sidecars: dict[str, Sidecar] = {}
    renamed: dict[str, str] = {}
    for record in outputs:
        if not isinstance(record, (Texture, File)):
            continue
        path = directory / sidecar_name(record, prefix)
        if anchor is None:
            asset = path.as_posix()
        else:
            relative = Path(os.path.relpath(path, anchor)).as_posix()
            asset = relative if relative.startswith("../") else f"./{relative}"
        sidecars.setdefault(path.name, Sidecar(record, path, asset))
        renamed[_asset_key(record.path)] = asset
    if not renamed:
        return list(outputs), []
    rewritten = []
    for record in outputs:
        if isinstance(record, (Texture, File)):
            continue
        if isinstance(record, Attribute) and record.type_name == "asset" and record.value is not None:
            target = renamed.get(_asset_key(str(record.value)))
            if target is not None:
                record = replace(record, value=target)
        rewritten.append(record)
    return rewritten, list(sidecars.values())


def _asset_key(path: str) -> str:
    """A record path or asset value as a comparable relative path ('./a/b.png' and 'a/b.png' match)."""
    return os.path.normpath(path.replace("\\", "/"))


class StagedFiles:
    """Sidecars written under temporary names beside their final ones; commit() renames them into
    place, discard() removes whatever was not committed."""

    def __init__(self, owner: str):
        self.owner = owner
        """The output's file name the temporary names start with."""
        self.pending: list[tuple[Path, Path]] = []
        self.finals: set[Path] = set()
        """Final paths committed."""
        self.created: set[Path] = set()
        """Final paths that did not exist before commit (what to take back if the layer never lands)."""
        self.digests: dict[Path, str] = {}
        """SHA-256 (hex) of each written file's bytes, by final path."""

    def write(self, sidecar: Sidecar) -> None:
        sidecar.path.parent.mkdir(parents=True, exist_ok=True)
        temp = temp_path(sidecar.path.parent, self.owner, sidecar.path.name)
        self.pending.append((temp, sidecar.path))
        if isinstance(sidecar.record, Texture):
            _write_image(sidecar.record.pixels, temp)
        else:
            temp.write_bytes(sidecar.record.data)
        self.digests[sidecar.path] = file_sha256(temp)

    def commit(self) -> None:
        while self.pending:
            temp, final = self.pending[0]
            if not final.exists():
                self.created.add(final)
            os.replace(temp, final)
            self.pending.pop(0)
            self.finals.add(final)

    def discard(self) -> None:
        for temp, _ in self.pending:
            temp.unlink(missing_ok=True)
        self.pending.clear()

    def take_back(self) -> None:
        """Remove the committed files that were new: their layer never came to name them."""
        for path in self.created:
            path.unlink(missing_ok=True)
        self.created.clear()


def temp_path(folder: Path, owner: str, tail: str) -> Path:
    """A recognisable temporary name in ``folder``: ``.<owner>.usdbake-tmp-<pid>-<token>-<tail>``.

    ``tail`` keeps the final extension, which Sdf and OpenImageIO pick the file format by.
    """
    return Path(folder) / f".{owner}{TEMP_TAG}{os.getpid()}-{secrets.token_hex(4)}-{tail}"


def remove_stale_temps(out: Path) -> list[Path]:
    """Remove temporary files an earlier, killed bake into ``out`` left beside it (returns them).

    Only files whose writing process is gone: a bake into the same output running right now in
    another process keeps its files.
    """
    removed = []
    pattern = re.compile(rf"^\.{re.escape(out.name)}{re.escape(TEMP_TAG)}(\d+)-")
    for path in out.parent.glob(f".{out.name}{TEMP_TAG}*"):
        match = pattern.match(path.name)
        if match and path.is_file() and not _process_alive(int(match.group(1))):
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True  # another bake of this process (a thread) may be writing them
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OSError:
        return False
    return True


def file_sha256(path: Path) -> str:
    with open(path, "rb") as file:
        return hashlib.file_digest(file, "sha256").hexdigest()


def sidecar_pattern(prefix: str) -> re.Pattern:
    """The names ``sidecar_name`` gives with ``prefix``: ``<prefix>_<record>_<hash8>[.<ext>]``."""
    return re.compile(rf"{re.escape(prefix)}_[A-Za-z0-9_.-]+_[0-9a-f]{{8}}(\.[A-Za-z0-9]+)?")


def owned_sidecars(layer: Sdf.Layer, *, folder: Path | None = None, prefix: str | None = None) -> dict[Path, str]:
    """{absolute path: recorded SHA-256} of the sidecars a bake layer recorded that it may own.

    A recorded name counts only when it lies directly in ``folder`` (default: the layer's own
    folder; none for an anonymous layer), carries the sidecar name with ``prefix`` (default: the
    layer's file stem) and has a recorded digest. ``..``, absolute paths elsewhere, subfolders, other
    names and a layer written without digests give nothing: a layer's provenance is user-editable
    text, and what it names is not ours to delete or serve unless all of these hold. Whether the
    file is still the one written (not replaced, not a link) is checked where it is used
    (``is_owned_file``).
    """
    if folder is None:
        if not layer.realPath:
            return {}
        folder = Path(layer.realPath).resolve().parent
    if prefix is None:
        if not layer.realPath:
            return {}
        prefix = Path(layer.realPath).stem
    provenance = provenance_of(layer)
    names, digests = provenance.get("sidecars"), provenance.get("sidecarDigests")
    if not all(isinstance(value, (list, tuple, Vt.StringArray)) for value in (names, digests)) \
            or len(names) != len(digests):
        return {}
    folder, pattern = Path(folder), sidecar_pattern(prefix)
    owned = {}
    for name, sha in zip(names, digests):
        if not isinstance(name, str) or not isinstance(sha, str) or not re.fullmatch(r"[0-9a-f]{64}", sha):
            continue
        path = Path(os.path.normpath(folder / name))  # an absolute name replaces folder
        if path.parent == folder and pattern.fullmatch(path.name):
            owned[path] = sha
    return owned


def is_owned_file(path: Path, sha256: str) -> bool:
    """True when ``path`` is a plain file (a link is never followed) whose bytes hash to ``sha256``."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return False
    with os.fdopen(fd, "rb") as file:
        if not stat.S_ISREG(os.fstat(file.fileno()).st_mode):
            return False
        return hashlib.file_digest(file, "sha256").hexdigest() == sha256


def _owned_by_file(path: Path) -> dict[Path, str]:
    """The sidecars the bake layer at ``path`` owns (nothing when it is missing or not a bake layer)."""
    if not path.is_file():
        return {}
    try:
        layer = Sdf.Layer.OpenAsAnonymous(str(path), metadataOnly=True)
    except Tf.ErrorException:
        return {}
    if layer is None or not is_bake_layer(layer):
        return {}
    return owned_sidecars(layer, folder=path.resolve().parent, prefix=path.stem)


def remove_sidecars(owned: dict[Path, str]) -> None:
    """Delete the files of ``owned`` ({path: recorded SHA-256}) that are still what the bake wrote."""
    for path, sha in owned.items():
        if is_owned_file(path, sha):
            path.unlink(missing_ok=True)


def _siblings(out: Path) -> list[Path]:
    """Other layers whose sidecars share ``out``'s prefix: the same stem with another extension."""
    return [out.with_suffix(suffix) for suffix in LAYER_SUFFIXES if out.with_suffix(suffix) != out]


def _cover_time_samples(layer: Sdf.Layer, outputs: list) -> None:
    """Widen the layer's start/endTimeCode to every authored time sample, so the timeline plays them."""
    times = [r.time for r in outputs if isinstance(r, (Primvar, Attribute)) and r.time is not None]
    if not times:
        return
    if layer.HasStartTimeCode():
        times.append(layer.startTimeCode)
    if layer.HasEndTimeCode():
        times.append(layer.endTimeCode)
    layer.startTimeCode, layer.endTimeCode = float(min(times)), float(max(times))


def check_topology(outputs: list) -> None:
    """Refuse outputs whose vertex/varying/uniform/faceVarying primvars do not fit a mesh another
    record re-authors (a refined mesh): the layer would be corrupt. Processors that follow a
    refinement run on the refined Scene, so their results fit; this is the last guard."""
    unexpanded = [record.prim for record in outputs if isinstance(record, RefinedMesh)]
    if unexpanded:
        raise TypeError(f"{unexpanded[0]}: a RefinedMesh record reached the layer; expand it with "
                        f"usdbake.stages.refined_mesh.complete_outputs first")
    points, faces, corners = {}, {}, {}
    for record in outputs:
        if isinstance(record, Attribute) and record.value is not None and not isinstance(record.value, Block):
            if record.name == "points":
                points[record.prim] = len(record.value)
            elif record.name == "faceVertexCounts":
                faces[record.prim] = len(record.value)
            elif record.name == "faceVertexIndices":
                corners[record.prim] = len(record.value)
    indexed = {(record.prim, record.name, record.time): record.value for record in outputs
               if isinstance(record, Attribute) and record.name.endswith(":indices")
               and record.value is not None and not isinstance(record.value, Block)}
    for record in outputs:
        if not isinstance(record, Primvar):
            continue
        expected = {"vertex": points, "varying": points, "uniform": faces,
                    "faceVarying": corners}.get(record.interpolation, {}).get(record.prim)
        indices = indexed.get((record.prim, f"primvars:{record.name}:indices", record.time))
        count = len(indices if indices is not None else record.values) // max(1, record.element_size)
        if expected is not None and count != expected:
            raise UsageError(
                f"{record.prim}.primvars:{record.name}: {count} {record.interpolation} values for a mesh "
                f"re-authored with {expected}; refusing to write data that does not fit its topology")


def _clear_opinions(layer: Sdf.Layer) -> None:
    """Remove the prim specs of an earlier bake, keeping sublayers and layer metadata."""
    for prim_spec in list(layer.rootPrims):
        del layer.rootPrims[prim_spec.name]


def new_output_layer(temp_path: str, source_path: str, out_path: str) -> Sdf.Layer:
    """A new layer at ``temp_path`` that sublayers ``source_path`` relative to ``out_path``'s folder."""
    layer = Sdf.Layer.CreateNew(temp_path)
    if layer is None:
        raise UsageError(f"{out_path}: cannot create a layer there")
    relative = os.path.relpath(source_path, start=str(Path(out_path).resolve().parent))
    layer.subLayerPaths.append(Path(relative).as_posix())
    source = Sdf.Layer.FindOrOpen(source_path)
    for key in ("upAxis", "metersPerUnit", "startTimeCode", "endTimeCode", "timeCodesPerSecond"):
        if source is not None and source.pseudoRoot.HasInfo(key):
            layer.pseudoRoot.SetInfo(key, source.pseudoRoot.GetInfo(key))
    if source is not None and source.defaultPrim:
        layer.defaultPrim = source.defaultPrim
    return layer


def save_atomically(out_path: str, source_path: str, outputs: list, provenance: dict) -> None:
    """Write a new bake layer and its sidecars to ``out_path``'s folder via temporary names and renames.

    Sidecars are renamed into place first and the layer last; then the sidecars the replaced
    output named and the new one does not are removed. On any failure, KeyboardInterrupt included,
    the temporary files are removed and an earlier output stays as it was.
    """
    out = Path(out_path).resolve()
    if out == Path(source_path).resolve():
        raise UsageError(f"{out_path}: refusing to overwrite the input layer; choose another -o")
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(out)
    temp = temp_path(out.parent, out.name, out.name)  # ends in the output's suffix: Sdf needs it
    staged, replaced = None, False
    try:
        with write_failures(out_path):
            layer = new_output_layer(str(temp), source_path, str(out))
            staged = author(layer, outputs, provenance, texture_dir=str(out.parent), sidecar_prefix=out.stem,
                            owner=out.name, commit=False)
            if not layer.Save():
                raise OSError(errno.EIO, "USD could not save the layer")
            previous = _owned_by_file(out)
            staged.commit()
            os.replace(temp, out)
        replaced = True
        reloaded = Sdf.Layer.Find(str(out))
        if reloaded is not None:  # a stale copy from an earlier bake in this process
            reloaded.Reload(force=True)
        kept = set().union(*(_owned_by_file(sibling) for sibling in _siblings(out)))
        remove_sidecars({path: sha for path, sha in previous.items() if path not in staged.finals and path not in kept})
    finally:
        if staged is not None:
            staged.discard()
            if not replaced:  # sidecars renamed into place for a layer that never landed
                staged.take_back()
        temp.unlink(missing_ok=True)


@contextlib.contextmanager
def write_failures(target: str):
    """Turn a failed write (OSError: a full disk, ``ulimit -f``, a quota; USD's Tf error from a failed
    save) into one OutputError line naming ``target`` and the reason."""
    try:
        yield
    except OSError as error:
        raise OutputError(f"{target}: could not be written ({error.strerror or error}); the previous output "
                          f"is unchanged") from None
    except Tf.ErrorException as error:
        found = re.search(r"Error occurred writing file: ([^']+)", str(error))
        reason = found.group(1) if found else "USD could not save the layer"
        raise OutputError(f"{target}: could not be written ({reason}); the previous output is unchanged") from None


def write_texture(texture: Texture, directory: str) -> str:
    """Write an image with OpenImageIO (float -> EXR/half data as given, uint8 -> PNG) to
    ``directory / texture.path``; returns the path."""
    path = Path(directory) / texture.path
    path.parent.mkdir(parents=True, exist_ok=True)
    _write_image(texture.pixels, path)
    return str(path)


def _write_image(pixels: np.ndarray, path: Path) -> None:
    import OpenImageIO as oiio

    pixels = np.ascontiguousarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    fmt = oiio.UINT8 if pixels.dtype == np.uint8 else oiio.FLOAT
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], fmt)
    output = oiio.ImageOutput.create(str(path))
    if output is None or not output.open(str(path), spec):
        raise OSError(errno.EIO, f"OpenImageIO cannot write {path.name}: {oiio.geterror()}")
    # write_image can return True after short writes (a full disk): its error text is the only sign
    written = output.write_image(pixels)
    error = output.geterror()
    closed = output.close()
    error = error or output.geterror()
    if not written or not closed or error:
        raise OSError(errno.EIO, f"OpenImageIO: {error.splitlines()[0] if error else 'the image was not written'}")


def _author_prim(layer: Sdf.Layer, record: Prim) -> None:
    spec = Sdf.CreatePrimInLayer(layer, record.path)
    if record.type_name:
        spec.specifier = Sdf.SpecifierDef
        spec.typeName = record.type_name
    if record.api_schemas:
        spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=list(record.api_schemas)))
    if record.instanceable is not None:
        spec.instanceable = record.instanceable


def _attribute_spec(layer: Sdf.Layer, prim_path: str, name: str, type_name: str, *,
                    uniform: bool = False, custom: bool = False) -> Sdf.AttributeSpec:
    prim_spec = Sdf.CreatePrimInLayer(layer, prim_path)
    existing = prim_spec.attributes.get(name)
    if existing is not None:
        return existing
    value_type = Sdf.ValueTypeNames.Find(type_name)
    if not value_type:
        raise ValueError(f"{prim_path}.{name}: unknown USD type {type_name!r}")
    variability = Sdf.VariabilityUniform if uniform else Sdf.VariabilityVarying
    return Sdf.AttributeSpec(prim_spec, name, value_type, variability, custom)


def _author_primvar(layer: Sdf.Layer, record: Primvar, value) -> None:
    spec = _attribute_spec(layer, record.prim, f"primvars:{record.name}", record.type_name + "[]")
    spec.SetInfo("interpolation", record.interpolation)
    spec.SetInfo("elementSize", int(record.element_size))
    _set_value(layer, spec, value, record.time)


def _author_attribute(layer: Sdf.Layer, record: Attribute, value) -> None:
    spec = _attribute_spec(layer, record.prim, record.name, record.type_name, uniform=record.uniform)
    if record.connect_to:
        spec.connectionPathList.explicitItems = [Sdf.Path(record.connect_to)]
    if value is not None:
        _set_value(layer, spec, value, record.time)


def _set_value(layer: Sdf.Layer, spec: Sdf.AttributeSpec, value, time: float | None) -> None:
    if time is None:
        spec.default = value
    else:
        layer.SetTimeSample(spec.path, float(time), value)


def to_vt(value, type_name: str):
    """Convert numpy data to the Vt/Gf value Sdf expects for ``type_name`` (e.g. 'color3f[]')."""
    value_type = Sdf.ValueTypeNames.Find(type_name)
    if isinstance(value, Block):
        return Sdf.ValueBlock()
    if type_name == "asset":
        return Sdf.AssetPath(str(value))
    if value_type.isArray:
        array_class = value_type.type.pythonClass
        return array_class.FromNumpy(np.ascontiguousarray(value))
    if isinstance(value, np.ndarray):
        return value_type.type.pythonClass(*value.tolist()) if value.ndim else value.item()
    return value


def _sanitize(value):
    """Make provenance storable as layer metadata (no None, plain Python scalars)."""
    if isinstance(value, dict):
        return {str(k): _sanitize(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        if all(isinstance(v, str) for v in value):
            return Vt.StringArray(list(value))  # string[]: a list would be a VtValue vector usdc cannot store
        return [_sanitize(v) for v in value]
    if value is None:
        return ""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return str(value)
    return value
