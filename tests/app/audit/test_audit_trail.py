"""The audit trail's store (app/audit/trail.py, real SQLite): retention by count and age, a bounded
queue, a write that fails keeps its records, and the query's filters and order."""

from __future__ import annotations

import os
import stat
import time

from app.audit import trail as trails


def row(ts_ns: int, client: str = "c", status: int = 200) -> tuple:
    return (ts_ns, client, "10.0.0.1", "operator", "PUT", "/api/v1/apps/a/data/t", "data", "apps", "a", None,
            status, None)


def test_retention_by_count_and_by_age(tmp_path):
    trail = trails.AuditTrail(str(tmp_path / "access.db"), max_records=100, max_age_days=1)
    trail._pid = os.getpid()   # no background writer: this test flushes itself
    now = time.time_ns()
    for n in range(30):
        trail.record(row(now - 2 * 86400 * 10**9 + n))    # two days old
    for n in range(150):
        trail.record(row(now + n, client=f"c{n}"))
    trail.flush()
    kept = trail.query([], None, 1000)
    assert [r["client_id"] for r in kept] == [f"c{n}" for n in range(149, 49, -1)]
    assert stat.S_IMODE(os.stat(tmp_path / "access.db").st_mode) == 0o600
    assert trail.query([("status_min", 400)], None, 10) == []
    assert [r["client_id"] for r in trail.query([("client_id", "c7")], None, 10)] == []   # pruned
    page = trail.query([], None, 3)
    assert [r["client_id"] for r in trail.query([], page[-1]["id"], 3)] == ["c146", "c145", "c144"]


def test_the_queue_is_bounded_and_a_failed_write_keeps_its_records(tmp_path, monkeypatch):
    monkeypatch.setattr(trails, "PENDING_MAX", 5)
    trail = trails.AuditTrail(str(tmp_path / "access.db"), max_records=100, max_age_days=1)
    trail._pid = os.getpid()
    trail._pending = trails.collections.deque(maxlen=5)
    for n in range(8):
        trail.record(row(time.time_ns(), client=f"c{n}"))
    assert trail.dropped == 3 and len(trail._pending) == 5
    blocker = tmp_path / "blocked"
    blocker.write_text("a file where the state directory should be")
    trail.db_path = str(blocker / "access.db")
    trail.flush()
    assert trail.write_errors == 1 and [r[1] for r in trail._pending] == [f"c{n}" for n in range(3, 8)]
    trail.db_path = str(tmp_path / "access.db")
    trail.flush()
    assert [r["client_id"] for r in trail.query([], None, 10)] == [f"c{n}" for n in range(7, 2, -1)]


def test_off_records_nothing(tmp_path):
    trail = trails.AuditTrail(str(tmp_path / "access.db"), max_records=0, max_age_days=1)
    trail.record(row(time.time_ns()))
    assert not trail.enabled and len(trail._pending) == 0 and not (tmp_path / "access.db").exists()
