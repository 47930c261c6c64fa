"""The trigger conditions and JSON Pointers, value by value (rosworker/triggers/conditions.py, ipc/jsonpointer.py).

What they do on real messages through a real gateway is tests/system/triggers/test_app_trigger_streams.py.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ipc import jsonpointer
from ipc.errors import IpcError
from rosworker.triggers.conditions import check_condition, fires, in_range, same

MISSING = jsonpointer.MISSING
NAN = "NaN"  # how a message's NaN reads in its JSON (rosworker/ros/encode.py)


def run(condition: dict, values: list) -> list[bool]:
    previous, out = MISSING, []
    for value in values:
        out.append(fires(condition, previous, value))
        previous = value
    return out


def test_on_change_fires_on_the_first_value_and_on_each_change():
    assert run({"condition_type": "OnChange"}, [1.0, 1.0, 2.0, 2, 3.5, {"a": 1}, {"a": 1}, {"a": 2}]) == [
        True, False, True, False, True, True, False, True]


def test_two_nan_are_no_change_and_nan_to_a_number_is_one():
    assert run({"condition_type": "OnChange"}, [NAN, NAN, 1.0, NAN, math.nan, "Infinity", "Infinity"]) == [
        True, False, True, True, False, True, False]


def test_on_change_to_fires_when_the_value_becomes_the_target():
    cond = {"condition_type": "OnChangeTo", "target_value": True}
    assert run(cond, [True, True, False, True, 1, True]) == [True, False, False, True, False, True]
    cond = {"condition_type": "OnChangeTo", "target_value": 3}
    assert run(cond, [1, 3.0, 3, 4, 3]) == [False, True, False, False, True]


@pytest.mark.parametrize("kind, values, expected", [
    ("EnterRange", [0, 5, 10, 10.5, 10, 2], [False, True, False, False, True, False]),
    ("LeaveRange", [5, 0, 1, 10, 10.0001, 12], [False, True, False, False, True, False]),
    ("LeaveRange", [5, NAN, 5, "Infinity", "-Infinity", 1], [False, True, False, True, False, False]),
    ("EnterRange", [NAN, 5, NAN, NAN, 3], [False, True, False, False, True]),
    ("EnterRange", ["5", 5, True, 5], [False, True, False, True]),
])
def test_ranges_fire_on_the_crossing_only_and_nan_is_in_no_range(kind, values, expected):
    assert run({"condition_type": kind, "lower_bound": 1, "upper_bound": 10}, values) == expected


def test_range_bounds_are_inclusive():
    assert in_range(1, 1, 10) and in_range(10.0, 1, 10) and not in_range(NAN, -math.inf, math.inf)
    assert not in_range(True, 0, 2) and not in_range(None, 0, 2)


def test_same_is_json_equality():
    assert same(1, 1.0) and not same(True, 1) and not same("1", 1) and same([NAN], [NAN])
    assert not same({"a": 1}, {"a": 1, "b": 2}) and same(None, None) and not same(None, 0)


def test_check_condition_guards_the_wire():
    for bad in (None, {}, {"condition_type": "x"}, {"condition_type": "OnChangeTo"},
                {"condition_type": "EnterRange", "lower_bound": 2, "upper_bound": 1},
                {"condition_type": "LeaveRange", "lower_bound": math.nan, "upper_bound": 1}):
        with pytest.raises(IpcError) as err:
            check_condition(bad)
        assert err.value.code == "bad-request"
    assert check_condition({"condition_type": "OnChange", "junk": 1}) == {"condition_type": "OnChange"}


@pytest.mark.parametrize("pointer, tokens", [
    ("", ()), ("/", ("",)), ("/a/b", ("a", "b")), ("/a~1b/~0c", ("a/b", "~c")), ("/~01", ("~1",)),
])
def test_pointers_parse_as_rfc_6901(pointer, tokens):
    assert jsonpointer.parse(pointer) == tokens


@pytest.mark.parametrize("pointer", ["a", "/a~", "/~2", "/" * 1025, 7])
def test_malformed_pointers_are_refused(pointer):
    with pytest.raises(ValueError):
        jsonpointer.parse(pointer)


def test_resolve_follows_objects_and_array_indexes():
    doc = {"a": [{"b": 1}, {"b": 2}], "": 3, "c/d": 4}
    assert jsonpointer.resolve(doc, jsonpointer.parse("/a/1/b")) == 2
    assert jsonpointer.resolve(doc, jsonpointer.parse("/")) == 3
    assert jsonpointer.resolve(doc, jsonpointer.parse("/c~1d")) == 4
    assert jsonpointer.resolve(doc, ()) is doc
    for missing in ("/a/2", "/a/01", "/a/-", "/a/x", "/x", "/a/0/b/c"):
        assert jsonpointer.resolve(doc, jsonpointer.parse(missing)) is MISSING, missing


JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
                    lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=3), c, max_size=3),
                    max_leaves=10)


@given(doc=JSON, pointer=st.text(max_size=30))
def test_hostile_pointers_never_raise_anything_but_value_error(doc, pointer):
    try:
        tokens = jsonpointer.parse(pointer)
    except ValueError:
        return
    jsonpointer.resolve(doc, tokens)


@given(previous=JSON, current=JSON, low=st.floats(allow_nan=False, allow_infinity=False),
       high=st.floats(allow_nan=False, allow_infinity=False),
       kind=st.sampled_from(["OnChange", "OnChangeTo", "EnterRange", "LeaveRange"]))
def test_every_condition_answers_a_boolean_for_any_values(previous, current, low, high, kind):
    cond = {"condition_type": kind, "target_value": previous, "lower_bound": min(low, high),
            "upper_bound": max(low, high)}
    assert fires(cond, previous, current) in (True, False)
    assert fires(cond, MISSING, current) in (True, False)


def test_a_trigger_observes_a_change_through_its_path_and_fires_with_the_payload_in_its_mode():
    from rosworker.triggers.registry import Trigger
    from rosworker.triggers.sources import TriggerObserver

    trigger = Trigger(id="trig_0000000000000001", collection="apps", entity_id="a", resource="/r", source="data",
                      target="/t", bytes="base64", path="/level", condition={"condition_type": "OnChange"},
                      multishot=True, persistent=False, lifetime=None, created_at_ns=0, client="", status="active")
    fired: list = []
    observer = TriggerObserver(trigger, lambda t, stamp, **kw: fired.append((t.id, stamp, kw)))
    asked: list[str] = []

    def payload(mode: str) -> bytes:
        asked.append(mode)
        return b"text in " + mode.encode()

    assert (observer.target, observer.bytes) == ("/t", "base64")
    observer.changed(1, {"level": 3}, payload)
    observer.changed(2, {"level": 3}, payload)        # no change: no event, no payload made
    observer.changed(3, {"other": 1}, payload)        # no value at the path: not evaluated
    observer.changed(4, {"level": 4}, payload)
    observer.failed(5, "cannot be decoded")
    assert fired == [(trigger.id, 1, {"payload": b"text in base64"}), (trigger.id, 4, {"payload": b"text in base64"}),
                     (trigger.id, 5, {"error": "cannot be decoded"})]
    assert asked == ["base64", "base64"]
