"""annual_daylight's metrics on the daylight stream's faces: the viewer's overlays, read from a bake layer.

``usdbake serve`` sends them after the daylight stream when one bake ran both ``daylight_stream`` and
``annual_daylight`` (docs/streaming.md, "Daylight in the browser"): the bake layer's own per-face primvars
on the stream's prims, put in the stream's face order, and sDA and ASE from its report prim.
"""

from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd

from ..formats.daylight_stream import decode_daylight_stream, encode_overlay, geometry_end

ANNUAL_PRIM = "/usdbake/AnnualDaylight"
ANNUAL_PRIMVARS = {"daylightAutonomy": "primvars:bake:daylightAutonomy", "daylightFactor": "primvars:bake:daylightFactor",
                   "usefulDaylight": "primvars:bake:usefulDaylight", "annualSunHours": "primvars:bake:annualSunHours",
                   "meanIlluminance": "primvars:bake:meanIlluminance"}
"""annual_daylight's per-face results the viewer overlays (``usefulDaylight``: below, within, above the band)."""


def annual_overlay(stage: Usd.Stage, layer: Sdf.Layer, daylight: bytes) -> bytes | None:
    """annual_daylight's per-face metrics on the daylight stream's faces, in stream order, from the bake layer's
    own primvars on the stream's prims (a prim's primvar element k is its k-th face in the bake's face order);
    None when the layer has none or they do not fit the stream's faces."""
    prefix = decode_daylight_stream(daylight[:geometry_end(lambda end: daylight[:end])])
    faces = len(prefix.face_id)
    by_prim = []  # per prim: its stream positions in the bake's face order (its primvars' element order)
    for index, prim in enumerate(prefix.header["prims"]):
        positions = np.flatnonzero(prefix.prim == index)
        by_prim.append((prim["path"], positions[np.argsort(prefix.face_id[positions], kind="stable")]))
    metrics = {}
    for name, attribute in ANNUAL_PRIMVARS.items():
        width = 3 if name == "usefulDaylight" else 1
        values = np.full((faces, width), np.nan, np.float32)
        for path, positions in by_prim:
            spec = layer.GetAttributeAtPath(f"{path}.{attribute}")
            data = np.asarray(spec.default if spec is not None and spec.default is not None else [], np.float32)
            if data.size != width * len(positions):
                return None
            values[positions] = data.reshape(-1, width)
        if width == 3:
            metrics.update({f"{name}{part}": values[:, k] for k, part in enumerate(("Below", "Within", "Above"))})
        else:
            metrics[name] = values[:, 0]
    report = stage.GetPrimAtPath(ANNUAL_PRIM)
    summary = {key: float(report.GetAttribute(f"bake:annual:{key}").Get()) for key in ("sDA", "ASE")
               if report and report.GetAttribute(f"bake:annual:{key}").HasAuthoredValue()}
    return encode_overlay(metrics, summary)
