"""The audit trail: one record per write attempt that reached a route, kept in ``access.db``.

A record (``app/core/accessdb.py``'s ``audit`` table): when (``ts_ns``), who (the token's client id,
else nobody; and always the client's address, the real one behind nginx), with which role, what
(the method, the path without its query, the route family, the entity, the request id) and the
outcome (the status and the answer's error code).  A write refused by the role check (401, 403),
by a lock (409), by an ``allow_*`` switch (403) or by its route's own checks is an attempt like any
other; a path that matches no route is not recorded.  Never in a record: a header, a body, a query
string; so never a secret or a token.

Off the request path: :meth:`AuditTrail.record` only appends a tuple to this worker's queue
(bounded by :data:`PENDING_MAX`; past it the oldest record is dropped and counted, and the log
says so).  Every :data:`FLUSH_EVERY` seconds a background greenlet hands the queue to a thread of
gevent's pool, which writes it in one transaction (``app/blocking.py``); records are written at
exit too.  A failed write keeps the records queued and is tried again.

Retention: past ``audit_max_records`` rows the oldest are deleted, and rows older than
``audit_max_age_days``, in the transaction of each write (by the primary key and the time index:
cheap), and every :data:`PRUNE_EVERY` seconds when nothing is written.
``audit_max_records = 0`` turns the trail off.
"""

from __future__ import annotations

import atexit
import collections
import logging
import os
import sqlite3
import time
from typing import Any

from ..core import accessdb, blocking

log = logging.getLogger("sovd.http.audit")

FLUSH_EVERY = 0.25      # seconds between writes of the queue
PENDING_MAX = 20000     # records one worker keeps queued at most
PRUNE_EVERY = 60.0      # seconds between retention checks
LOG_EVERY = 10.0        # seconds between two log lines about failed writes or dropped records
COLUMNS = ("ts_ns", "client_id", "address", "role", "method", "resource", "family", "collection",
           "entity_id", "request_id", "status", "error_code")
_INSERT = f"INSERT INTO audit ({', '.join(COLUMNS)}) VALUES ({', '.join('?' * len(COLUMNS))})"


class AuditTrail:
    def __init__(self, db_path: str, max_records: int, max_age_days: int):
        self.db_path = db_path
        self.max_records = max_records
        self.max_age_ns = max_age_days * 86400 * 10**9
        self.enabled = max_records > 0
        self._pending: collections.deque[tuple[Any, ...]] = collections.deque(maxlen=PENDING_MAX)
        self._pid = 0
        self._stop = None
        self._pruned = 0.0
        self._logged = 0.0
        self.dropped = 0
        self.written = 0
        self.write_errors = 0

    def record(self, row: tuple[Any, ...]) -> None:
        """Queue one record (on the request's greenlet: no I/O)."""
        if not self.enabled:
            return
        if self._pid != os.getpid():
            self._start()
        if len(self._pending) == PENDING_MAX:
            self.dropped += 1
        self._pending.append(row)

    def _start(self) -> None:
        self._pid = os.getpid()
        self._pending.clear()  # a parent's queue is the parent's to write
        self._stop = blocking.every(FLUSH_EVERY, self.flush, "audit trail writer")
        atexit.register(self._flush_at_exit)

    def close(self) -> None:
        """Write what is queued and stop the writer (an app that is done: a test's)."""
        if self._pid == os.getpid() and self._stop is not None:
            self._stop()
            self._stop = None
            self._flush_at_exit()

    def _flush_at_exit(self) -> None:
        if self._pending and os.path.isdir(os.path.dirname(self.db_path)):  # (a test's directory may be gone)
            self.flush()

    def flush(self) -> None:
        """Write what is queued (blocking: on a pool thread, or at exit)."""
        rows = []
        while self._pending:
            rows.append(self._pending.popleft())
        now = time.monotonic()
        if not rows and (now - self._pruned < PRUNE_EVERY or not os.path.isdir(os.path.dirname(self.db_path))):
            return   # (nothing to write, and nothing to prune in a store that is not there)
        try:
            with accessdb.connect(self.db_path) as db:
                db.execute("BEGIN IMMEDIATE")
                db.executemany(_INSERT, rows)
                self._prune(db)
                db.execute("COMMIT")
        except (sqlite3.Error, OSError) as exc:
            self.write_errors += 1
            self._pending.extendleft(reversed(rows))  # the oldest go first should the queue fill up
            self._say(f"audit trail: cannot write {self.db_path} ({exc}); {len(self._pending)} records wait")
            return
        self._pruned = now
        self.written += len(rows)
        if self.dropped:
            self._say(f"audit trail: {self.dropped} records dropped so far (more than {PENDING_MAX} waited)")

    def _prune(self, db: sqlite3.Connection) -> None:
        db.execute("DELETE FROM audit WHERE ts_ns < ?", (time.time_ns() - self.max_age_ns,))
        newest = db.execute("SELECT MAX(id) FROM audit").fetchone()[0]
        if newest is not None:
            db.execute("DELETE FROM audit WHERE id <= ?", (newest - self.max_records,))

    def _say(self, text: str) -> None:
        now = time.monotonic()
        if now - self._logged >= LOG_EVERY:
            self._logged = now
            log.error("%s", text)

    # ---- reading (GET /api/v1/x-medkit-audit) ----------------------------------------------------
    def query(self, where: list[tuple[str, Any]], before: int | None, limit: int) -> list[dict[str, Any]]:
        """The newest ``limit`` records matching every ``(column, value)`` (blocking)."""
        clauses, values = [], []
        for column, value in where:
            if column == "since_ns":
                clauses.append("ts_ns >= ?")
            elif column == "until_ns":
                clauses.append("ts_ns < ?")
            elif column == "status_min":
                clauses.append("status >= ?")
            elif column == "status_max":
                clauses.append("status <= ?")
            else:
                assert column in COLUMNS
                clauses.append(f"{column} = ?")
            values.append(value)
        with accessdb.connect(self.db_path) as db:
            if before is not None:
                # the page after the record ``before``: older ones, by time then id (a record pruned
                # since: by id alone)
                row = db.execute("SELECT ts_ns FROM audit WHERE id = ?", (before,)).fetchone()
                if row is None:
                    clauses.append("id < ?")
                    values.append(before)
                else:
                    clauses.append("(ts_ns < ? OR (ts_ns = ? AND id < ?))")
                    values += [row[0], row[0], before]
            sql = f"SELECT id, {', '.join(COLUMNS)} FROM audit"
            if clauses:
                sql += " WHERE " + " AND ".join(clauses)
            sql += " ORDER BY ts_ns DESC, id DESC LIMIT ?"
            values.append(limit)
            return [dict(zip(("id", *COLUMNS), row, strict=True)) for row in db.execute(sql, values)]
