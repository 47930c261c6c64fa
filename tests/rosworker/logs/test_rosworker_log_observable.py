"""rosworker/logs/observable.py: the ``logs`` collection as observers see it, line by line.

The log book is the real one (its ``add``, no subscription); the observers record what they are told.
Through a real gateway with real logging nodes: tests/system/triggers/test_app_trigger_sources.py.
"""

from __future__ import annotations

import json

from rosworker.core.stats import Stats
from rosworker.logs.book import LogBook
from tests.rosworker.faults.test_rosworker_fault_observable import Observer


class Executor:
    def guarded(self, where, fn, *args):
        return fn(*args)


def book() -> LogBook:
    return LogBook(None, Executor(), Stats(pool_cap=1, cold_wait_cap=1, watchdog_threshold_ms=1000), buffer_size=10,
                   max_bytes=10**6, max_nodes=10)


def test_a_line_is_told_to_its_nodes_observers_only_with_the_entry_as_listed():
    b = book()
    b.add(1, 0, 40, "ns.a", "before any observer", "", "", 0)
    watch = Observer(json.dumps({"nodes": ["/ns/a"]}))
    b.observable.attach(watch)
    b.add(2, 5, 20, "ns.a", "calm", "f.py", "run", 7)
    b.add(3, 0, 40, "ns/b", "another node", "", "", 0)
    b.add(4, 123, 40, "ns/a", "broken", "f.py", "run", 9)   # the slash form of the same node
    assert [c["message"] for c in watch.changes] == ["calm", "broken"]
    assert watch.changes[1] == {
        "id": "log_4", "timestamp": "1970-01-01T00:00:04.000000123Z", "severity": "error", "message": "broken",
        "context": {"node": "ns/a", "function": "run", "file": "f.py", "line": 9}}
    b.observable.close()
    b.add(5, 0, 40, "ns.a", "after", "", "", 0)
    assert len(watch.changes) == 2 and b.observable.observers == []


def test_an_observer_of_every_line_hears_every_node():
    b = book()
    everything = Observer("")
    b.observable.attach(everything)
    b.add(1, 0, 20, "ns.a", "one", "", "", 0)
    b.add(2, 0, 20, "other", "two", "", "", 0)
    assert [c["message"] for c in everything.changes] == ["one", "two"]
