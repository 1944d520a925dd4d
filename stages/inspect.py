"""What baked data a layer holds: provenance plus every authored property with its size."""

from __future__ import annotations

import re
from pathlib import Path

from pxr import Sdf, Tf

from ..core.errors import UsageError
from .provenance import PROVENANCE_KEY, is_bake_layer, provenance_of
from .inputs import usd_reason


def inspect_layer(path: str) -> dict:
    """{'provenance': {...}, 'properties': [{path, type, interpolation, element_size, values, time_samples}],
    'lightmaps': [{path, file, width, height, channels, format}] (the texture target's images, read with
    OpenImageIO; ``error`` instead of the size when one cannot be read)}."""
    if not Path(path).exists():
        raise UsageError(f"{path}: no such file")
    if Path(path).is_dir():
        raise UsageError(f"{path}: is a folder, not a layer")
    try:
        layer = Sdf.Layer.FindOrOpen(path)
    except Tf.ErrorException as error:
        raise UsageError(f"{path}: cannot be read as USD ({usd_reason(error, path)})") from None
    if layer is None:
        raise UsageError(f"{path}: cannot be read as USD")
    if not is_bake_layer(layer):
        raise UsageError(f"{path}: not a usdbake output (no '{PROVENANCE_KEY}' in customLayerData)")
    properties = []

    def visit(spec_path: Sdf.Path) -> None:
        if not spec_path.IsPropertyPath():
            return
        spec = layer.GetAttributeAtPath(spec_path)
        if spec is None:
            return
        default = spec.default
        properties.append({
            "path": str(spec_path), "type": str(spec.typeName),
            "interpolation": spec.GetInfo("interpolation") if spec.HasInfo("interpolation") else "",
            "element_size": spec.GetInfo("elementSize") if spec.HasInfo("elementSize") else 1,
            "values": len(default) if hasattr(default, "__len__") and not isinstance(default, str) else
            (1 if default is not None else 0),
            "time_samples": layer.GetNumTimeSamplesForPath(spec_path),
        })

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    properties.sort(key=lambda row: row["path"])
    lightmaps = [_lightmap(layer, row["path"]) for row in properties
                 if row["type"] == "asset" and re.fullmatch(r".*\.bake:lightmap:[^:]+:file", row["path"])]
    return {"provenance": _plain(provenance_of(layer)), "properties": properties,
            "sublayers": list(layer.subLayerPaths), "lightmaps": lightmaps}


def _lightmap(layer: Sdf.Layer, path: str) -> dict:
    """One lightmap file named by the layer: its size, channels and pixel format as OpenImageIO reads them. A
    file per time (daylight's) is described by its first sample, with ``times`` the number of samples."""
    import OpenImageIO as oiio

    asset = layer.GetAttributeAtPath(path).default
    times = layer.ListTimeSamplesForPath(path)
    if asset is None and times:
        asset = layer.QueryTimeSample(path, times[0])
    file = layer.ComputeAbsolutePath(asset.path) if asset is not None and asset.path else ""
    row = {"path": path, "file": asset.path if asset is not None else "", "times": len(times)}
    image = oiio.ImageInput.open(file) if file else None
    if image is None:
        row["error"] = f"cannot be read ({oiio.geterror() or 'no file'})"
        return row
    spec = image.spec()
    image.close()
    row.update({"width": spec.width, "height": spec.height, "channels": spec.nchannels, "format": str(spec.format)})
    return row


def _plain(value):
    """Layer metadata as plain Python for --json: Vt arrays (string[] sidecars, warnings) become lists."""
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)) or (hasattr(value, "__len__") and hasattr(value, "__getitem__")
                                           and not isinstance(value, (str, bytes))):
        return [_plain(item) for item in value]
    return value
