"""Revoked tokens, shared by every HTTP worker and kept across restarts.

A revocation is a row of ``access.db``'s ``revoked`` table (``app/core/accessdb.py``): the token's id
(``jti``, never the token) and when the token expires anyway, after which the row is dropped.  The
worker that records one writes the row, then bumps the ``revocations`` generation
(``common/generations.py``) and only then answers; every worker reads that generation before it
trusts its copy of the set, and reads the table again when it moved.  So a token revoked through
one worker is refused by the other from the moment the revoke was answered, and still after a
restart of the gateway.

The set is bounded by the tokens the gateway issued that have not expired.  Should the store be
unwritable (a read-only disk), a revocation is still kept in this worker's memory, logged, and
the revoke is answered 500 ``server_error``: it is not shared nor kept.
"""

from __future__ import annotations

import logging
import sqlite3
import time

from common.generations import Generations

from ..core import accessdb, blocking

log = logging.getLogger("sovd.http.auth")
SLOT = "revocations"


class StoreError(Exception):
    """The revocation could not be written to the store."""


class Revocations:
    def __init__(self, db_path: str, generations: Generations):
        self.db_path = db_path
        self.generations = generations
        self._seen: int | None = None
        self._ids: frozenset[str] = frozenset()
        self._local: set[str] = set()   # revoked here while the store could not be written

    def current(self) -> frozenset[str]:
        """The revoked ids now (read again from the store after any worker revoked one)."""
        generation = self.generations.read(SLOT)
        if generation != self._seen:
            try:
                ids = blocking.run(self._load)
            except (sqlite3.Error, OSError) as exc:
                log.error("revoked tokens: cannot read %s (%s); using the last set read", self.db_path, exc)
            else:
                self._ids = frozenset(ids) | self._local
                self._seen = generation
        return self._ids

    def add(self, jti: str, expires_at: int) -> None:
        """Record a revocation; raises :class:`StoreError` when the store could not keep it."""
        try:
            blocking.run(self._insert, jti, expires_at)
        except (sqlite3.Error, OSError) as exc:
            self._local.add(jti)
            self._ids = self._ids | {jti}
            log.error("revoked tokens: cannot write %s (%s): this revocation holds in this HTTP worker only, "
                      "until it restarts", self.db_path, exc)
            raise StoreError(str(exc)) from None
        self.generations.bump(SLOT)
        self._ids = self._ids | {jti}

    def _load(self) -> list[str]:
        with accessdb.connect(self.db_path) as db:
            return [row[0] for row in db.execute("SELECT jti FROM revoked WHERE expires_at >= ?",
                                                 (int(time.time()),))]

    def _insert(self, jti: str, expires_at: int) -> None:
        with accessdb.connect(self.db_path) as db:
            db.execute("BEGIN IMMEDIATE")
            db.execute("INSERT OR IGNORE INTO revoked (jti, expires_at) VALUES (?, ?)", (jti, expires_at))
            db.execute("DELETE FROM revoked WHERE expires_at < ?", (int(time.time()),))
            db.execute("COMMIT")
