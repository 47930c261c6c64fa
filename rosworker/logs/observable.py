"""Logs as a collection to observe (``core/notifier.py``): every line of an entity's nodes.

Event-driven: the log book calls :meth:`LogObservable.on_line` on each line it
buffers (ROS thread), only while an observer exists, so lines nobody watches
cost one attribute test.  An observer's target is an entity's scope
(``{"nodes": [FQN, ...]}``, ``""``: every line): a line belongs to it when its
logger name is one of the nodes' in slash or dot form (the logs routes' rule,
``book.py`` ``names_of``).  The change handed on is the line as ``GET …/logs``
lists it (medkit's ``entry_to_json``, ``log_manager.cpp``).
"""

from __future__ import annotations

import time
from typing import Any

from ..core.notifier import Observer, ScopedObservable
from .book import LEVELS, Entry, names_of


def entry_json(entry: Entry) -> dict[str, Any]:
    """medkit's ``entry_to_json``: the line as ``GET …/logs`` lists it (``app/logs/routes.py`` ``item``)."""
    context: dict[str, Any] = {"node": entry.name}
    if entry.function:
        context["function"] = entry.function
    if entry.file:
        context["file"] = entry.file
    if entry.line:
        context["line"] = entry.line
    whole = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(entry.sec))
    return {"id": f"log_{entry.id}", "timestamp": f"{whole}.{min(entry.nanosec, 999_999_999):09d}Z",
            "severity": LEVELS.get(entry.level, "debug"), "message": entry.msg, "context": context}


class LogObservable(ScopedObservable):
    def __init__(self, stats: Any):
        super().__init__(stats)
        self.by_logger: dict[str, list[Observer]] = {}   # logger name (slash and dot form) -> its observers
        self.everything: list[Observer] = []              # observers of every line (target "")

    def indexed(self) -> None:
        index: dict[str, list[Observer]] = {}
        everything = []
        for observer in self.observers:
            nodes = self.scope(observer)["nodes"]
            if nodes is None:
                everything.append(observer)
                continue
            for name in {name for fqn in nodes for name in names_of(fqn)}:
                index.setdefault(name, []).append(observer)
        self.by_logger, self.everything = index, everything

    def on_line(self, entry: Entry) -> None:
        """A line the log book buffered (ROS thread)."""
        watchers = self.by_logger.get(entry.name)
        if watchers or self.everything:
            self.notify([*(watchers or ()), *self.everything], entry_json(entry), time.time_ns())
