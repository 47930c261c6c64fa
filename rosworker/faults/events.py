"""The faults' events: ``fault_confirmed``, ``fault_updated``, ``fault_cleared`` (ROS thread only).

The fault manager (``manager.py``) makes one on each change of a confirmed
fault.  Their ids never go backwards: a start's ids begin at its epoch (the
wall clock in microseconds, or the last stored id + 1 if that is higher) and
count up by one, so a new start's ids are above every earlier one's even when
the store is in memory only (an unwritable state dir, a corrupt file moved
aside).  They stay plain integers (the SSE ``id:``, ``Last-Event-ID``).  The
last ``MAX_EVENTS`` are kept (also in the store, ``store.py``) for
``Last-Event-ID`` replay; each is published on the events channel
(``ipc/events.py``, key ``f|``) for the HTTP workers' fault streams, and the
observers of ``faults`` (triggers, ``observable.py``) are told of it.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from typing import Any

from ipc import events as channel
from ipc import protocol

from .model import public
from .observable import FaultObservable
from .store import MAX_EVENTS, FaultTables


class FaultEvents:
    """The events kept for replay and the id of the next one."""

    def __init__(self, executor, store: FaultTables, send: Callable[[list[bytes]], None],
                 observable: FaultObservable):
        self.executor = executor
        self.store = store
        self.send = send
        self.observable = observable
        self.kept: collections.deque[tuple[int, dict[str, Any]]] = collections.deque(maxlen=MAX_EVENTS)
        self.next_id = 1

    def load(self, events: list[tuple[int, dict[str, Any]]]) -> None:
        """The stored events (oldest first); this start's ids begin above them and at its epoch."""
        for event_id, event in events:
            self.kept.append((event_id, event))
        # The ids of this start begin at its epoch (wall clock, µs), above every id of an earlier
        # start: a stream that stays open across a ROS worker restart, or a client that reconnects with
        # Last-Event-ID, never takes a new event for one it has (a store in memory only keeps no ids).
        self.next_id = max(time.time_ns() // 1000, self.kept[-1][0] + 1 if self.kept else 1)

    def add(self, event_type: str, record: dict[str, Any]) -> None:
        """A new event of the fault ``record``: kept, stored, published and observed."""
        event_id = self.next_id
        self.next_id += 1
        event = {"event_type": event_type, "fault": public(record), "timestamp": time.time()}
        self.kept.append((event_id, event))
        self.store.event(event_id, event)
        self.send([channel.FAULT_KEY, protocol.pack({"id": event_id, **event})])
        if self.observable.observers:  # faults triggers: evaluated on the event, nothing when none watches
            self.executor.guarded("the faults triggers", self.observable.on_fault, event_type, event["fault"])

    def after(self, after: int) -> list[dict[str, Any]]:
        """The kept events with an id above ``after`` (``Last-Event-ID``), oldest first."""
        return [{"id": i, **e} for i, e in self.kept if i > after]
