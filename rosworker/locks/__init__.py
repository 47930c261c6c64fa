"""The locks family: SOVD locks (ISO 17978-3 §7.17), held by the ROS worker so that every HTTP worker
agrees on them (``table.py``: the table, its commands, its file under the runtime dir, its counters).

A restarted ROS worker takes the table back from its file (``restart``); a new gateway starts with none.
"""

from __future__ import annotations

from ..core.family import Core, Family
from .table import FILE_NAME, LockTable

__all__ = ["FILE_NAME", "FAMILY", "LockTable"]


class Locks(Family):
    name = "locks"

    def start(self, core: Core) -> None:
        cfg = core.cfg
        self.table = LockTable(cfg.runtime_dir, core.stats, max_locks=cfg.max_locks,
                               max_expiration=cfg.locking_default_max_expiration,
                               cleanup_interval=cfg.locking_cleanup_interval, call_later=core.executor.call_later,
                               restore=bool(core.restart))
        self.table.start()
        self.commands = self.table.commands

    def shutdown(self) -> None:
        self.table.shutdown()


FAMILY = Locks()
