"""core/plain_data.py: trees of containers, arrays and dataclasses survive JSON text and a .npz file
(the form the cache stores) with their types, decoding runs none of the stored types' code, and what
cannot be stored or was not written by ``encode`` is refused with where it sits."""

import dataclasses
import io
import json
import math
import re
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from usdbake.core import plain_data


@dataclasses.dataclass(frozen=True)
class Checked:
    """A test dataclass whose constructor refuses negative values: decoding must not run it."""

    value: float
    label: str = "x"
    memo: dict = dataclasses.field(default_factory=dict, compare=False)

    def __post_init__(self):
        if self.value < 0:
            raise ValueError("negative")


def this_module(module: str) -> bool:
    return module == __name__


def stored(value, trusted=plain_data.trusted_by_default):
    """Encode, write as the cache does (JSON text, one .npz of arrays), read back and decode."""
    tree, arrays = plain_data.encode(value, trusted=trusted)
    text = json.dumps(tree, allow_nan=False)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    buffer.seek(0)
    with np.load(buffer) as loaded:
        read = {name: loaded[name] for name in loaded.files}
    return plain_data.decode(json.loads(text), read, trusted=trusted)


def same(a, b) -> bool:
    """Equal values of equal types all the way down (NaN equals NaN; arrays by dtype, shape and bytes)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, dict):
        return list(a) == list(b) and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (float, np.floating)):
        return (math.isnan(a) and math.isnan(b)) or (a == b and math.copysign(1, a) == math.copysign(1, b))
    return a == b


scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=8), st.binary(max_size=8),
                    st.integers(-128, 127).map(np.int8), st.floats(width=32).map(np.float32))
keys = st.one_of(st.integers(), st.text(max_size=6), st.tuples(st.integers(), st.text(max_size=3)))
arrays = st.sampled_from([np.float32, np.int64, np.uint8, np.float64]).flatmap(
    lambda dtype: st.lists(st.integers(0, 255), max_size=12).map(lambda items: np.array(items, dtype)))
trees = st.recursive(st.one_of(scalars, arrays), lambda children: st.one_of(
    st.lists(children, max_size=4), st.tuples(children, children), st.dictionaries(keys, children, max_size=4)),
    max_leaves=20)


@settings(max_examples=150, deadline=None, derandomize=True, database=None)  # the same examples on every run
@given(trees)
def test_any_tree_survives_json_and_npz(value):
    assert same(stored(value), value)


def test_non_finite_floats_are_plain_json():
    tree, _ = plain_data.encode([float("nan"), float("inf"), float("-inf")])
    json.dumps(tree, allow_nan=False)  # raises on a bare NaN or Infinity
    back = stored([float("nan"), float("inf"), float("-inf")])
    assert math.isnan(back[0]) and back[1:] == [math.inf, -math.inf]


def test_read_only_arrays_come_back_read_only_and_shared_ones_shared():
    frozen = np.arange(6.0).reshape(2, 3)
    frozen.flags.writeable = False
    back = stored({"frozen": frozen, "pair": (frozen, frozen), "open": np.zeros(2)})
    assert not back["frozen"].flags.writeable and back["open"].flags.writeable
    assert back["pair"][0] is back["pair"][1] is back["frozen"]


def test_decoding_runs_no_constructor_and_makes_memo_fields_afresh():
    assert sys.modules[__name__] is not None  # resolve() finds trusted modules among those imported
    original = Checked(1.0, "kept", {"memo": 1})
    tree, arrays = plain_data.encode(original, trusted=this_module)
    assert "memo" not in tree["fields"]
    tree["fields"]["value"] = -2.0  # a value __post_init__ would refuse
    back = plain_data.decode(tree, arrays, trusted=this_module)
    assert type(back) is Checked and back.value == -2.0 and back.label == "kept" and back.memo == {}


def test_a_usdbake_dataclass_of_arrays_round_trips_with_its_type():
    from usdbake.kernels.sky import SkyPatches, reinhart_patches

    patches = reinhart_patches(2)
    back = stored({"layout": patches, "kind": SkyPatches})
    assert type(back["layout"]) is SkyPatches and back["kind"] is SkyPatches
    assert all(same(getattr(back["layout"], f.name), getattr(patches, f.name)) for f in dataclasses.fields(patches))


@pytest.mark.parametrize("value, where", [
    ({"outputs": [1, object()]}, "outputs[1]"),
    ([np.array([None], object)], "[0]"),
    ({"f": lambda: 0}, "f"),
])
def test_unstorable_values_are_named_by_their_path(value, where):
    with pytest.raises(TypeError, match=rf"^{re.escape(where)}: cannot store"):
        plain_data.encode(value)


def test_untrusted_dataclasses_and_attributes_that_are_not_fields_are_refused():
    with pytest.raises(TypeError, match="not from usdbake"):
        plain_data.encode(Checked(1.0))
    sneaky = Checked(1.0)
    object.__setattr__(sneaky, "extra", 5)
    with pytest.raises(TypeError, match="not fields"):
        plain_data.encode(sneaky, trusted=this_module)


def test_entries_encode_did_not_write_are_refused():
    tree, arrays = plain_data.encode({"a": np.arange(4, dtype=np.int32)})
    node = tree["items"][0][1]
    with pytest.raises(ValueError, match="the manifest says"):
        plain_data.decode(tree, {node["name"]: np.arange(4, dtype=np.int64)})
    with pytest.raises(ValueError, match="unknown node"):
        plain_data.decode({"$": "pickle", "data": ""}, {})
    entry, arrays = plain_data.encode(Checked(1.0), trusted=this_module)
    missing = {**entry, "fields": {"value": 1.0}}
    with pytest.raises(ValueError, match="field label is not in the entry"):
        plain_data.decode(missing, arrays, trusted=this_module)
    extra = {**entry, "fields": {**entry["fields"], "command": "rm"}}
    with pytest.raises(ValueError, match="has no fields"):
        plain_data.decode(extra, arrays, trusted=this_module)
