"""rosworker/core/store.py: the state dir's SQLite store: tables a family declares, a corrupt file, a
state dir that cannot be written, failed writes retried, the bound on what waits.

A real SQLite file and the real writer thread; the faults' and the triggers' use of it through the real
gateway: tests/system/faults/test_app_fault_store.py, tests/system/triggers/test_app_trigger_store.py.
"""

from __future__ import annotations

import os
import sqlite3
import threading
import time

from common.harness.procs import poll_until
from rosworker.core.store import Store, Table

THINGS = Table("things", "CREATE TABLE IF NOT EXISTS things (id TEXT PRIMARY KEY, doc TEXT NOT NULL)",
               upsert="INSERT OR REPLACE INTO things (id, doc) VALUES (?, ?)", delete="DELETE FROM things WHERE id = ?",
               select="SELECT id, doc FROM things")
LOG = Table("log", "CREATE TABLE IF NOT EXISTS log (id INTEGER PRIMARY KEY, doc TEXT NOT NULL)",
            upsert="INSERT OR REPLACE INTO log (id, doc) VALUES (?, ?)", delete="DELETE FROM log WHERE id = ?",
            select="SELECT id, doc FROM log ORDER BY id", keep=3, trim="DELETE FROM log WHERE id <= ?")


def opened(path) -> Store:
    store = Store(str(path))
    store.open()
    return store


def test_rows_put_and_deleted_come_back_and_a_then_runs_once_written(tmp_path):
    store = opened(tmp_path)
    things = store.table(THINGS)
    store.start()
    written = threading.Event()
    things.put("a", {"v": 1})
    things.put("b", b'{"v":2}')
    things.put("a", {"v": 3}, then=written.set)   # the newest value of a row wins
    things.put("b", None)                         # deleted
    assert written.wait(5)
    store.close(5)
    again = opened(tmp_path)
    assert again.table(THINGS).rows() == [("a", {"v": 3})]
    again.close(1)


def test_a_keep_table_keeps_its_newest_rows(tmp_path):
    store = opened(tmp_path)
    log = store.table(LOG)
    for i in range(1, 8):
        log.put(i, {"n": i})   # before start: written at once
    store.close(1)
    assert opened(tmp_path).table(LOG).rows() == [(5, {"n": 5}), (6, {"n": 6}), (7, {"n": 7})]


def test_a_corrupt_file_is_moved_aside(tmp_path, caplog):
    path = tmp_path / "faults.db"
    path.write_bytes(b"\x00garbage" * 4096)
    store = opened(tmp_path)
    assert store.table(THINGS).rows() == []
    assert store.moved_aside.startswith(str(path) + ".corrupt-") and os.path.exists(store.moved_aside)
    assert "moved it aside" in caplog.text
    store.close(1)


def test_an_unwritable_state_dir_keeps_everything_in_memory_and_answers_at_once(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    store = opened(blocker / "sub")
    things = store.table(THINGS)
    assert things.rows() == [] and store.enabled is False and store.last_write_error
    answered = []
    things.put("X", {"code": "X"}, then=lambda: answered.append(1))   # nothing to write to, nothing raised
    assert answered == [1]
    store.close(1)


def test_a_failed_write_is_counted_and_retried(tmp_path, monkeypatch):
    monkeypatch.setattr("rosworker.core.store.RETRY_AFTER", 0.05)
    store = opened(tmp_path)
    things = store.table(THINGS)
    store.start()
    real = store._writer._write
    calls = {"n": 0}

    def flaky(batch):
        calls["n"] += 1
        if calls["n"] == 1:
            raise sqlite3.OperationalError("disk I/O error")
        real(batch)

    monkeypatch.setattr(store._writer, "_write", flaky)
    things.put("A", {"code": "A"})
    poll_until(lambda: store.writes >= 1, 5, message="the write, tried again")
    assert store.write_errors == 1 and "disk I/O error" in store.last_write_error and store.writes == 1
    store.close(5)
    db = sqlite3.connect(tmp_path / "faults.db")
    assert db.execute("SELECT id FROM things").fetchall() == [("A",)]
    db.close()


def test_what_waits_for_a_failing_disk_is_bounded_for_a_keep_table(tmp_path, monkeypatch):
    monkeypatch.setattr("rosworker.core.store.RETRY_AFTER", 0.01)
    store = opened(tmp_path)
    log = store.table(LOG)
    store.start()

    def failing(batch):
        raise sqlite3.OperationalError("disk full")

    monkeypatch.setattr(store._writer, "_write", failing)
    for i in range(1, 200):
        log.put(i, {"n": i})
    poll_until(lambda: store.write_errors >= 2, 5, message="failing writes")
    deadline = time.monotonic() + 1
    while time.monotonic() < deadline:
        assert store.pending <= LOG.keep + 1
        time.sleep(0.01)
    store.close(0.5)
