"""stages.provenance: a layer is a bake layer exactly when its customLayerData holds a dictionary under
PROVENANCE_KEY, and provenance_of hands that dictionary back (or {})."""

import pytest
from pxr import Sdf, Vt

from usdbake.stages.provenance import PROVENANCE_KEY, is_bake_layer, provenance_of

PROVENANCE = {"version": "0.0.test", "source": "in.usda", "sidecars": Vt.StringArray(["out.ao.png"]),
              "processors": {"ambient_occlusion": {"action": "run", "params": {"samples": 16}}}}


def layer_with(data: dict) -> Sdf.Layer:
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.customLayerData = data
    return layer


def test_the_key_is_the_package_name():
    assert PROVENANCE_KEY == "usdbake"


def test_a_layer_with_the_provenance_dictionary_is_a_bake_layer():
    layer = layer_with({PROVENANCE_KEY: PROVENANCE, "studio": {"shot": "010"}})
    assert is_bake_layer(layer)
    provenance = provenance_of(layer)
    assert provenance["version"] == "0.0.test" and provenance["source"] == "in.usda"
    assert list(provenance["sidecars"]) == ["out.ao.png"]
    assert provenance["processors"]["ambient_occlusion"]["params"]["samples"] == 16
    assert "studio" not in provenance  # only what usdbake wrote under its key


@pytest.mark.parametrize("data", [
    {},
    {"studio": {"usdbake": {"version": "1"}}},  # the key one level down is someone else's data
    {PROVENANCE_KEY: "0.3.1"},  # written by hand or corrupted: not a dictionary
    {PROVENANCE_KEY: 1},
    {PROVENANCE_KEY: Vt.StringArray(["version", "0.3.1"])},
], ids=["no-data", "nested-elsewhere", "a-string", "an-int", "a-string-array"])
def test_anything_else_under_the_key_is_not_ours(data):
    layer = layer_with(data)
    assert not is_bake_layer(layer)
    assert provenance_of(layer) == {}


def test_provenance_of_is_a_copy_the_layer_does_not_share():
    layer = layer_with({PROVENANCE_KEY: {"version": "1", "source": "in.usda"}})
    provenance = provenance_of(layer)
    provenance["source"] = "elsewhere.usda"
    provenance["extra"] = 1
    assert provenance_of(layer) == {"version": "1", "source": "in.usda"}


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])
def test_the_provenance_survives_a_save_and_a_fresh_read(tmp_path, suffix):
    path = tmp_path / f"out{suffix}"
    layer = Sdf.Layer.CreateNew(str(path))
    layer.customLayerData = {PROVENANCE_KEY: PROVENANCE}
    assert layer.Save()
    del layer
    reread = Sdf.Layer.OpenAsAnonymous(str(path), metadataOnly=True)  # how check_output reads an existing output
    assert is_bake_layer(reread)
    assert provenance_of(reread)["processors"] == PROVENANCE["processors"]
    assert list(provenance_of(reread)["sidecars"]) == ["out.ao.png"]
