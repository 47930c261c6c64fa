"""Faults and logs trigger sources, event by event (rosworker/triggers/sources.py).

The registry is a stand-in that records what fires (a collaborator); the log
book is the real one (its ``add``, no subscription).  Through a real gateway
with a real /diagnostics publisher and real logging nodes:
tests/app/test_app_trigger_sources.py.
"""

from __future__ import annotations

import json
import types

import orjson
import pytest

from ipc.errors import IpcError
from rosworker.core.stats import Stats
from rosworker.logs.book import LogBook
from rosworker.triggers.registry import SOURCES, Trigger
from rosworker.triggers.sources import FaultSource, LogSource, in_scope, parse_target


class Registry:
    """What a source asks of the registry: its stats, and fire()."""

    def __init__(self):
        self.stats = Stats(pool_cap=1, cold_wait_cap=1, watchdog_threshold_ms=1000)
        self.fired: list[tuple[str, dict]] = []

    def fire(self, trigger, stamp, *, payload=None, error=None):
        assert isinstance(stamp, int) and error is None
        self.fired.append((trigger.id, orjson.loads(payload)))


class Executor:
    def guarded(self, where, fn, *args):
        return fn(*args)


def trigger(n: int, source: str, target: dict, condition: dict, path: str = "") -> Trigger:
    return Trigger(id=f"trig_{n:016x}", collection="apps", entity_id="a", resource="/api/v1/apps/a/" + source,
                   source=source, target=json.dumps(target), bytes="array", path=path, condition=condition,
                   multishot=True, persistent=False, lifetime=None, created_at_ns=0, client="", status="active")


def fault(code: str, status: str, sources: list[str]) -> dict:
    return {"fault_code": code, "severity": 2, "description": "x", "first_occurred": 1.0, "last_occurred": 2.0,
            "occurrence_count": 1, "status": status, "reporting_sources": sources, "severity_label": "ERROR"}


def test_faults_and_logs_are_sources():
    assert SOURCES["faults"] is FaultSource and SOURCES["logs"] is LogSource


def test_the_hook_is_set_while_a_trigger_watches_and_cleared_with_the_last():
    registry, owner = Registry(), types.SimpleNamespace(trigger_hook=None)
    source = FaultSource(registry)
    source.bind(owner)
    assert owner.trigger_hook is None and not source.active()
    one = trigger(1, "faults", {"nodes": ["/a"], "code": None}, {"condition_type": "OnChange"}, "/status")
    source.attach(one)
    assert owner.trigger_hook == source.on_fault
    source.detach(one)
    assert owner.trigger_hook is None


def test_a_fault_event_fires_in_scope_with_the_fault_and_its_event_type():
    registry, owner = Registry(), types.SimpleNamespace(trigger_hook=None)
    source = FaultSource(registry)
    source.bind(owner)
    every = trigger(1, "faults", {"nodes": ["/a"], "code": None},
                    {"condition_type": "OnChangeTo", "target_value": "CONFIRMED"}, "/status")
    one_code = trigger(2, "faults", {"nodes": ["/a"], "code": "B"}, {"condition_type": "OnChange"}, "/status")
    source.attach(every)
    source.attach(one_code)
    owner.trigger_hook("fault_updated", fault("A", "PREPASSED", ["/a"]))
    owner.trigger_hook("fault_confirmed", fault("A", "CONFIRMED", ["/a/sub"]))   # below /a: in scope
    owner.trigger_hook("fault_confirmed", fault("C", "CONFIRMED", ["/a", "/other"]))  # mixed: out of scope
    owner.trigger_hook("fault_confirmed", fault("B", "CONFIRMED", ["/a"]))
    assert [(tid[-1], p["fault_code"], p["event_type"]) for tid, p in registry.fired] == [
        ("1", "A", "fault_confirmed"), ("2", "B", "fault_confirmed")]
    assert registry.fired[0][1] == {**fault("A", "CONFIRMED", ["/a/sub"]), "event_type": "fault_confirmed"}


def test_a_line_fires_for_its_nodes_triggers_only_with_the_entry_as_listed():
    registry = Registry()
    book = LogBook(None, Executor(), Stats(pool_cap=1, cold_wait_cap=1, watchdog_threshold_ms=1000), buffer_size=10, max_bytes=10**6, max_nodes=10)
    source = LogSource(registry)
    source.bind(book)
    book.add(1, 0, 40, "ns.a", "before any trigger", "", "", 0)
    watch = trigger(1, "logs", {"nodes": ["/ns/a"]}, {"condition_type": "OnChangeTo", "target_value": "error"},
                    "/severity")
    source.attach(watch)
    book.add(2, 5, 20, "ns.a", "calm", "f.py", "run", 7)
    book.add(3, 0, 40, "ns/b", "another node", "", "", 0)
    book.add(4, 123, 40, "ns.a", "broken", "f.py", "run", 9)
    book.add(5, 0, 40, "ns/a", "still broken", "", "", 0)   # the slash form of the same node: no change
    assert registry.fired == [(watch.id, {
        "id": "log_4", "timestamp": "1970-01-01T00:00:04.000000123Z", "severity": "error", "message": "broken",
        "context": {"node": "ns.a", "function": "run", "file": "f.py", "line": 9}})]
    source.close()
    assert book.trigger_hook is None


@pytest.mark.parametrize("text", ["", "[]", '{"nodes": "x"}', '{"nodes": ["relative"]}', '{"nodes": [1]}'])
def test_a_target_that_names_no_scope_is_refused(text):
    with pytest.raises(IpcError) as err:
        parse_target(text, with_code=False)
    assert err.value.code == "bad-request"


def test_a_fault_code_target_is_checked():
    assert parse_target('{"nodes": ["/a"], "code": "X"}', True) == {"nodes": ["/a"], "code": "X"}
    for code in ("", 3, "x" * 257):
        with pytest.raises(IpcError):
            parse_target(json.dumps({"nodes": ["/a"], "code": code}), True)


def test_scope_is_every_source_under_the_nodes():
    assert in_scope(["/a", "/a/b"], ["/a"]) and not in_scope(["/ab"], ["/a"])
    assert not in_scope([], ["/a"]) and not in_scope(["/a"], []) and not in_scope(None, ["/a"])
