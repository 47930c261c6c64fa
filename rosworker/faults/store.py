"""The faults' tables of the state directory's store (``core/store.py``, ``faults.db``).

- ``faults``: one row per fault code, its record as a JSON document
  (``manager.py`` owns the record's fields), stamped with the write's time;
- ``events``: the fault stream's last ``MAX_EVENTS`` events by id, so that a
  client reconnecting with ``Last-Event-ID`` is answered from here, even after
  a restart.

The ROS thread only hands rows over (:meth:`FaultTables.put`,
:meth:`FaultTables.event`); the store's writer thread writes them (a burst of
changes to one fault is one row write).
"""

from __future__ import annotations

import logging
from typing import Any

from ..core.store import Store, Table

log = logging.getLogger("sovd.rosworker.faults")

MAX_EVENTS = 1000          # events kept for Last-Event-ID replay

FAULTS = Table(
    "faults", "CREATE TABLE IF NOT EXISTS faults (code TEXT PRIMARY KEY, doc TEXT NOT NULL, updated_ns INTEGER NOT NULL)",
    upsert="INSERT INTO faults (code, doc, updated_ns) VALUES (?, ?, ?) ON CONFLICT(code) "
           "DO UPDATE SET doc = excluded.doc, updated_ns = excluded.updated_ns",
    delete="DELETE FROM faults WHERE code = ?", select="SELECT code, doc FROM faults", stamped=True)
EVENTS = Table(
    "events", "CREATE TABLE IF NOT EXISTS events (id INTEGER PRIMARY KEY, doc TEXT NOT NULL)",
    upsert="INSERT OR REPLACE INTO events (id, doc) VALUES (?, ?)", delete="DELETE FROM events WHERE id = ?",
    select=f"SELECT id, doc FROM events ORDER BY id DESC LIMIT {MAX_EVENTS}", keep=MAX_EVENTS,
    trim="DELETE FROM events WHERE id <= ?")


class FaultTables:
    """The faults and their events in the store; what /health says of the store."""

    def __init__(self, store: Store):
        self.store = store
        self._faults = store.table(FAULTS)
        self._events = store.table(EVENTS)

    def load(self) -> tuple[dict[str, dict[str, Any]], list[tuple[int, dict[str, Any]]]]:
        """The stored faults and events (oldest first): start-up, on the ROS thread."""
        faults = {str(code): record for code, record in self._faults.rows() if isinstance(record, dict)}
        events = [(int(i), e) for i, e in reversed(self._events.rows()) if isinstance(e, dict)]
        if self.store.enabled:
            log.info("fault store %s: %d faults, %d events", self.store.path, len(faults), len(events))
        return faults, events

    def put(self, code: str, record: dict[str, Any] | None) -> None:
        """Write ``record`` as the fault ``code`` (None: delete it), soon, on the writer thread."""
        self._faults.put(code, record)

    def event(self, event_id: int, event: dict[str, Any]) -> None:
        self._events.put(event_id, event)

    @property
    def path(self) -> str:
        return self.store.path
