"""Output records -> USD: the non-destructive bake layer.

The bake layer sublayers the untouched input (relative path) and holds only
bake opinions, all under the ``bake:`` namespace. Every edit is prepared
first (values converted, textures written) and then authored with the Sdf
API inside one ``Sdf.ChangeBlock``. Saves are atomic: write a temporary file
in the destination folder, then rename it over the destination.

A bake layer holds exactly the results of the last bake into it: re-baking
replaces its content, it never nests or duplicates.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
from pxr import Sdf, Tf, Usd

from ..core.errors import UsageError
from ..core.records import Attribute, File, Prim, Primvar, Texture

PROVENANCE_KEY = "usdbake"


def is_bake_layer(layer: Sdf.Layer) -> bool:
    return PROVENANCE_KEY in dict(layer.customLayerData)


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


def author(layer: Sdf.Layer, outputs: list, provenance: dict, *, texture_dir: str | None = None) -> None:
    """Author output records into ``layer`` (replacing what an earlier bake put there).

    Textures are written to ``texture_dir`` (default: the layer's folder) before any USD edit.
    """
    check_topology(outputs)
    for record in outputs:
        if isinstance(record, Texture):
            write_texture(record, texture_dir or str(Path(layer.realPath or ".").parent))
        elif isinstance(record, File):
            write_file(record, texture_dir or str(Path(layer.realPath or ".").parent))
    with Sdf.ChangeBlock():
        if is_bake_layer(layer):
            _clear_opinions(layer)
        for record in outputs:
            if isinstance(record, Prim):
                _author_prim(layer, record)
        for record in outputs:
            if isinstance(record, Primvar):
                _author_primvar(layer, record)
            elif isinstance(record, Attribute):
                _author_attribute(layer, record)
        _cover_time_samples(layer, outputs)
        data = dict(layer.customLayerData)
        data[PROVENANCE_KEY] = _sanitize(provenance)
        layer.customLayerData = data


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
    """Refuse outputs whose vertex/uniform primvars do not fit a mesh another record re-authors.

    A processor that refines meshes (sky_visibility) authors new points and faces; per-vertex or
    per-face data computed on the original topology by a processor that did not read the refined
    mesh would no longer line up, and the output would be corrupt.
    """
    points, faces = {}, {}
    for record in outputs:
        if isinstance(record, Attribute) and record.value is not None:
            if record.name == "points":
                points[record.prim] = len(record.value)
            elif record.name == "faceVertexCounts":
                faces[record.prim] = len(record.value)
    for record in outputs:
        if not isinstance(record, Primvar):
            continue
        expected = {"vertex": points, "uniform": faces}.get(record.interpolation, {}).get(record.prim)
        count = len(record.values) // max(1, record.element_size) if np.ndim(record.values) == 1 \
            else len(record.values)
        if expected is not None and count != expected:
            raise UsageError(
                f"{record.prim}.primvars:{record.name}: {count} {record.interpolation} values, but another "
                f"processor re-authors this mesh with {expected}; bake mesh-refining processors "
                f"(sky_visibility, daylight) in a run of their own")


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
    """Write a new bake layer to ``out_path`` via a temporary file and a rename."""
    out = Path(out_path).resolve()
    if out == Path(source_path).resolve():
        raise UsageError(f"{out_path}: refusing to overwrite the input layer; choose another -o")
    out.parent.mkdir(parents=True, exist_ok=True)
    handle, temp = tempfile.mkstemp(prefix=f".{out.stem}.", suffix=out.suffix, dir=out.parent)
    os.close(handle)
    os.unlink(temp)  # Sdf.Layer.CreateNew refuses an existing file
    try:
        layer = new_output_layer(temp, source_path, str(out))
        author(layer, outputs, provenance, texture_dir=str(out.parent))
        if not layer.Save():
            raise UsageError(f"{out_path}: could not be written")
        os.replace(temp, out)
        reloaded = Sdf.Layer.Find(str(out))
        if reloaded is not None:  # a stale copy from an earlier bake in this process
            reloaded.Reload(force=True)
    finally:
        if os.path.exists(temp):
            os.unlink(temp)


def write_texture(texture: Texture, directory: str) -> str:
    """Write an image with OpenImageIO (float -> EXR/half data as given, uint8 -> PNG)."""
    import OpenImageIO as oiio

    path = Path(directory) / texture.path
    path.parent.mkdir(parents=True, exist_ok=True)
    pixels = np.ascontiguousarray(texture.pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    fmt = oiio.UINT8 if pixels.dtype == np.uint8 else oiio.FLOAT
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], fmt)
    output = oiio.ImageOutput.create(str(path))
    if output is None or not output.open(str(path), spec):
        raise UsageError(f"{path}: OpenImageIO cannot write it ({oiio.geterror()})")
    output.write_image(pixels)
    output.close()
    return str(path)


def write_file(record: File, directory: str) -> str:
    """Write a raw file record (bytes) to ``directory / record.path``."""
    path = Path(directory) / record.path
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(record.data)
    return str(path)


def _author_prim(layer: Sdf.Layer, record: Prim) -> None:
    spec = Sdf.CreatePrimInLayer(layer, record.path)
    if record.type_name:
        spec.specifier = Sdf.SpecifierDef
        spec.typeName = record.type_name
    if record.api_schemas:
        spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=list(record.api_schemas)))


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


def _author_primvar(layer: Sdf.Layer, record: Primvar) -> None:
    spec = _attribute_spec(layer, record.prim, f"primvars:{record.name}", record.type_name + "[]")
    spec.SetInfo("interpolation", record.interpolation)
    spec.SetInfo("elementSize", int(record.element_size))
    _set_value(layer, spec, to_vt(record.values, record.type_name + "[]"), record.time)


def _author_attribute(layer: Sdf.Layer, record: Attribute) -> None:
    spec = _attribute_spec(layer, record.prim, record.name, record.type_name, uniform=record.uniform)
    if record.connect_to:
        spec.connectionPathList.explicitItems = [Sdf.Path(record.connect_to)]
    if record.value is not None:
        _set_value(layer, spec, to_vt(record.value, record.type_name), record.time)


def _set_value(layer: Sdf.Layer, spec: Sdf.AttributeSpec, value, time: float | None) -> None:
    if time is None:
        spec.default = value
    else:
        layer.SetTimeSample(spec.path, float(time), value)


def to_vt(value, type_name: str):
    """Convert numpy data to the Vt/Gf value Sdf expects for ``type_name`` (e.g. 'color3f[]')."""
    value_type = Sdf.ValueTypeNames.Find(type_name)
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
        return [_sanitize(v) for v in value]
    if value is None:
        return ""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return str(value)
    return value


def open_source(path: str):
    """Open the stage to bake: the input, or the source of a usdbake output."""
    if not Path(path).exists():
        raise UsageError(f"{path}: no such file")
    try:
        source = bake_source(path)
        stage = Usd.Stage.Open(source)
    except Tf.ErrorException as error:
        raise UsageError(f"{path}: cannot be read as USD ({_usd_reason(error)})") from None
    if stage is None:
        raise UsageError(f"{path}: cannot be read as USD")
    return source, stage


def _usd_reason(error: Exception) -> str:
    """The human part of a Tf error: the text after the last ' : ', without the quotes."""
    # Whitespace is collapsed first: a parser message can end in a newline inside its quotes.
    return " ".join(str(error).split()).rsplit(" : ", 1)[-1].strip("'\" ")
