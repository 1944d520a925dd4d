"""core.records on its own: the output records are frozen values with the documented defaults, compare
by content, and ``Output`` admits each record kind (and nothing else), which is what the bake layer's
writer dispatches on."""

from __future__ import annotations

import dataclasses
import typing

import numpy as np
import pytest
from usdbake.core.records import Attribute, Block, File, Output, Prim, Primvar, RefinedMesh, Relationship, Texture


def test_output_is_exactly_the_seven_record_kinds():
    assert set(typing.get_args(Output)) == {Primvar, Attribute, Prim, Relationship, Texture, File, RefinedMesh}
    for kind in typing.get_args(Output):
        assert dataclasses.is_dataclass(kind) and kind.__dataclass_params__.frozen, kind.__name__
    assert isinstance(Prim("/World/A"), Output)
    assert not isinstance(Block(), Output)  # a value for an Attribute, not a record of its own
    assert not isinstance("/World/A", Output)


def test_defaults_are_the_documented_ones():
    primvar = Primvar("/World/A", "bake:ao", np.zeros(3, np.float32), "float", "vertex")
    assert (primvar.element_size, primvar.time) == (1, None)
    attribute = Attribute("/World/A", "bake:version", "1", "string")
    assert (attribute.uniform, attribute.time, attribute.connect_to) == (False, None, None)
    prim = Prim("/World/Probes")
    assert (prim.type_name, prim.api_schemas, prim.instanceable) == ("", (), None)


def test_records_are_frozen():
    prim = Prim("/World/A", "Xform")
    with pytest.raises(dataclasses.FrozenInstanceError):
        prim.path = "/World/B"
    texture = Texture("ao.exr", np.zeros((2, 2, 1), np.float32))
    with pytest.raises(dataclasses.FrozenInstanceError):
        texture.path = "x.exr"
    assert dataclasses.replace(prim, path="/World/B").path == "/World/B" and prim.path == "/World/A"


def test_records_without_arrays_compare_and_hash_by_value():
    a = Attribute("/World/A", "bake:x", 1.5, "float", uniform=True, time=3.0)
    assert a == Attribute("/World/A", "bake:x", 1.5, "float", uniform=True, time=3.0)
    assert a != dataclasses.replace(a, time=None)
    assert len({Prim("/A", "Xform", ("BakeAPI",)), Prim("/A", "Xform", ("BakeAPI",)), Prim("/A")}) == 2
    assert File("a.dds", b"\x00\x01") == File("a.dds", b"\x00\x01") != File("a.dds", b"\x00")
    assert Block() == Block() and hash(Block()) == hash(Block())
