"""stages/annual_overlay.py: annual_daylight's primvars on the window_room, put in the daylight stream's face
order, are the bake's values face for face; a layer without them, or whose counts do not fit, gives none."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Sdf, Usd

from daylight_served import bake_daylight, tmy3
from usdbake.formats.daylight_stream import decode_daylight_stream, decode_overlay
from usdbake.stages.annual_overlay import annual_overlay

pytest.importorskip("pvlib")


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    out = bake_daylight(tmp_path_factory.mktemp("overlay"), tmy3())
    return out, next(out.parent.glob("room_daylight_*.bin")).read_bytes()


def test_the_overlay_is_the_bakes_primvars_in_stream_order(baked):
    path, stream = baked
    stage = Usd.Stage.Open(str(path))
    summary, metrics = decode_overlay(annual_overlay(stage, stage.GetRootLayer(), stream))
    report = stage.GetPrimAtPath("/usdbake/AnnualDaylight")
    assert summary["sDA"] == pytest.approx(report.GetAttribute("bake:annual:sDA").Get())
    prefix = decode_daylight_stream(stream)
    for index, prim in enumerate(prefix.header["prims"]):
        positions = np.flatnonzero(prefix.prim == index)
        positions = positions[np.argsort(prefix.face_id[positions])]
        primvars = stage.GetPrimAtPath(prim["path"])
        np.testing.assert_array_equal(metrics["daylightAutonomy"][positions],
                                      np.asarray(primvars.GetAttribute("primvars:bake:daylightAutonomy").Get()))
        useful = np.asarray(primvars.GetAttribute("primvars:bake:usefulDaylight").Get()).reshape(-1, 3)
        np.testing.assert_array_equal(metrics["usefulDaylightAbove"][positions], useful[:, 2])


def test_no_overlay_without_fitting_primvars(baked):
    path, stream = baked
    stage = Usd.Stage.Open(str(path))
    first = decode_daylight_stream(stream).header["prims"][0]["path"]
    layer = Sdf.Layer.CreateAnonymous()
    layer.TransferContent(stage.GetRootLayer())
    spec = layer.GetAttributeAtPath(f"{first}.primvars:bake:daylightFactor")
    spec.default = list(spec.default)[:-1]  # one face short
    assert annual_overlay(stage, layer, stream) is None
    assert annual_overlay(stage, Sdf.Layer.CreateAnonymous(), stream) is None
