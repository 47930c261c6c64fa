"""rosworker/core/notifier.py: what a family provides to observe, an entity's scope as a target, and one
payload made for all the observers of a change."""

from __future__ import annotations

import json

import pytest

from ipc.errors import IpcError
from rosworker.core.notifier import ChangeNotifier, ScopedObservable, parse_scope
from tests.rosworker.faults.test_rosworker_fault_observable import Observer


@pytest.mark.parametrize("text", ["[]", '{"nodes": "x"}', '{"nodes": ["relative"]}', '{"nodes": [1]}', "{not json"])
def test_a_target_that_names_no_scope_is_refused(text):
    with pytest.raises(IpcError) as err:
        parse_scope(text, with_code=False)
    assert err.value.code == "bad-request"


def test_a_scope_is_sorted_and_a_fault_code_is_checked():
    assert parse_scope('{"nodes": ["/b", "/a", "/a"]}') == {"nodes": ["/a", "/b"]}
    assert parse_scope('{"nodes": ["/a"], "code": "X"}', True) == {"nodes": ["/a"], "code": "X"}
    assert parse_scope("", True) == {"nodes": None, "code": None}   # everything
    for code in ("", 3, "x" * 257):
        with pytest.raises(IpcError):
            parse_scope(json.dumps({"nodes": ["/a"], "code": code}), True)


def test_a_collection_is_provided_once_and_an_unknown_one_is_refused():
    notifier = ChangeNotifier()
    notifier.provide("logs", object())
    with pytest.raises(ValueError):
        notifier.provide("logs", object())
    with pytest.raises(IpcError) as err:
        notifier.observe("updates", Observer(""))
    assert err.value.code == "bad-request" and err.value.message == "source: expected one of logs"


def test_a_change_is_told_to_each_observer_with_one_payload_made_for_all():
    class Counting:
        trigger_messages = 0

    observable = ScopedObservable(Counting())
    a, b = Observer('{"nodes": ["/a"]}'), Observer('{"nodes": ["/a"]}')
    observable.attach(a)
    observable.attach(b)
    made = []
    payloads = []

    class Doc(dict):
        pass

    doc = Doc(x=1)
    for o in (a, b):
        o.changed = lambda stamp, d, payload, o=o: payloads.append(payload("array"))
    observable.notify([a, b], doc, 1)
    made.append(len({id(p) for p in payloads}))
    assert payloads == [b'{"x":1}', b'{"x":1}'] and made == [1]   # the same bytes object: made once
    assert observable.stats.trigger_messages == 1
    observable.notify([], doc, 2)
    assert observable.stats.trigger_messages == 1   # nobody concerned: not counted
