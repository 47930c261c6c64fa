"""The gateway's memory: SQLite in the state directory, written by one thread of the ROS worker.

``<state_dir>/faults.db`` (Python's ``sqlite3``; WAL, ``synchronous=FULL``, so a
committed write survives a killed process and a power cut) holds the tables the
families declare with :meth:`Store.table` (:class:`Table`: its ``CREATE``, how a
row is put and deleted, and how they are read back at start-up): the faults and
their events (``faults/store.py``), the triggers (``triggers/store.py``).  A row
is a key and a JSON document; a change writes that one row, never a whole set.

The file, its ``-wal`` and ``-shm`` are the service user's alone (0600: freeze
frames hold robot data), in a state directory made 0700 when the gateway makes
it (systemd makes it with ``StateDirectoryMode=``).

Threads: :meth:`Store.open` and :meth:`TableHandle.rows` run on the ROS thread
at start-up, before the loop.  After :meth:`start`, the ROS thread only calls
:meth:`TableHandle.put`, which hands the row to the writer thread
(``core/writer.py``: keyed by table and key, the latest state wins, so a burst
of changes to one row is one row write) and never waits on the disk; what waits
is bounded by the rows (``max_faults``, ``max_triggers``) and, for a table with
``keep`` (the fault events), by that count.  A failed write (disk full, file
removed) is counted, kept as ``last_write_error`` and retried after
``RETRY_AFTER`` s with whatever is newer.

A file that SQLite cannot open or whose ``PRAGMA quick_check`` fails is moved
aside (``faults.db.corrupt-<unix time>``) with an error line in the log, and an
empty store is used: the gateway starts without its history rather than not
at all.  A state directory that cannot be written at all leaves the store in
memory only (also logged): puts are dropped, and their ``then`` runs at once.
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from common.statedir import make_private_dir, private_files

from .writer import LatestWriter

log = logging.getLogger("sovd.rosworker.store")

FILE_NAME = "faults.db"
RETRY_AFTER = 1.0          # seconds before a failed write is tried again
BUSY_TIMEOUT = 5.0         # seconds sqlite waits for a lock (only this process writes)


@dataclass(frozen=True)
class Table:
    """One table of the store: rows of (key, JSON document).

    ``upsert`` takes ``(key, doc)``, or ``(key, doc, now_ns)`` when ``stamped``; ``delete`` takes
    ``(key,)``; ``select`` gives ``(key, doc)`` rows at start-up.  With ``keep`` (integer keys that
    only grow), ``trim`` deletes the rows up to the newest key written minus ``keep`` at each write,
    and no more than ``keep`` of them wait for the writer."""

    name: str
    create: str
    upsert: str
    delete: str
    select: str
    stamped: bool = False
    keep: int = 0
    trim: str = ""


class TableHandle:
    """A family's table: its rows at start-up, and puts (ROS thread)."""

    def __init__(self, store: Store, table: Table):
        self.store = store
        self.table = table

    def rows(self) -> list[tuple[Any, Any]]:
        """``(key, document)`` of every row, the document None when it is not JSON (start-up only)."""
        return self.store._rows(self.table)

    def put(self, key: Any, doc: Any, then: Callable[[], None] | None = None) -> None:
        """Write ``doc`` (a dict, or JSON bytes) as row ``key`` (None: delete it), soon, on the writer
        thread; ``then()`` on the ROS thread once it is written (at once when the store is in memory)."""
        self.store._put(self.table, key, doc, then)


class Store:
    def __init__(self, state_dir: str, post: Callable[[Callable[[], None]], None] | None = None):
        self.path = os.path.join(state_dir, FILE_NAME) if state_dir else ""
        self.enabled = bool(self.path)
        self._db: sqlite3.Connection | None = None
        self._tables: dict[str, Table] = {}
        self.moved_aside = ""      # where a corrupt file went, if one did at start-up
        self._why = ""             # why the store is in memory only
        self._writer = LatestWriter("store-writer", self._write, post=post, retry_after=RETRY_AFTER,
                                    on_error=self._failed, keep=self._bound)

    # ---- what /health shows (read by the control thread: plain attributes) --------------------------
    @property
    def writes(self) -> int:
        return self._writer.writes

    @property
    def write_errors(self) -> int:
        return self._writer.errors

    @property
    def last_write_error(self) -> str:
        return self._writer.last_error or self._why

    @property
    def pending(self) -> int:
        return self._writer.pending

    # ---- start-up (ROS thread, before the loop) ------------------------------------------------------
    def open(self) -> None:
        """Open the file (a corrupt one is moved aside and an empty store used)."""
        if not self.enabled:
            return
        try:
            make_private_dir(os.path.dirname(self.path))
        except OSError as exc:
            self._disable(f"cannot create the state directory: {exc}")
            return
        try:
            self._open()
            return
        except sqlite3.DatabaseError as exc:
            self._close_db()
            self._move_aside(exc)
        try:
            self._open()
        except sqlite3.Error as exc:
            self._close_db()
            self._disable(f"cannot open a new store: {exc}")

    def _open(self) -> None:
        private_files(self.path)
        db = sqlite3.connect(self.path, timeout=BUSY_TIMEOUT, isolation_level=None, check_same_thread=False)
        self._db = db
        check = db.execute("PRAGMA quick_check").fetchone()
        if not check or check[0] != "ok":
            raise sqlite3.DatabaseError(f"quick_check: {check[0] if check else 'no answer'}")
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=FULL")
        private_files(self.path)  # the -wal and -shm that journal_mode=WAL made (SQLite copies the file's mode)
        log.info("store %s opened", self.path)

    def table(self, table: Table) -> TableHandle:
        """Declare ``table`` (made if the file has none); a family's start."""
        self._tables[table.name] = table
        if self._db is not None:
            try:
                self._db.execute(table.create)
            except sqlite3.Error as exc:
                log.error("store %s: table %s could not be made (%s)", self.path, table.name, exc)
        return TableHandle(self, table)

    def _rows(self, table: Table) -> list[tuple[Any, Any]]:
        if not self.enabled or self._db is None:
            return []
        out: list[tuple[Any, Any]] = []
        try:
            for key, doc in self._db.execute(table.select):
                try:
                    out.append((key, json.loads(doc)))
                except ValueError:
                    log.warning("store: a row of %s (%r) is not JSON", table.name, str(key)[:100])
                    out.append((key, None))
        except sqlite3.Error as exc:
            log.error("store %s: the %s could not be read (%s)", self.path, table.name, exc)
        return out

    def _move_aside(self, exc: Exception) -> None:
        target = f"{self.path}.corrupt-{int(time.time())}"
        try:
            os.replace(self.path, target)
            for suffix in ("-wal", "-shm"):
                if os.path.exists(self.path + suffix):
                    os.replace(self.path + suffix, target + suffix)
        except OSError as move_error:
            log.error("store %s is corrupt or unreadable (%s) and could not be moved aside (%s)",
                      self.path, exc, move_error)
            return
        self.moved_aside = target
        log.error("store %s is corrupt or unreadable (%s): moved it aside to %s; starting with an "
                  "empty store (the old file is kept for inspection)", self.path, exc, target)

    def _disable(self, why: str) -> None:
        self.enabled = False
        self._why = why
        log.error("store %s: %s; faults and triggers are kept in memory only until the next restart",
                  self.path, why)

    def _close_db(self) -> None:
        if self._db is not None:
            try:
                self._db.close()
            except sqlite3.Error:
                pass
            self._db = None

    def start(self) -> None:
        if self.enabled and self._db is not None:
            self._writer.start()

    # ---- ROS thread ------------------------------------------------------------------------------
    def _put(self, table: Table, key: Any, doc: Any, then: Callable[[], None] | None) -> None:
        if not self.enabled or self._db is None:
            if then is not None:
                then()
            return
        # A dict is copied: its owner goes on changing it on the ROS thread (the writer serialises it).
        self._writer.submit((table.name, key), dict(doc) if isinstance(doc, dict) else doc, then)

    def _bound(self, pending: dict[tuple[str, Any], Any]) -> None:
        """What waits for the writer of a ``keep`` table: its newest ``keep`` rows (a disk that fails)."""
        for table in self._tables.values():
            if table.keep and len(pending) > table.keep:
                keys = sorted(k for k in pending if k[0] == table.name)
                for key in keys[:-table.keep]:
                    del pending[key]

    def close(self, timeout: float) -> None:
        """Write what is pending (waiting up to ``timeout`` s), then close the file."""
        if not self._writer.close(timeout):
            return
        self._close_db()
        self.enabled = False

    # ---- the writer thread -------------------------------------------------------------------------
    def _failed(self, exc: Exception) -> None:
        errors = self._writer.errors
        if errors == 1 or errors % 100 == 0:
            log.error("store %s: write failed (%s; %d failures so far); retrying in %g s",
                      self.path, exc, errors, RETRY_AFTER)

    def _write(self, batch: dict[tuple[str, Any], Any]) -> None:
        db = self._db
        if db is None:
            return
        now = time.time_ns()
        db.execute("BEGIN IMMEDIATE")
        try:
            for table in self._tables.values():
                rows = [(key, doc) for (name, key), doc in batch.items() if name == table.name]
                if not rows:
                    continue
                gone = [(key,) for key, doc in rows if doc is None]
                if gone:
                    db.executemany(table.delete, gone)
                kept = [(key, _text(doc)) + ((now,) if table.stamped else ()) for key, doc in rows
                        if doc is not None]
                if kept:
                    db.executemany(table.upsert, kept)
                if table.keep and kept:
                    db.execute(table.trim, (max(k for k, *_ in kept) - table.keep,))
            db.execute("COMMIT")
        except BaseException:
            try:
                db.execute("ROLLBACK")
            except sqlite3.Error:
                pass
            raise


def _text(doc: Any) -> str:
    if isinstance(doc, bytes):
        return doc.decode()
    if isinstance(doc, str):
        return doc
    return json.dumps(doc, separators=(",", ":"))
