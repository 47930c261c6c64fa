"""The logs family: the robot's ``/rosout`` as SOVD logs (ring buffers per node, memory only).

- ``book.py``: the subscription, the buffers, the entities' configurations, and the commands
  ``logs``, ``log_config_get``, ``log_config_set``;
- ``observable.py``: the ``logs`` collection for observers (triggers: every line of an entity).
"""

from __future__ import annotations

from ..core.family import Core, Family
from .book import LogBook


class Logs(Family):
    name = "logs"

    def start(self, core: Core) -> None:
        cfg = core.cfg
        self.book = book = LogBook(core.node, core.executor, core.stats, buffer_size=cfg.log_buffer_size,
                                   max_bytes=cfg.log_max_bytes, max_nodes=cfg.log_max_nodes)
        core.executor.guarded("subscribing to /rosout", book.start)
        core.notifier.provide("logs", book.observable)
        self.commands = book.handlers

    def shutdown(self) -> None:
        self.book.shutdown()


FAMILY = Logs()
