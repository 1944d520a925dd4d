"""``usdbake serve`` with a daylight stream: the manifest names it, /files serves the bake's bytes, and a
daylight streamFile that is not the bake's own sidecar, or whose bytes changed, is left out with a warning."""

from __future__ import annotations

import json
import shutil

import pytest
from pxr import Sdf, Usd

from daylight_served import bake_daylight
from served_stage import get, running
from usdbake.core.errors import UsageError
from usdbake.stages.serve import make_app


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    return bake_daylight(tmp_path_factory.mktemp("served_daylight"), None)


def copy_of(baked, folder):
    """The bake layer and its sidecars in ``folder`` (edits stay out of the module's bake)."""
    for path in baked.parent.iterdir():
        if path.is_file():
            shutil.copy2(path, folder / path.name)
    return folder / baked.name


def test_the_daylight_stream_is_served(baked):
    sidecar = next(baked.parent.glob("room_daylight_*.bin"))
    with running(make_app(str(baked))) as url:
        _, _, manifest = get(url + "/manifest")
        manifest = json.loads(manifest)
        assert manifest["meshes"] == [] and manifest["grid"] is None and manifest["overlay"] is None
        assert manifest["daylight"]["bytes"] == sidecar.stat().st_size
        status, _, body = get(url + manifest["daylight"]["url"])
        assert status == 200 and body == sidecar.read_bytes()
        status, _, _ = get(url + "/overlay")
        assert status == 404


def test_a_foreign_or_changed_daylight_stream_is_not_served(baked, tmp_path):
    (tmp_path / "outside").mkdir()
    layer = copy_of(baked, tmp_path / "outside")
    secret = tmp_path / "secret.bin"
    secret.write_bytes(next(baked.parent.glob("room_daylight_*.bin")).read_bytes())
    stage = Usd.Stage.Open(str(layer))
    stage.GetPrimAtPath("/usdbake/DaylightStream").GetAttribute("streamFile").Set(Sdf.AssetPath("../secret.bin"))
    stage.Save()
    said = []
    with pytest.raises(UsageError, match="no streams to serve"):
        make_app(str(layer), log=said.append)
    assert any("/usdbake/DaylightStream.streamFile" in line and "../secret.bin" in line for line in said), said
    (tmp_path / "changed").mkdir()
    layer = copy_of(baked, tmp_path / "changed")
    sidecar = next(layer.parent.glob("room_daylight_*.bin"))
    sidecar.write_bytes(sidecar.read_bytes() + b"x")
    said = []
    with pytest.raises(UsageError, match="no streams to serve"):
        make_app(str(layer), log=said.append)
    assert any("not the bytes the bake recorded" in line for line in said), said
