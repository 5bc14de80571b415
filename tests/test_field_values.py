"""tools.field_values: FIELD=VALUE command-line items into numbers and booleans, bad items named."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tools.errors import ToolError
from tools.field_values import parse_field_values


def test_numbers_and_booleans():
    got = parse_field_values(["a=1", "b=true", "c=0.5", "d=-3", "e=1e9", " f = False "])
    assert got == {"a": 1, "b": True, "c": 0.5, "d": -3, "e": 1e9, "f": False}
    assert isinstance(got["a"], int) and isinstance(got["e"], float)


@pytest.mark.parametrize("item", ["novalue", "=1", "a=x", "a=", "a=1.2.3"])
def test_a_bad_item_is_named_with_the_flag(item):
    with pytest.raises(ToolError) as exc:
        parse_field_values([item], "--eval-set")
    msg = str(exc.value)
    assert "--eval-set" in msg and (item.partition("=")[2] in msg or item in msg)


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_a_float_round_trips(v):
    assert parse_field_values([f"x={v!r}"]) == {"x": v}


@given(st.integers())
def test_an_integer_round_trips(v):
    assert parse_field_values([f"x={v}"]) == {"x": v}
