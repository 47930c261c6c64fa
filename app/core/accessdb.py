"""The HTTP workers' SQLite store in the state directory: ``access.db``.

Two tables, written by every HTTP worker (SQLite serialises their writes; WAL lets readers go on
while one writes, and ``synchronous=FULL`` keeps a committed row through a power cut):

- ``audit``: one row per write attempt that reached a route (``app/audit/``);
- ``revoked``: the ids (``jti``) of revoked tokens until their expiry (``app/auth/revocations.py``).

A connection is opened per use, on a thread of gevent's pool (``app/blocking.py``), never on the
event loop.  The file, its ``-wal`` and ``-shm`` are 0600 in a 0700 directory
(``common/statedir.py``); it lives beside the ROS worker's ``faults.db``.  The directory is
``state_dir`` (default ``$STATE_DIRECTORY``, else XDG's state home).
"""

from __future__ import annotations

import os
import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager

from common import settings
from common.statedir import make_private_dir, private_files

FILE_NAME = "access.db"
BUSY_TIMEOUT = 5.0   # seconds a write waits for another HTTP worker's
_SCHEMA = (
    "CREATE TABLE IF NOT EXISTS audit (id INTEGER PRIMARY KEY AUTOINCREMENT, ts_ns INTEGER NOT NULL, "
    "client_id TEXT, address TEXT NOT NULL, role TEXT, method TEXT NOT NULL, resource TEXT NOT NULL, "
    "family TEXT NOT NULL, collection TEXT, entity_id TEXT, request_id TEXT, status INTEGER NOT NULL, "
    "error_code TEXT)",
    "CREATE INDEX IF NOT EXISTS audit_ts ON audit (ts_ns)",
    "CREATE TABLE IF NOT EXISTS revoked (jti TEXT PRIMARY KEY, expires_at INTEGER NOT NULL)",
)


def path_for(cfg) -> str:
    """``access.db`` in the configured state directory."""
    return os.path.join(cfg.state_dir or settings.default_state_dir(os.environ), FILE_NAME)


_prepared: set[str] = set()


@contextmanager
def connect(path: str) -> Iterator[sqlite3.Connection]:
    """A connection to the store at ``path`` (made, private and in WAL mode on first use); closed after.

    Blocking: call it through ``app/blocking.py``.  Raises ``sqlite3.Error`` or ``OSError``.
    """
    if path not in _prepared:
        make_private_dir(os.path.dirname(path))
        private_files(path)
    db = sqlite3.connect(path, timeout=BUSY_TIMEOUT, isolation_level=None, check_same_thread=False)
    try:
        if path not in _prepared:
            db.execute("PRAGMA journal_mode=WAL")
            for statement in _SCHEMA:
                db.execute(statement)
            private_files(path)  # the -wal and -shm that WAL mode made
            _prepared.add(path)
        db.execute("PRAGMA synchronous=FULL")
        yield db
    finally:
        db.close()
