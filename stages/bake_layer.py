"""Output records -> USD: the non-destructive bake layer.

The bake layer sublayers the untouched input (relative path) and holds only
bake opinions, all under the ``bake:`` namespace. Every edit is prepared
first (values converted, sidecar files written under temporary names) and
then authored with the Sdf API inside one ``Sdf.ChangeBlock``. Saves are
atomic: the layer and its sidecars are written to temporary names in the
destination folder, then renamed, sidecars first and the layer last, so a
layer on disk never names a file that is not there. How sidecars are named,
staged and owned (a re-bake removes only files the layer still owns):
``stages.sidecars``.

A bake layer holds exactly the results of the last bake into it: re-baking
replaces its content, it never nests or duplicates.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
from pathlib import Path

import numpy as np
from pxr import Sdf, Tf, Vt

from ..core.errors import OutputError, UsageError
from ..core.records import Attribute, Block, Prim, Primvar, RefinedMesh, Relationship
from .provenance import PROVENANCE_KEY, is_bake_layer
from .sidecars import (StagedFiles, assign_sidecars, owned_by_file, owned_sidecars, remove_sidecars,
                       remove_stale_temps, temp_path)

LAYER_SUFFIXES = (".usd", ".usda", ".usdc")
"""Output layer types usdbake writes (.usdz is refused: a package would have to hold its sidecars)."""


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
                elif isinstance(record, Relationship):
                    _author_relationship(layer, record)
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
            previous = owned_by_file(out)
            staged.commit()
            os.replace(temp, out)
        replaced = True
        reloaded = Sdf.Layer.Find(str(out))
        if reloaded is not None:  # a stale copy from an earlier bake in this process
            reloaded.Reload(force=True)
        kept = set().union(*(owned_by_file(sibling) for sibling in _siblings(out)))
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


def _author_prim(layer: Sdf.Layer, record: Prim) -> None:
    spec = Sdf.CreatePrimInLayer(layer, record.path)
    if record.type_name:
        spec.specifier = Sdf.SpecifierDef
        spec.typeName = record.type_name
    if record.api_schemas:  # added to what earlier records applied to the prim (several processors, or channels)
        earlier = list(spec.GetInfo("apiSchemas").prependedItems) if spec.HasInfo("apiSchemas") else []
        schemas = earlier + [name for name in record.api_schemas if name not in earlier]
        spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=schemas))
    if record.instanceable is not None:
        spec.instanceable = record.instanceable
    for path in record.references:
        spec.referenceList.Prepend(Sdf.Reference(primPath=Sdf.Path(path)))


def _author_relationship(layer: Sdf.Layer, record: Relationship) -> None:
    prim = Sdf.CreatePrimInLayer(layer, record.prim)
    spec = prim.relationships.get(record.name) or Sdf.RelationshipSpec(prim, record.name, custom=False)
    spec.targetPathList.explicitItems = [Sdf.Path(target) for target in record.targets]


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
    spec = _attribute_spec(layer, record.prim, record.name, record.type_name, uniform=record.uniform,
                           custom=record.custom)
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
