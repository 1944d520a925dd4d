"""What baked data a layer holds: provenance plus every authored property with its size."""

from __future__ import annotations

from pathlib import Path

from pxr import Sdf

from ..core.errors import UsageError
from .bake_layer import PROVENANCE_KEY, is_bake_layer


def inspect_layer(path: str) -> dict:
    """{'provenance': {...}, 'properties': [{path, type, interpolation, element_size, values, time_samples}]}."""
    if not Path(path).exists():
        raise UsageError(f"{path}: no such file")
    layer = Sdf.Layer.FindOrOpen(path)
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
    return {"provenance": dict(layer.customLayerData[PROVENANCE_KEY]), "properties": properties,
            "sublayers": list(layer.subLayerPaths)}
