"""The gateway's memory: SQLite in the state directory, written by one thread of the ROS worker.

``<state_dir>/faults.db`` (Python's ``sqlite3``; WAL, ``synchronous=FULL``, so a
committed write survives a killed process and a power cut) holds three tables:

- ``faults``: one row per fault code, its record as a JSON document
  (``rosworker/faults/manager.py`` owns the record's fields);
- ``events``: the fault stream's last ``MAX_EVENTS`` events by id, so that a
  client reconnecting with ``Last-Event-ID`` is answered from here, even after
  a restart;
- ``triggers``: one row per trigger, its record as a JSON document
  (``rosworker/triggers/registry.py`` owns it): a change writes that one row, never the
  whole set.

The file, its ``-wal`` and ``-shm`` are the service user's alone (0600: freeze
frames hold robot data), in a state directory made 0700 when the gateway makes
it (systemd makes it with ``StateDirectoryMode=``).

Threads: :meth:`FaultStore.load` and :meth:`FaultStore.load_triggers` run on
the ROS thread at start-up, before the loop.  After :meth:`start`, the ROS
thread only calls :meth:`put`, :meth:`event` and :meth:`put_trigger`, which put
the change in a dict keyed by fault code or trigger id (the latest state wins:
a burst of changes to one row is one row write) and wake the writer thread; so
the pending work is bounded by the number of faults (``max_faults``), of
triggers (``max_triggers``) and ``MAX_EVENTS``, and a write never delays a
take.  A failed write (disk full, file removed) is counted, kept as
``last_write_error`` and retried after ``RETRY_AFTER`` s with whatever is newer.

A file that SQLite cannot open or whose ``PRAGMA quick_check`` fails is moved
aside (``faults.db.corrupt-<unix time>``) with an error line in the log, and an
empty store is used: the gateway starts without its history rather than not
at all.  A state directory that cannot be written at all leaves the store in
memory only (also logged).
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
import threading
import time
from collections.abc import Callable
from typing import Any

log = logging.getLogger("sovd.rosworker.faultstore")

FILE_NAME = "faults.db"
MAX_EVENTS = 1000          # events kept for Last-Event-ID replay
RETRY_AFTER = 1.0          # seconds before a failed write is tried again
BUSY_TIMEOUT = 5.0         # seconds sqlite waits for a lock (only this process writes)

FILE_MODE = 0o600         # the store's files: the service user's alone
DIR_MODE = 0o700          # a state directory the gateway makes
_SCHEMA = (
    "CREATE TABLE IF NOT EXISTS faults (code TEXT PRIMARY KEY, doc TEXT NOT NULL, updated_ns INTEGER NOT NULL)",
    "CREATE TABLE IF NOT EXISTS events (id INTEGER PRIMARY KEY, doc TEXT NOT NULL)",
    "CREATE TABLE IF NOT EXISTS triggers (id TEXT PRIMARY KEY, doc TEXT NOT NULL)",
)


class FaultStore:
    def __init__(self, state_dir: str):
        self.path = os.path.join(state_dir, FILE_NAME) if state_dir else ""
        self.enabled = bool(self.path)
        self._db: sqlite3.Connection | None = None
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._faults: dict[str, dict[str, Any] | None] = {}   # code -> record (None: delete)
        self._events: list[tuple[int, dict[str, Any]]] = []
        self._triggers: dict[str, bytes | None] = {}        # trigger id -> record (None: delete)
        self._written: list[Callable[[], None]] = []         # called once what was put before is written
        self._thread: threading.Thread | None = None
        self._closing = False
        self._busy = False
        # what /health shows (read by the control thread: plain attributes)
        self.writes = 0
        self.write_errors = 0
        self.last_write_error = ""
        self.moved_aside = ""      # where a corrupt file went, if one did at start-up

    # ---- start-up (ROS thread, before the loop) ------------------------------------------------
    def load(self) -> tuple[dict[str, dict[str, Any]], list[tuple[int, dict[str, Any]]]]:
        """The stored faults and events; a corrupt file is moved aside and an empty store used."""
        if not self.enabled:
            return {}, []
        try:
            make_private_dir(os.path.dirname(self.path))
        except OSError as exc:
            self._disable(f"cannot create the state directory: {exc}")
            return {}, []
        try:
            return self._open_and_read()
        except sqlite3.DatabaseError as exc:
            self._close_db()
            self._move_aside(exc)
        try:
            return self._open_and_read()
        except sqlite3.Error as exc:
            self._close_db()
            self._disable(f"cannot open a new store: {exc}")
            return {}, []

    def _open_and_read(self):
        private_files(self.path)
        db = sqlite3.connect(self.path, timeout=BUSY_TIMEOUT, isolation_level=None, check_same_thread=False)
        self._db = db
        check = db.execute("PRAGMA quick_check").fetchone()
        if not check or check[0] != "ok":
            raise sqlite3.DatabaseError(f"quick_check: {check[0] if check else 'no answer'}")
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=FULL")
        for statement in _SCHEMA:
            db.execute(statement)
        faults: dict[str, dict[str, Any]] = {}
        for code, doc in db.execute("SELECT code, doc FROM faults"):
            try:
                record = json.loads(doc)
            except ValueError:
                log.warning("fault store: the record of %r is not JSON; dropped", code[:100])
                continue
            if isinstance(record, dict):
                faults[code] = record
        events = []
        for event_id, doc in db.execute("SELECT id, doc FROM events ORDER BY id DESC LIMIT ?", (MAX_EVENTS,)):
            try:
                events.append((int(event_id), json.loads(doc)))
            except ValueError:
                continue
        events.reverse()
        private_files(self.path)  # the -wal and -shm that journal_mode=WAL made (SQLite copies the file's mode)
        log.info("fault store %s: %d faults, %d events", self.path, len(faults), len(events))
        return faults, events

    def load_triggers(self) -> list[tuple[str, Any]]:
        """The stored triggers: ``(row id, record)``, the record None when it is not JSON (ROS thread,
        after :meth:`load`, before :meth:`start`)."""
        if not self.enabled or self._db is None:
            return []
        out: list[tuple[str, Any]] = []
        try:
            for trigger_id, doc in self._db.execute("SELECT id, doc FROM triggers"):
                try:
                    out.append((str(trigger_id), json.loads(doc)))
                except ValueError:
                    out.append((str(trigger_id), None))
        except sqlite3.Error as exc:
            log.error("store %s: the triggers could not be read (%s)", self.path, exc)
        return out

    def _move_aside(self, exc: Exception) -> None:
        target = f"{self.path}.corrupt-{int(time.time())}"
        try:
            os.replace(self.path, target)
            for suffix in ("-wal", "-shm"):
                if os.path.exists(self.path + suffix):
                    os.replace(self.path + suffix, target + suffix)
        except OSError as move_error:
            log.error("fault store %s is corrupt or unreadable (%s) and could not be moved aside (%s)",
                      self.path, exc, move_error)
            return
        self.moved_aside = target
        log.error("fault store %s is corrupt or unreadable (%s): moved it aside to %s; starting with an "
                  "empty fault store (the old file is kept for inspection)", self.path, exc, target)

    def _disable(self, why: str) -> None:
        self.enabled = False
        self.last_write_error = why
        log.error("fault store %s: %s; faults are kept in memory only until the next restart", self.path, why)

    def _close_db(self) -> None:
        if self._db is not None:
            try:
                self._db.close()
            except sqlite3.Error:
                pass
            self._db = None

    def start(self) -> None:
        if self.enabled and self._db is not None:
            self._thread = threading.Thread(target=self._run, name="fault-store-writer", daemon=True)
            self._thread.start()

    # ---- ROS thread ------------------------------------------------------------------------------
    def put(self, code: str, record: dict[str, Any] | None) -> None:
        """Write ``record`` as the fault ``code`` (None: delete it), soon, on the writer thread."""
        if not self.enabled:
            return
        with self._lock:
            self._faults[code] = None if record is None else dict(record)
            self._wake.notify()

    def event(self, event_id: int, event: dict[str, Any]) -> None:
        if not self.enabled:
            return
        with self._lock:
            self._events.append((event_id, event))
            if len(self._events) > MAX_EVENTS:
                del self._events[:-MAX_EVENTS]
            self._wake.notify()

    def put_trigger(self, trigger_id: str, record: bytes | None, then: Callable[[], None] | None = None) -> None:
        """Write one trigger's record (None: delete it), soon, on the writer thread; ``then()`` is
        called (on that thread) once it is written.  A store in memory only calls it at once."""
        if not self.enabled or self._db is None:
            if then is not None:
                then()
            return
        with self._lock:
            self._triggers[trigger_id] = record
            if then is not None:
                self._written.append(then)
            self._wake.notify()
        if self._thread is None:  # not started, or closed: written here
            self._write_now()

    @property
    def pending(self) -> int:
        return len(self._faults) + len(self._events) + len(self._triggers) + (1 if self._busy else 0)

    def close(self, timeout: float) -> None:
        """Write what is pending (waiting up to ``timeout`` s), then close the file."""
        with self._lock:
            self._closing = True
            self._wake.notify()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                log.warning("fault store: the last writes did not finish within %g s", timeout)
                return
        self._write_now()  # never started (or the writer gave up): what is pending is written here
        self._close_db()
        self.enabled = False

    def _write_now(self) -> None:
        """Write what is pending on the calling thread (no writer thread runs)."""
        with self._lock:
            faults, self._faults = self._faults, {}
            events, self._events = self._events, []
            triggers, self._triggers = self._triggers, {}
            then, self._written = self._written, []
        if self._db is None or not (faults or events or triggers):
            for fn in then:
                fn()
            return
        try:
            self._write(faults, events, triggers)
            self.writes += 1
        except sqlite3.Error as exc:
            self.write_errors += 1
            self.last_write_error = f"{type(exc).__name__}: {exc}"[:300]
            log.error("store %s: a write failed (%s)", self.path, exc)
        for fn in then:
            fn()

    # ---- the writer thread -------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._lock:
                while not self._faults and not self._events and not self._triggers and not self._closing:
                    self._wake.wait()
                if not self._faults and not self._events and not self._triggers:
                    return
                faults, self._faults = self._faults, {}
                events, self._events = self._events, []
                triggers, self._triggers = self._triggers, {}
                then, self._written = self._written, []
                self._busy = True
            try:
                self._write(faults, events, triggers)
                self.writes += 1
                for fn in then:
                    fn()
            except sqlite3.Error as exc:
                self.write_errors += 1
                self.last_write_error = f"{type(exc).__name__}: {exc}"[:300]
                if self.write_errors == 1 or self.write_errors % 100 == 0:
                    log.error("fault store %s: write failed (%s; %d failures so far); retrying in %g s",
                              self.path, exc, self.write_errors, RETRY_AFTER)
                with self._lock:
                    for code, record in faults.items():
                        self._faults.setdefault(code, record)  # a newer state of a fault wins
                    for trigger_id, doc in triggers.items():
                        self._triggers.setdefault(trigger_id, doc)
                    self._written[:0] = then
                    self._events[:0] = events
                    del self._events[:-MAX_EVENTS]
                    closing = self._closing
                if closing:
                    return
                time.sleep(RETRY_AFTER)
            finally:
                self._busy = False

    def _write(self, faults: dict[str, dict[str, Any] | None], events: list[tuple[int, dict[str, Any]]],
               triggers: dict[str, bytes | None]) -> None:
        db = self._db
        now = time.time_ns()
        db.execute("BEGIN IMMEDIATE")
        try:
            deleted = [(code,) for code, record in faults.items() if record is None]
            if deleted:
                db.executemany("DELETE FROM faults WHERE code = ?", deleted)
            rows = [(code, json.dumps(record, separators=(",", ":")), now)
                    for code, record in faults.items() if record is not None]
            if rows:
                db.executemany("INSERT INTO faults (code, doc, updated_ns) VALUES (?, ?, ?) ON CONFLICT(code) "
                               "DO UPDATE SET doc = excluded.doc, updated_ns = excluded.updated_ns", rows)
            if events:
                db.executemany("INSERT OR REPLACE INTO events (id, doc) VALUES (?, ?)",
                               [(i, json.dumps(e, separators=(",", ":"))) for i, e in events])
                db.execute("DELETE FROM events WHERE id <= ?", (events[-1][0] - MAX_EVENTS,))
            gone = [(i,) for i, doc in triggers.items() if doc is None]
            if gone:
                db.executemany("DELETE FROM triggers WHERE id = ?", gone)
            kept = [(i, doc.decode()) for i, doc in triggers.items() if doc is not None]
            if kept:
                db.executemany("INSERT OR REPLACE INTO triggers (id, doc) VALUES (?, ?)", kept)
            db.execute("COMMIT")
        except BaseException:
            try:
                db.execute("ROLLBACK")
            except sqlite3.Error:
                pass
            raise


def make_private_dir(path: str) -> None:
    """``path`` made 0700 if it is not there (its parents as the umask says); one that is stays as it is."""
    if not os.path.isdir(path):
        os.makedirs(path, exist_ok=True)
        os.chmod(path, DIR_MODE)


def private_files(path: str) -> None:
    """The database file made 0600 before SQLite opens it (SQLite gives its -wal and -shm the file's
    mode), and an existing file, -wal or -shm of a looser mode narrowed to 0600."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, FILE_MODE)
    os.close(fd)
    for name in (path, path + "-wal", path + "-shm"):
        try:
            if os.stat(name).st_mode & 0o777 != FILE_MODE:
                os.chmod(name, FILE_MODE)
        except FileNotFoundError:
            pass
