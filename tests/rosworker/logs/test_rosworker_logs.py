"""rosworker/logs/book.py on its own: the CDR reader against rclpy's serializer, the caps, queries and commands.

The same behaviour through a real gateway and real nodes: tests/system/logs/test_app_logs.py and
tests/system/logs/test_app_logs_storm.py.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rcl_interfaces.msg import Log
from rclpy.serialization import deserialize_message, serialize_message

from ipc.errors import IpcError
from rosworker.core.stats import Stats
from rosworker.logs.book import MAX_TEXT, LogBook, parse_log


class Task:
    def __init__(self, args):
        self.args = args
        self.result = None

    def reply(self, result):
        self.result = result


def book(**kw) -> LogBook:
    caps = {"buffer_size": 3, "max_bytes": 10**6, "max_nodes": 2, **kw}
    return LogBook(None, None, Stats(pool_cap=1, cold_wait_cap=1, watchdog_threshold_ms=1000), **caps)


def line(b: LogBook, name: str, msg: str, level: int = 20) -> None:
    b.add(1, 2, level, name, msg, "f.py", "fn", 7)


@settings(max_examples=200, deadline=None)
@given(sec=st.integers(-2**31, 2**31 - 1), nanosec=st.integers(0, 2**32 - 1), level=st.integers(0, 255),
       name=st.text(max_size=50), msg=st.text(max_size=300), file=st.text(max_size=30),
       function=st.text(max_size=30), number=st.integers(0, 2**32 - 1))
def test_the_cdr_reader_reads_what_rclpy_writes(sec, nanosec, level, name, msg, file, function, number):
    m = Log(level=level, name=name, msg=msg, file=file, function=function, line=number)
    m.stamp.sec, m.stamp.nanosec = sec, nanosec
    raw = serialize_message(m)
    d = deserialize_message(raw, Log)  # what rclpy reads back (a NUL ends a string, as in C)
    assert parse_log(raw) == (d.stamp.sec, d.stamp.nanosec, d.level, d.name, d.msg, d.file, d.function, d.line)
    if "\x00" not in name + msg + file + function:
        assert parse_log(raw) == (sec, nanosec, level, name, msg, file, function, number)


def test_the_cdr_reader_cuts_long_messages_and_refuses_truncated_ones():
    raw = serialize_message(Log(name="n", msg="x" * (MAX_TEXT + 10)))
    assert parse_log(raw)[4] == "x" * MAX_TEXT + f"… [cut: {MAX_TEXT + 10} characters]"
    with pytest.raises(ValueError):
        parse_log(raw[:40])
    assert parse_log(b"\x00\x00\x00\x00" + raw[4:]) is None  # big-endian: left to rclpy


def test_per_node_ring_byte_cap_and_node_cap_are_counted():
    b = book()
    for i in range(5):
        line(b, "a", f"a{i}")
    assert [r[5] for r in b.query(["a"], 0, "", 100)] == ["a2", "a3", "a4"]
    assert b.stats.logs_evicted == 2 and b.stats.logs_buffered == 3
    line(b, "b", "b0")
    line(b, "c", "dropped")   # a third node past max_nodes=2
    assert b.stats.logs_dropped == 1 and "c" not in b.buffers and b.stats.logs_nodes == 2
    small = book(max_bytes=400, buffer_size=100)
    for i in range(10):
        line(small, "a" if i % 2 else "b", f"{i}" * 20)
    assert small.nbytes <= 400 and small.stats.logs_bytes == small.nbytes
    kept = small.query(["a", "b"], 0, "", 100)
    assert [r[5][0] for r in kept] == [str(i) for i in range(10 - len(kept), 10)]  # the oldest anywhere went


def test_the_order_index_stays_bounded_when_rings_push_out():
    b = book(buffer_size=2, max_nodes=10)
    for i in range(10000):
        line(b, "a", str(i))
    assert len(b._order) <= 2 * b._live + 64


def test_queries_merge_nodes_by_arrival_and_apply_severity_context_and_limit():
    b = book(buffer_size=10)
    line(b, "ns.a", "1", 10)
    line(b, "ns.b", "2", 40)
    line(b, "ns.a", "3", 30)
    assert [r[5] for r in b.query(["ns.a", "ns.b"], 0, "", 100)] == ["1", "2", "3"]
    assert [r[5] for r in b.query(["ns.a", "ns.b"], 30, "", 100)] == ["2", "3"]
    assert [r[5] for r in b.query(["ns.a", "ns.b"], 0, ".b", 100)] == ["2"]
    assert [r[5] for r in b.query(["ns.a", "ns.b"], 0, "", 2)] == ["2", "3"]
    task = Task({"entity_id": "a", "nodes": ["/ns/a"], "severity": "warning"})
    b.query_cmd(task)
    assert [r[5] for r in task.result["rows"]] == ["3"]   # an FQN matches its dotted logger name


def test_configuration_commands_and_their_guards():
    b = book()
    task = Task({"entity_id": "x"})
    b.config_get_cmd(task)
    assert task.result == {"severity_filter": "debug", "max_entries": 100}
    b.config_set_cmd(Task({"entity_id": "x", "max_entries": 7}))
    b.config_set_cmd(Task({"entity_id": "x", "severity_filter": "error"}))
    b.config_get_cmd(task)
    assert task.result == {"severity_filter": "error", "max_entries": 7}
    for bad in ({"entity_id": "x", "max_entries": 0}, {"entity_id": "x", "max_entries": True},
                {"entity_id": "x", "severity_filter": "loud"}, {"entity_id": ""}, {"entity_id": 5}):
        with pytest.raises(IpcError) as err:
            b.config_set_cmd(Task(bad))
        assert err.value.code == "bad-request"
    for bad in ({"entity_id": "x", "nodes": "a"}, {"entity_id": "x", "nodes": [1]},
                {"entity_id": "x", "nodes": [], "severity": "loud"}, {"entity_id": "x", "nodes": [], "context": 5}):
        with pytest.raises(IpcError):
            b.query_cmd(Task(bad))
