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


def _trigger(n: int, **fields):
    from rosworker.triggers.registry import Trigger

    return Trigger(**{"id": f"trig_{n:016x}", "collection": "apps", "entity_id": "a", "resource": "/r",
                      "source": "data", "target": "/t", "bytes": "array", "path": "/level",
                      "condition": {"condition_type": "OnChange"}, "multishot": True, "persistent": False,
                      "lifetime": None, "created_at_ns": 0, "client": "", "status": "active", **fields})


def test_a_group_evaluates_each_trigger_through_its_path_and_hands_on_those_that_fired_together():
    from rosworker.triggers.sources import TriggerGroup

    on_change, base64, whole = _trigger(1), _trigger(2, bytes="base64"), _trigger(3, path="")
    to_four = _trigger(4, condition={"condition_type": "OnChangeTo", "target_value": 4})
    fired: list = []
    group = TriggerGroup("data", "/t", lambda stamp, triggers, **kw: fired.append(
        (stamp, [t.id for t in triggers], sorted(kw))))
    group.triggers += [on_change, base64, whole, to_four]
    asked: list[str] = []

    def payload(mode: str) -> bytes:
        asked.append(mode)
        return b"text in " + mode.encode()

    group.changed(1, {"level": 3}, payload)
    group.changed(2, {"level": 3}, payload)        # no change: nothing fired, nothing handed on
    group.changed(3, {"other": 1}, payload)        # no value at the path: only the whole-message one
    group.changed(4, {"level": 4}, payload)
    group.failed(5, "cannot be decoded")
    ids = [t.id for t in (on_change, base64, whole, to_four)]
    assert fired == [(1, ids[:3], ["payload"]), (3, [ids[2]], ["payload"]), (4, ids, ["payload"]),
                     (5, ids, ["error"])]
    assert asked == []  # the group makes no payload: the registry asks once per bytes mode


def test_one_change_that_fires_several_triggers_is_one_frame_per_bytes_mode_with_each_ones_seq():
    from ipc import events, protocol
    from rosworker.core.stats import Stats
    from rosworker.triggers.registry import TriggerRegistry

    sent: list[list[bytes]] = []
    registry = TriggerRegistry.__new__(TriggerRegistry)  # fire() alone: no executor, store nor notifier
    registry._send, registry.stats = sent.append, Stats(1, 1, 1)
    registry._terminate = lambda trigger: setattr(trigger, "status", "terminated")
    multi, other, once, b64 = _trigger(1), _trigger(2), _trigger(3, multishot=False), _trigger(4, bytes="base64")
    for n, trigger in enumerate((multi, other, once, b64)):
        trigger.seq = 100 * n
    asked: list[str] = []

    def payload(mode: str) -> bytes:
        asked.append(mode)
        return mode.encode()

    registry.fire(7, [multi, other, once, b64], payload=payload)
    assert asked == ["array", "base64"]  # each payload made once
    assert [f[0] for f in sent] == [events.trigger_group_key("data", "array", "/t"),
                                    events.trigger_group_key("data", "base64", "/t")]
    assert protocol.unpack(sent[0][1]) == {"ts": 7, "fired": [[multi.id, 1, False], [other.id, 101, False],
                                                              [once.id, 201, True]]}
    assert sent[0][2] == b"array" and sent[1][2] == b"base64"
    assert protocol.unpack(sent[1][1]) == {"ts": 7, "fired": [[b64.id, 301, False]]}
    assert once.status == "terminated" and multi.last_event == (7, 1, b"array", None)
    assert (registry.stats.trigger_frames, registry.stats.trigger_events) == (2, 4)
    sent.clear()
    registry.fire(8, [multi, other, once], error="unreadable")  # the terminated one-shot is no longer fired
    assert len(sent) == 1 and sent[0][2] == b""
    assert protocol.unpack(sent[0][1]) == {"ts": 8, "error": "unreadable",
                                           "fired": [[multi.id, 2, False], [other.id, 102, False]]}
    assert events.trigger_group_key("data", "array", "/t") != events.trigger_group_key("data", "array", "/u")
