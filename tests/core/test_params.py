"""core.params: bounds and choices checked at construction, user text converted to the field's type, and
the describe / table / Markdown rows a person reads."""

from dataclasses import dataclass

import numpy as np
import pytest
from usdbake.core.params import ParamError, Params, format_range, format_value, param


@dataclass(frozen=True)
class Example(Params):
    samples: int = param(64, "rays per point", low=1, high=4096)
    distance: float = param(float("inf"), "ray length", low=0.0)
    mode: str = param("fast", "how | which", choices=("fast", "exact"))
    enabled: bool = param(True, "on or off")
    label: str = param("", "a name")


def test_defaults_build():
    assert Example().as_dict() == {"samples": 64, "distance": float("inf"), "mode": "fast", "enabled": True,
                                   "label": ""}


@pytest.mark.parametrize("values, message", [
    (dict(samples=0), "samples=0 is below the minimum 1"),
    (dict(samples=4097), "samples=4097 is above the maximum 4096"),
    (dict(distance=float("nan")), "distance=nan is not a number"),
    (dict(mode="slow"), r"mode='slow' is not one of \['fast', 'exact'\]"),
    (dict(distance=np.float64(-1.5)), r"distance=-1.5 is below"),  # a numpy scalar shown as its number
])
def test_bounds_and_choices_are_checked_at_construction(values, message):
    with pytest.raises(ParamError, match=message):
        Example(**values)


def test_text_from_the_command_line_is_converted_to_the_field_type():
    params = Example.from_dict({"samples": " 12 ", "distance": "2.5", "enabled": "off", "label": "x"})
    assert (params.samples, params.distance, params.enabled, params.label) == (12, 2.5, False, "x")
    assert Example.from_dict({"enabled": "YES"}).enabled is True
    assert Example.from_dict({"distance": "inf"}).distance == float("inf")


@pytest.mark.parametrize("values, message", [
    ({"samples": "many"}, "samples='many' is not a valid int"),
    ({"enabled": "maybe"}, "enabled='maybe' is not a valid bool"),
    ({"samples": True}, "samples=True is not a valid int"),  # True is not a sample count
    ({"samples": 2.0}, "samples=2.0 is not a valid int"),
    ({"enabled": 1}, "enabled=1 is not a valid bool"),
    ({"colour": 1}, "unknown parameter 'colour'"),
])
def test_values_of_the_wrong_type_or_name_are_refused(values, message):
    with pytest.raises(ParamError, match=message):
        Example.from_dict(values)


def test_non_string_values_keep_or_widen_to_the_field_type():
    params = Example.from_dict({"samples": np.int32(8), "distance": 3})
    assert type(params.samples) is int and params.samples == 8
    assert type(params.distance) is float and params.distance == 3.0


def test_values_are_written_as_a_user_types_them():
    assert [format_value(v) for v in (True, np.bool_(False), float("inf"), -float("inf"), 0.5, "", "a", 3)] == \
        ["true", "false", "inf", "-inf", "0.5", "''", "a", "3"]
    assert format_range({"choices": None, "low": 1, "high": 4}) == "[1, 4]"
    assert format_range({"choices": None, "low": 0.0, "high": None}) == ">= 0.0"
    assert format_range({"choices": None, "low": None, "high": 2}) == "<= 2"
    assert format_range({"choices": None, "low": None, "high": None}) == ""
    assert format_range({"choices": ("a", "b"), "low": None, "high": None}) == "a, b"


def test_table_rows_and_markdown_agree_with_the_fields():
    assert Example.table_rows() == [
        ("samples", "int", "64", "[1, 4096]", "rays per point"),
        ("distance", "float", "inf", ">= 0.0", "ray length"),
        ("mode", "str", "fast", "fast, exact", "how | which"),
        ("enabled", "bool", "true", "", "on or off"),
        ("label", "str", "''", "", "a name"),
    ]
    lines = Example.markdown_table().split("\n")
    assert lines[0] == "| param | type | default | range | meaning |"
    assert lines[1] == "|---|---|---|---|---|"
    assert lines[4] == r"| `mode` | str | `fast` | `fast`, `exact` | how \| which |"
    assert len(lines) == 2 + 5
