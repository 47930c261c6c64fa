"""rosworker/faults/observable.py: the ``faults`` collection as observers see it, event by event.

The observers are stand-ins that record what they are told (as a trigger is, rosworker/triggers/sources.py);
the fault manager is the real one.  Through a real gateway with a real /diagnostics publisher:
tests/system/triggers/test_app_trigger_sources.py.
"""

from __future__ import annotations

import json

import orjson

from rosworker.faults.manager import FaultManager
from rosworker.faults.observable import FaultObservable, in_scope
from tests.rosworker.faults.test_rosworker_faults import Pool, Stats, array, tables


class Observer:
    """An observer of a collection: its target, its bytes mode, and what it was told."""

    def __init__(self, target: str, bytes_mode: str = "array"):
        self.target = target
        self.bytes = bytes_mode
        self.changes: list[dict] = []

    def changed(self, stamp, doc, payload):
        assert isinstance(stamp, int)
        assert orjson.loads(payload(self.bytes)) == doc
        self.changes.append(doc)

    def failed(self, stamp, message):
        raise AssertionError(message)


def fault(code: str, status: str, sources: list[str]) -> dict:
    return {"fault_code": code, "severity": 2, "description": "x", "first_occurred": 1.0, "last_occurred": 2.0,
            "occurrence_count": 1, "status": status, "reporting_sources": sources, "severity_label": "ERROR"}


def test_a_fault_event_is_told_in_scope_with_the_fault_and_its_event_type():
    stats = Stats()
    stats.trigger_messages = 0
    observable = FaultObservable(stats)
    every = Observer(json.dumps({"nodes": ["/a"], "code": None}))
    one_code = Observer(json.dumps({"nodes": ["/a"], "code": "B"}))
    everything = Observer("")   # every fault (bulk data's kind of observer)
    for o in (every, one_code, everything):
        observable.attach(o)
    observable.on_fault("fault_confirmed", fault("A", "CONFIRMED", ["/a/sub"]))   # below /a: in scope
    observable.on_fault("fault_confirmed", fault("C", "CONFIRMED", ["/a", "/other"]))  # mixed: out of scope
    observable.on_fault("fault_confirmed", fault("B", "CONFIRMED", ["/a"]))
    assert [(c["fault_code"], c["event_type"]) for c in every.changes] == [("A", "fault_confirmed"),
                                                                           ("B", "fault_confirmed")]
    assert [c["fault_code"] for c in one_code.changes] == ["B"]
    assert [c["fault_code"] for c in everything.changes] == ["A", "C", "B"]
    assert every.changes[0] == {**fault("A", "CONFIRMED", ["/a/sub"]), "event_type": "fault_confirmed"}
    assert stats.trigger_messages == 3


def test_the_manager_tells_its_observers_and_nothing_while_none_watches(tmp_path):
    executor = type("E", (), {"guarded": staticmethod(lambda where, fn, *a: fn(*a))})()
    m = FaultManager(None, executor, Pool(), Stats(), tables(tmp_path), confirm_count=1)
    m.load()
    m.on_array(array(("x", 2)))          # nobody watches: not even asked
    watcher = Observer(json.dumps({"nodes": ["/diagnostics"], "code": None}))
    m.observable.stats.trigger_messages = 0
    m.observable.attach(watcher)
    m.clear(["X"])
    assert [c["event_type"] for c in watcher.changes] == ["fault_cleared"]
    m.observable.detach(watcher)
    m.on_array(array(("x", 2)))
    assert len(watcher.changes) == 1 and m.observable.observers == []
    m.store.store.close(5)


def test_scope_is_every_source_under_the_nodes():
    assert in_scope(["/a", "/a/b"], ["/a"]) and not in_scope(["/ab"], ["/a"])
    assert not in_scope([], ["/a"]) and not in_scope(["/a"], []) and not in_scope(None, ["/a"])
    assert in_scope(["/anything"], None)   # an observer of every fault
