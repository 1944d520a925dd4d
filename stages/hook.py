"""The Python hook for DCCs and pipelines: bake into an already open Usd.Stage.

    >>> import usdbake
    >>> layer = usdbake.bake(stage, processors=["ambient_occlusion"],
    ...                      params={"ambient_occlusion": {"samples": 64}})

Results go into a layer the call returns: by default a new anonymous layer
inserted as the strongest sublayer of the stage's session layer (reused on
the next call), so no layer of the user's is touched.

Sidecar files (textures, .dds, .npz, streams) go to ``texture_dir`` named
``<stage stem>.usdbake_<record>_<content hash>.<ext>`` (``<layer stem>_...``
when ``layer`` is a file); an anonymous layer names them by absolute path,
since it anchors no relative one. A bake that would author nothing (every
processor skipped) raises UsageError and leaves the layer as it was, as the
command does.
"""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path

from pxr import Sdf, Usd, Vt

from ..core.errors import UsageError
from ..core.params import ParamError
from ..core.pipeline import Pipeline
from ..core.records import File, Texture
from ..core.runtime import Runtime
from ..kernels.tracer import Tracer
from .bake_file import compute_outputs
from .bake_layer import author, write_failures
from .provenance import PROVENANCE_KEY, is_bake_layer, provenance_of
from .inputs import check_cache_folder, check_device, check_writable_folder


def bake(stage: Usd.Stage, processors=None, params=None, *, layer: Sdf.Layer | None = None,
         time: float | None = None, device: str = "cpu", cache_dir: str | None = None, force: bool = False,
         texture_dir: str | None = None, on_progress=None, allow_missing: bool = False,
         deinstance: bool = False, threads: int | None = None, target: str | None = None) -> Sdf.Layer:
    """Run processors on ``stage`` and author their results into a bake layer.

    Parameters
    ----------
    stage : an open Usd.Stage (may be in memory, never saved)
    processors : processor names (default: ambient_occlusion); dependencies are added
    params : {processor: {param: value}}
    layer : where to author; default: the session layer's usdbake sublayer (created if missing)
    time : time code to read the stage at (None: default time)
    texture_dir : folder for texture outputs (default: beside the stage's root layer, else a temp folder)
    allow_missing : bake without missing or unreadable sublayers, references and payloads (each one a
        warning) instead of raising StageError naming the first
    deinstance : bake natively instanced meshes as ordinary ones (per vertex); the layer sets
        ``instanceable = false`` on the instances whose meshes receive data
    threads : CPU threads for ray casting (None, the default: every core)
    target : where per-surface results go, for every processor that has a ``target`` param and is not given
        its own in ``params``: 'vertex' (primvars), 'texture' (lightmaps on the asset's UVs; no mesh is
        changed) or 'both'; None keeps each processor's default (vertex)
    on_progress : ``on_progress(name, fraction)`` hears 'reading stage' and each processor

    Warnings (missing assets allowed, textures that could not be read and the fallback used, faces
    left out) are issued as Python warnings and kept in the layer's report: ``last_warnings(layer)``.

    Returns
    -------
    The Sdf.Layer holding the results. On failure nothing is authored.
    """
    processors = check_arguments(stage, processors, params, layer=layer, device=device, cache_dir=cache_dir,
                                 texture_dir=texture_dir)
    runtime = Runtime(Tracer.from_scene, device=device, threads=threads)
    pipeline = Pipeline.build(processors, params, runtime=runtime, cache_dir=cache_dir, force=force, target=target)
    target = layer if layer is not None else _session_bake_layer(stage)
    muted = _mute_for_extraction(stage, target)
    try:  # the stage is read without an earlier bake's opinions, also where refined meshes are completed
        scene, outputs = compute_outputs(stage, pipeline, time_code=time, allow_missing=allow_missing,
                                         deinstance=deinstance, on_progress=on_progress)
    finally:
        if muted:
            stage.UnmuteLayer(target.identifier)
    if layer is None and target.identifier not in stage.GetSessionLayer().subLayerPaths:
        stage.GetSessionLayer().subLayerPaths.insert(0, target.identifier)
    if texture_dir is None and any(isinstance(record, (Texture, File)) for record in outputs):
        texture_dir = _default_texture_dir(stage)  # only when needed: it may create a temp folder
    report = {"source": scene.source, "warnings": Vt.StringArray(list(scene.warnings))}  # string[]: usdc stores it
    with write_failures(texture_dir or target.identifier):
        author(target, outputs, pipeline.provenance(report), texture_dir=texture_dir,
               sidecar_prefix=_sidecar_prefix(stage, target))
    for message in scene.warnings:
        warnings.warn(f"usdbake: {message}", stacklevel=2)
    return target


def check_arguments(stage, processors, params, *, layer, device, cache_dir, texture_dir) -> list | None:
    """Refuse, before the stage is read, arguments that would fail later or harm a layer; returns the
    processor names as a list (one name given as a string is one processor). Raises UsageError
    (ParamError for params) with the one-line messages the command prints."""
    if not isinstance(stage, Usd.Stage):
        raise UsageError(f"stage={_shown(stage)}: expected an open Usd.Stage (Usd.Stage.Open(path))")
    if isinstance(processors, str):
        processors = [processors]
    elif processors is not None:
        if not isinstance(processors, (list, tuple)) or not all(isinstance(name, str) for name in processors):
            raise UsageError(f"processors={_shown(processors)}: expected a processor name or a list of names")
        processors = list(processors)
    if params is not None and (not isinstance(params, dict) or not all(
            isinstance(name, str) and isinstance(values, dict) for name, values in params.items())):
        raise ParamError(f"params={_shown(params)}: expected {{processor: {{param: value}}}}, e.g. "
                         f"{{'ambient_occlusion': {{'samples': 64}}}}")
    check_device(device, option="device=")
    if cache_dir is not None:
        check_cache_folder(cache_dir, option="cache_dir=")
    if texture_dir is not None:
        if Path(texture_dir).exists() and not Path(texture_dir).is_dir():
            raise UsageError(f"texture_dir={texture_dir}: is a file, not a folder")
        check_writable_folder(Path(texture_dir), what=f"texture_dir={texture_dir}")
    if layer is not None:
        if not isinstance(layer, Sdf.Layer):
            raise UsageError(f"layer={_shown(layer)}: expected an Sdf.Layer (or None for the session layer's)")
        own = {used.identifier for used in stage.GetLayerStack(includeSessionLayers=False)}
        if layer.identifier in own and not is_bake_layer(layer) or layer == stage.GetRootLayer():
            raise UsageError(f"layer={layer.identifier}: a layer of the stage's own content; a bake replaces "
                             f"everything in its layer, so give a new layer (Sdf.Layer.CreateAnonymous()) or none")
    return processors


def _shown(value) -> str:
    """A value as an error line shows it: short, one line."""
    text = repr(value).replace("\n", " ")
    return text if len(text) <= 60 else text[:57] + "..."


def last_report(layer: Sdf.Layer) -> list[dict]:
    """What the last bake into ``layer`` did, one dict per processor, from the layer's provenance."""
    provenance = provenance_of(layer)
    return [{"processor": name, **info} for name, info in provenance.get("processors", {}).items()]


def last_warnings(layer: Sdf.Layer) -> list[str]:
    """The warnings of the last bake into ``layer`` (missing assets allowed, unreadable textures), one line each."""
    return list(provenance_of(layer).get("warnings", []))


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


def _sidecar_prefix(stage: Usd.Stage, layer: Sdf.Layer) -> str:
    """File-name prefix of a bake's sidecars: the layer's stem, else '<root layer stem>.usdbake'."""
    if layer.realPath:
        return Path(layer.realPath).stem
    root = stage.GetRootLayer().realPath
    return f"{Path(root).stem}.usdbake" if root else "usdbake"


def _default_texture_dir(stage: Usd.Stage) -> str:
    real_path = stage.GetRootLayer().realPath
    if real_path:
        return str(Path(real_path).parent)
    return tempfile.mkdtemp(prefix="usdbake-textures-")
