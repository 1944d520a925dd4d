"""The Python hook for DCCs and pipelines: bake into an already open Usd.Stage.

    >>> import usdbake
    >>> layer = usdbake.bake(stage, processors=["ambient_occlusion"],
    ...                      params={"ambient_occlusion": {"samples": 64}})

Results go into a layer the call returns: by default a new anonymous layer
inserted as the strongest sublayer of the stage's session layer (reused on
the next call), so no layer of the user's is touched.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from pxr import Sdf, Usd

from ..core.pipeline import Pipeline
from ..core.records import File, Texture
from .bake_layer import PROVENANCE_KEY, author, is_bake_layer
from .extract import extract_scene


def bake(stage: Usd.Stage, processors=None, params=None, *, layer: Sdf.Layer | None = None,
         time: float | None = None, device: str = "cpu", cache_dir: str | None = None, force: bool = False,
         texture_dir: str | None = None, on_progress=None) -> Sdf.Layer:
    """Run processors on ``stage`` and author their results into a bake layer.

    Parameters
    ----------
    stage : an open Usd.Stage (may be in memory, never saved)
    processors : processor names (default: ambient_occlusion); dependencies are added
    params : {processor: {param: value}}
    layer : where to author; default: the session layer's usdbake sublayer (created if missing)
    time : time code to read the stage at (None: default time)
    texture_dir : folder for texture outputs (default: beside the stage's root layer, else a temp folder)

    Returns
    -------
    The Sdf.Layer holding the results. On failure nothing is authored.
    """
    pipeline = Pipeline.build(processors, params, device=device, cache_dir=cache_dir, force=force)
    target = layer if layer is not None else _session_bake_layer(stage)
    muted = _mute_for_extraction(stage, target)
    try:
        scene = extract_scene(stage, time=time)
    finally:
        if muted:
            stage.UnmuteLayer(target.identifier)
    pipeline.run(scene, on_progress=on_progress)
    if layer is None and target.identifier not in stage.GetSessionLayer().subLayerPaths:
        stage.GetSessionLayer().subLayerPaths.insert(0, target.identifier)
    outputs = pipeline.outputs()
    if texture_dir is None and any(isinstance(record, (Texture, File)) for record in outputs):
        texture_dir = _default_texture_dir(stage)  # only when needed: it may create a temp folder
    author(target, outputs, pipeline.provenance({"source": scene.source}), texture_dir=texture_dir)
    return target


def last_report(layer: Sdf.Layer) -> list[dict]:
    """What the last bake into ``layer`` did, one dict per processor, from the layer's provenance."""
    provenance = dict(layer.customLayerData).get(PROVENANCE_KEY, {})
    return [{"processor": name, **info} for name, info in provenance.get("processors", {}).items()]


def _session_bake_layer(stage: Usd.Stage) -> Sdf.Layer:
    """The usdbake layer among the session layer's sublayers, or a new anonymous one (not yet inserted)."""
    for identifier in stage.GetSessionLayer().subLayerPaths:
        candidate = Sdf.Layer.Find(identifier)
        if candidate is not None and is_bake_layer(candidate):
            return candidate
    layer = Sdf.Layer.CreateAnonymous("usdbake")
    layer.customLayerData = {PROVENANCE_KEY: {"pending": True}}
    return layer


def _mute_for_extraction(stage: Usd.Stage, layer: Sdf.Layer) -> bool:
    """Mute an earlier bake's layer while reading the stage, so results never feed the next bake."""
    in_stack = any(l.identifier == layer.identifier for l in stage.GetLayerStack(includeSessionLayers=True))
    if in_stack and is_bake_layer(layer) and layer.rootPrims:
        stage.MuteLayer(layer.identifier)
        return True
    return False


def _default_texture_dir(stage: Usd.Stage) -> str:
    real_path = stage.GetRootLayer().realPath
    if real_path:
        return str(Path(real_path).parent)
    return tempfile.mkdtemp(prefix="usdbake-textures-")
