"""The fault manager's rules and the fault store, on the real message classes and a real SQLite file.

The executor, pool and events socket are stand-ins here (what they do is covered through the real
gateway in tests/system/faults/test_app_faults.py); the lifecycle's timers are driven by ``tick`` and by the
wall clock the manager reads.
"""

from __future__ import annotations

import sqlite3
import time
import types

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from ipc import events, protocol
from rosworker.core.store import Store
from rosworker.faults import manager as mod
from rosworker.faults import snapshots
from rosworker.faults.manager import FaultManager
from rosworker.faults.model import fault_code, parse_codes, parse_snapshot_topics
from rosworker.faults.store import FaultTables


class Stats:
    faults: dict = {}

    def set_section(self, name, part):
        setattr(self, name, part)


class Pool:
    """The core's samplers as the freeze frames use them: ``data`` topics warmed and read."""

    def __init__(self):
        self.subscribed: list[str] = []
        self.samples: dict[str, dict] = {}

    def warm(self, kind, topic):
        assert kind == "data"
        self.subscribed.append(topic)

    def read(self, kind, topic, mode):
        assert kind == "data"
        return self.samples.get(topic)


def tables(path) -> FaultTables:
    """The faults' tables in a store opened on ``path`` (the core opens it before the families start)."""
    store = Store(str(path))
    store.open()
    return FaultTables(store)


def array(*statuses) -> DiagnosticArray:
    msg = DiagnosticArray()
    for name, level, *rest in statuses:
        values = rest[0] if rest else {}
        hardware_id = rest[1] if len(rest) > 1 else ""
        msg.status.append(DiagnosticStatus(level=bytes([level]), name=name, message=f"level {level}",
                                           hardware_id=hardware_id, values=[KeyValue(key=k, value=v)
                                                                    for k, v in values.items()]))
    return msg


@pytest.fixture
def make(tmp_path):
    made = []

    def build(**options) -> FaultManager:
        sent: list[list[bytes]] = []
        manager = FaultManager(None, None, options.pop("pool", Pool()), Stats(), tables(tmp_path),
                               send=sent.append, **options)
        manager.sent = sent
        manager.load()
        made.append(manager)
        return manager

    yield build
    for manager in made:
        manager.store.store.close(5)


def status(manager, code):
    return manager.faults[code]["status"]


def test_codes_are_medkit_s():
    assert fault_code("motor: Temperature") == "MOTOR_TEMPERATURE"
    assert fault_code("/robot/sensor") == "ROBOT_SENSOR"
    assert fault_code("motor temp") == "MOTOR_TEMP"
    assert fault_code("::") == ""
    assert len(fault_code("x" * 1000)) == 256
    assert parse_codes("motor: Temperature=motor overheat;bad;=X") == {"motor: Temperature": "MOTOR_OVERHEAT"}
    assert parse_snapshot_topics("MOTOR_*=/a, /b;;X=") == [("MOTOR_*", ["/a", "/b"])]


def test_confirmed_by_count_healed_by_count_and_a_new_occurrence(make):
    m = make(confirm_count=3, confirm_s=3600, heal_count=2)
    m.on_array(array(("drive", 2)))
    assert status(m, "DRIVE") == "PREFAILED" and m.faults["DRIVE"]["count"] == 1
    m.on_array(array(("drive", 2)))
    assert status(m, "DRIVE") == "PREFAILED"
    m.on_array(array(("drive", 2)))
    assert status(m, "DRIVE") == "CONFIRMED"
    m.on_array(array(("drive", 0)))
    assert status(m, "DRIVE") == "PREPASSED"
    m.on_array(array(("drive", 1)))               # failing again before it healed: confirmed again
    assert status(m, "DRIVE") == "CONFIRMED" and m.faults["DRIVE"]["count"] == 1
    m.on_array(array(("drive", 0)))
    m.on_array(array(("drive", 0)))
    assert status(m, "DRIVE") == "HEALED" and m.faults["DRIVE"]["passed_ns"] > 0
    first = m.faults["DRIVE"]["first_ns"]
    m.on_array(array(("drive", 2)))              # failing again after it healed: the same occurrence
    assert status(m, "DRIVE") == "PREFAILED" and m.faults["DRIVE"]["count"] == 1
    assert m.faults["DRIVE"]["first_ns"] == first
    for _ in range(5):                           # reports that go on: last_occurred, never the count
        m.on_array(array(("drive", 2)))
    assert status(m, "DRIVE") == "CONFIRMED" and m.faults["DRIVE"]["count"] == 1
    assert m.clear(["DRIVE"]) == ["DRIVE"]
    m.on_array(array(("drive", 2)))              # reported again after a clear: a new occurrence
    assert status(m, "DRIVE") == "PREFAILED" and m.faults["DRIVE"]["count"] == 2
    assert m.faults["DRIVE"]["first_ns"] > first
    kinds = [protocol.unpack(frames[1])["event_type"] for frames in m.sent]
    # confirmed; then PREPASSED, CONFIRMED again, PREPASSED, HEALED: each an update of a confirmed fault;
    # confirmed again (from PREFAILED, after it healed), then cleared
    assert kinds == ["fault_confirmed"] + ["fault_updated"] * 4 + ["fault_confirmed", "fault_cleared"]
    assert all(frames[0] == events.FAULT_KEY for frames in m.sent)


def test_a_node_found_after_the_first_report_replaces_the_topic_as_its_source(make):
    m = make(confirm_count=3, confirm_s=3600, heal_count=2)
    m.on_array(array(("drive: motor", 2)))       # the graph does not know the node yet: the topic stands in
    assert m.faults["DRIVE_MOTOR"]["sources"] == ["/diagnostics"]
    m.attribution.graph = types.SimpleNamespace(nodes=["/fleet/drive"])
    m.on_array(array(("drive: motor", 2)))
    assert m.faults["DRIVE_MOTOR"]["sources"] == ["/fleet/drive"]
    m.attribution.graph = types.SimpleNamespace(nodes=[])    # not found again: a guess neither replaces nor joins it
    m.on_array(array(("drive: motor", 2)))
    assert m.faults["DRIVE_MOTOR"]["sources"] == ["/fleet/drive"]
    m.on_array(array(("drive: motor", 2, {}, "/fleet/other")))  # another node the status names joins
    assert m.faults["DRIVE_MOTOR"]["sources"] == ["/fleet/drive", "/fleet/other"]


def test_confirmed_by_time_when_reports_are_rare(make):
    m = make(confirm_count=100, confirm_s=0.2)
    m.on_array(array(("slow", 2)))
    m.tick(time.monotonic())
    assert status(m, "SLOW") == "PREFAILED"
    time.sleep(0.25)
    m.tick(time.monotonic())
    assert status(m, "SLOW") == "CONFIRMED"


def test_a_stale_level_confirms_at_once_and_a_silent_status_turns_stale(make):
    m = make(confirm_count=10, confirm_s=3600, stale_s=5)
    m.on_array(array(("dead", 3), ("quiet", 0)))
    assert status(m, "DEAD") == "CONFIRMED" and m.faults["DEAD"]["severity"] == 3
    assert "QUIET" not in m.faults
    m.tick(time.monotonic() + 4)
    assert "QUIET" not in m.faults
    m.tick(time.monotonic() + 6)
    assert status(m, "QUIET") == "CONFIRMED" and m.faults["QUIET"]["description"].startswith("stale")
    assert m.faults["QUIET"]["severity"] == 3
    m.tick(time.monotonic() + 12)                  # reported once, not on every tick
    assert m.faults["QUIET"]["count"] == 1


def test_silence_is_judged_against_what_was_taken_not_against_the_clock(make):
    """Reports that wait in the subscription's queue (the ROS thread was busy) are not silence: a check of
    the timers takes what waits first, and judges staleness only up to the last moment the queue was
    seen empty (a flood past a round's budget leaves that moment where it was)."""
    m = make(confirm_count=1, stale_s=5)
    m.executor = types.SimpleNamespace(call_later=lambda *_: None, guarded=lambda _where, fn, *a: fn(*a))
    waiting: list = []
    m.sub = types.SimpleNamespace(handle=types.SimpleNamespace(
        take_message=lambda _cls, _raw: (waiting.pop(0), {}) if waiting else None))
    m.on_array(array(("probe", 2)))
    m.seen["PROBE"][0] -= 10                       # its last report was taken 10 s ago ...
    waiting.append(array(("probe", 2)))            # ... and a new one waits in the queue
    m._tick_round()
    assert m.faults["PROBE"]["severity"] == 2 and not m.faults["PROBE"]["description"].startswith("stale")
    m.seen["PROBE"][0] -= 10                       # 10 s since that one ...
    m._drained -= 10                               # ... the queue last seen empty then, and a flood waits:
    waiting.extend(array(*((f"flood {i}.{j}", 0) for j in range(100))) for i in range(mod.TAKE_PER_ROUND))
    m._tick_round()                                # one round's budget of it is taken, not all
    assert waiting and m.faults["PROBE"]["severity"] == 2
    waiting.clear()                                # the queue empties: nothing came in 10 s
    m._tick_round()
    assert m.faults["PROBE"]["severity"] == 3 and m.faults["PROBE"]["description"].startswith("stale")


def test_a_stale_status_whose_node_came_into_the_graph_since_is_that_node_s(make):
    m = make(confirm_count=1, stale_s=5)
    m.on_array(array(("dead: motor", 0)))          # reported before the graph knew the node: a guess
    m.attribution.graph = types.SimpleNamespace(nodes=["/base/dead"])
    m.tick(time.monotonic() + 6)                   # silent since: stale, from the node it names
    assert m.faults["DEAD_MOTOR"]["description"].startswith("stale")
    assert m.faults["DEAD_MOTOR"]["sources"] == ["/base/dead"]


def test_a_flood_of_new_names_never_pushes_a_held_fault_out_of_the_stale_watch(make):
    m = make(confirm_count=1, stale_s=5, max_faults=3)
    m.on_array(array(("held a", 2), ("held b", 2)))
    for i in range(0, 500, 50):                    # passing statuses with new names, far past the cap
        m.on_array(array(*((f"flood {j}", 0) for j in range(i, i + 50))))
    assert len(m.seen) <= mod.SEEN_PER_FAULT * 3
    assert {"HELD_A", "HELD_B"} <= set(m.seen)
    m.tick(time.monotonic() + 6)
    assert all(m.faults[c]["description"].startswith("stale") for c in ("HELD_A", "HELD_B"))


def test_an_endpoint_discovered_before_its_node_is_no_source(make):
    publishers = [types.SimpleNamespace(node_namespace="_NODE_NAMESPACE_UNKNOWN_", node_name="_NODE_NAME_UNKNOWN_")]
    m = make(confirm_count=3)
    m.attribution.endpoints = types.SimpleNamespace(publishers=lambda topic: list(publishers))
    m.on_array(array(("calibrator: probe", 2)))    # the node is not known yet, nor the publisher's name
    assert m.faults["CALIBRATOR_PROBE"]["sources"] == ["/diagnostics"]
    publishers[0] = types.SimpleNamespace(node_namespace="/", node_name="calibrator")
    m.attribution._publishers = (0.0, [])
    m.on_array(array(("calibrator: probe", 2)))    # the only publisher, named now: a better guess
    assert m.faults["CALIBRATOR_PROBE"]["sources"] == ["/calibrator"]
    publishers.append(types.SimpleNamespace(node_namespace="/", node_name="other"))
    m.attribution._publishers = (0.0, [])
    m.on_array(array(("calibrator: probe", 2)))    # no single publisher: the topic adds nothing
    assert m.faults["CALIBRATOR_PROBE"]["sources"] == ["/calibrator"]
    m.attribution.graph = types.SimpleNamespace(nodes=["/calibrator"])
    m.on_array(array(("other: probe", 2, {}, "/elsewhere/node")))
    m.on_array(array(("calibrator: probe", 2)))    # the node the status names: one source, not two
    assert m.faults["CALIBRATOR_PROBE"]["sources"] == ["/calibrator"]
    assert m.faults["CALIBRATOR_PROBE"]["guessed"] is False


def test_freeze_frames_are_bounded_in_count_and_bytes(make):
    pool = Pool()
    topics = [f"/t{i}" for i in range(20)]
    for i, topic in enumerate(topics):
        size = snapshots.SNAPSHOT_BYTES + 10 if i == 0 else 10
        pool.samples[topic] = {"status": "data", "type": "std_msgs/msg/String",
                               "data_json": b'{"data":"' + b"x" * size + b'"}'}
    m = make(confirm_count=1, snapshot_topics="MOTOR_*=" + ",".join(topics), pool=pool)
    m.on_array(array(("motor: a", 2, {"rpm": "0"})))
    assert pool.subscribed[:3] == ["/t0", "/t1", "/t2"]     # pooled at PREFAILED
    frames = m.faults["MOTOR_A"]["snapshots"]
    assert len(frames) == snapshots.SNAPSHOTS_MAX
    assert frames[0]["topic"] == "/diagnostics" and '"rpm":"0"' in frames[0]["data"]
    assert frames[1]["topic"] == "/t0" and frames[1]["truncated"] > snapshots.SNAPSHOT_BYTES and frames[1]["data"] == "{}"
    assert all(len(f["data"]) <= snapshots.SNAPSHOT_BYTES for f in frames)


def test_max_faults_drops_the_oldest_done_fault_then_refuses(make):
    m = make(confirm_count=1, heal_count=1, max_faults=2)
    m.on_array(array(("a", 2), ("b", 2)))
    m.on_array(array(("a", 0)))
    m.on_array(array(("c", 2)))
    assert set(m.faults) == {"B", "C"}
    m.on_array(array(("d", 2)))
    assert set(m.faults) == {"B", "C"} and m.refused == 1


def test_the_store_keeps_faults_and_event_ids_across_managers(make, tmp_path):
    m = make(confirm_count=1)
    m.on_array(array(("kept", 2, {"v": "1"})))
    assert m.clear(["KEPT", "NOPE"]) == ["KEPT"]
    last = m.next_event_id
    m.store.store.close(5)
    again = make()
    assert again.faults["KEPT"]["status"] == "CLEARED" and again.faults["KEPT"]["snapshots"]
    assert again.next_event_id >= last  # never backwards: this start's epoch, or the stored id + 1
    assert [e["event_type"] for e in again.events_after(0)] == ["fault_confirmed", "fault_cleared"]
    assert [e["id"] for e in again.events_after(0)] == [last - 2, last - 1]
    db = sqlite3.connect(tmp_path / "faults.db")
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    db.close()


def test_event_ids_never_go_backwards_across_starts_even_with_no_store(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    ids = []
    for _ in range(3):  # three starts with a store in memory only (an unwritable state dir)
        m = FaultManager(None, None, Pool(), Stats(), tables(blocker / "sub"), confirm_count=1)
        m.load()
        assert m.store.store.enabled is False
        m.on_array(array(("x", 2)))
        m.clear(["X"])
        ids += [e["id"] for e in m.events_after(0)]
    assert ids == sorted(ids) and len(set(ids)) == len(ids), ids
    assert all(0 < i < 2**53 for i in ids)  # a plain integer a browser reads exactly
