"""The triggers' table of the state directory's store (``core/store.py``, ``faults.db``).

One row per trigger, its record as a JSON document (``registry.py``'s
``Trigger.record``): a change writes that one row, never the whole set, and a
command that changed a trigger is answered once its row is written (``then``).
A restarted ROS worker restores them all; a new gateway only the ``persistent``
ones (the others' rows are deleted).  A ``triggers.json`` left by an older
gateway is imported once (and renamed ``triggers.json.imported``).
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from typing import Any

from ipc import protocol

from ..core.store import Store, Table

log = logging.getLogger("sovd.rosworker.triggers")

LEGACY_FILE = "triggers.json"    # an older gateway's store: imported once
LEGACY_MAX_BYTES = 64 * 2**20    # a larger one is not read
MAX_LIFETIME = 2**31 - 1

TRIGGERS = Table(
    "triggers", "CREATE TABLE IF NOT EXISTS triggers (id TEXT PRIMARY KEY, doc TEXT NOT NULL)",
    upsert="INSERT OR REPLACE INTO triggers (id, doc) VALUES (?, ?)", delete="DELETE FROM triggers WHERE id = ?",
    select="SELECT id, doc FROM triggers")


class TriggerStore:
    def __init__(self, store: Store, legacy_path: str = ""):
        self._table = store.table(TRIGGERS)
        self.legacy_path = legacy_path

    def rows(self) -> list[tuple[str, Any]]:
        """``(id, record)`` of every stored trigger, the record None when it is not JSON (start-up)."""
        return [(str(trigger_id), record) for trigger_id, record in self._table.rows()]

    def put(self, trigger_id: str, record: bytes | None, then: Callable[[], None] | None = None) -> None:
        """Write one trigger's record (None: delete it); ``then()`` on the ROS thread once it is written."""
        self._table.put(trigger_id, record, then)

    def legacy(self) -> list[dict[str, Any]]:
        """The triggers of an older gateway's ``triggers.json``, read once (the file is then renamed)."""
        path = self.legacy_path
        try:
            if not path or not os.path.isfile(path) or os.path.getsize(path) > LEGACY_MAX_BYTES:
                return []
            with open(path, "rb") as fh:
                data = json.loads(fh.read())
            os.replace(path, path + ".imported")
        except (OSError, ValueError) as exc:
            log.warning("could not import the triggers of %s: %s", path, exc)
            return []
        items = data.get("triggers") if isinstance(data, dict) else None
        found = [t for t in items if isinstance(t, dict)] if isinstance(items, list) else []
        log.info("imported %d triggers from %s (now %s.imported)", len(found), path, path)
        return found


def valid_record(fields: dict[str, Any]) -> bool:
    """A stored trigger's fields have the types a created one has (the file may have been edited)."""
    strings = ("id", "collection", "entity_id", "resource", "source", "target", "bytes", "path", "client")
    lifetime = fields["lifetime"]
    return (all(isinstance(fields[name], str) for name in strings) and fields["id"].startswith("trig_")
            and fields["bytes"] in protocol.BYTES_MODES
            and all(isinstance(fields[name], bool) for name in ("multishot", "persistent"))
            and isinstance(fields["created_at_ns"], int)
            and (lifetime is None or (isinstance(lifetime, int) and not isinstance(lifetime, bool)
                                      and 0 < lifetime <= MAX_LIFETIME)))
