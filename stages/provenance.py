"""What makes a layer a bake layer: usdbake's provenance dictionary under PROVENANCE_KEY in its
customLayerData (version, processors, params, sidecars and their digests)."""

from __future__ import annotations

from pxr import Sdf

PROVENANCE_KEY = "usdbake"


def is_bake_layer(layer: Sdf.Layer) -> bool:
    """The layer's customLayerData holds usdbake's provenance dictionary (something else under that key,
    written by hand or corrupted, does not make a layer ours)."""
    return isinstance(dict(layer.customLayerData).get(PROVENANCE_KEY), dict)


def provenance_of(layer: Sdf.Layer) -> dict:
    """The provenance dictionary of a bake layer ({} for any other layer)."""
    value = dict(layer.customLayerData).get(PROVENANCE_KEY)
    return dict(value) if isinstance(value, dict) else {}
