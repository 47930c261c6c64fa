"""The nodes' parameter defaults, told apart by each node's start (ROS thread only).

ROS 2 has no "default" service.  The first time an operation reaches a node,
its parameters are read and kept as that node's record (``commands.py``),
keyed by the node's start: the GIDs of its ``/parameter_events`` publishers in
the graph (:meth:`Defaults.start_keys`), so a restarted node is a new record.
A stopped start can linger in the graph beside the new one for a while, so a
record (or a negative-cache entry, ``clients.py``) made with some set of GIDs
holds while the graph shows none outside it.  A parameter first seen later
(declared later: its ``/parameter_events`` "new" entry, or first read) joins
the record with the value it had then.  Reset sets the recorded value back.
At most ``MAX_RECORDS`` nodes are kept (the oldest record goes first).

One ``/parameter_events`` subscription, read with ``take``
(:meth:`Defaults.drain`) before each operation, on every idle sweep and at
each tick of a parameter feed, keeps the records of parameters declared later
and hands every message to the ``listeners`` (the parameter feeds,
``feed.py``).  Values themselves are never cached, so a change made elsewhere
shows on the next read.
"""

from __future__ import annotations

import collections
from collections.abc import Callable
from typing import Any

from rcl_interfaces.msg import ParameterEvent, ParameterValue
from rclpy.qos import qos_profile_parameter_events

from ..core.stats import Stats

EVENTS_TOPIC = "/parameter_events"
EVENTS_PER_DRAIN = 1000      # parameter events taken at most per look (the rest wait for the next)
MAX_RECORDS = 4096           # nodes whose defaults are kept (the oldest record goes first)


class Record:
    """One start of a node (``key``: its start keys) and the first value seen of each of its parameters."""

    __slots__ = ("key", "values")

    def __init__(self, key: Any):
        self.key = key
        self.values: dict[str, ParameterValue] = {}


class Defaults:
    """The records of the nodes' defaults and the ``/parameter_events`` subscription that keeps them."""

    def __init__(self, node, stats: Stats):
        self.node = node
        self.stats = stats
        self.records: collections.OrderedDict[str, Record] = collections.OrderedDict()
        # cyclic subscriptions on parameters (feed.py): called with each /parameter_events message
        self.listeners: list[Callable[[Any], None]] = []
        self._events = None

    def start_keys(self, fqn: str) -> frozenset:
        """Which starts of the node are in the graph: the GIDs of their /parameter_events publishers (a
        stopped start can linger beside the new one for a while).  A record or a negative-cache entry
        made with some set holds while the graph shows no GID outside it."""
        namespace, _, name = fqn.rpartition("/")
        namespace = namespace or "/"
        try:
            infos = self.node.get_publishers_info_by_topic(EVENTS_TOPIC)
        except Exception:
            return frozenset()
        return frozenset(tuple(info.endpoint_gid) for info in infos
                         if info.node_name == name and info.node_namespace == namespace)

    def keep(self, fqn: str, key: frozenset, read: tuple[list[str], list[ParameterValue]]) -> Record:
        """A new record of the node's start ``key``, of the values ``read`` (names, values)."""
        record = Record(key)
        record.values.update(zip(*read, strict=True))
        self.records[fqn] = record
        while len(self.records) > MAX_RECORDS:
            self.records.popitem(last=False)
        return record

    def drain(self) -> None:
        """Take the /parameter_events messages that came: parameters declared since join their node's
        record with the value they were declared with; every message goes to the listeners."""
        if self._events is None:
            self._events = self.node.create_subscription(ParameterEvent, EVENTS_TOPIC, lambda _msg: None,
                                                         qos_profile_parameter_events)
        for _ in range(EVENTS_PER_DRAIN):
            taken = self._events.handle.take_message(ParameterEvent, False)
            if taken is None:
                return
            event = taken[0]
            self.stats.parameter_events += 1
            for listener in self.listeners:  # cyclic subscriptions on parameters (feed.py)
                listener(event)
            record = self.records.get(event.node)
            if record is None or not event.new_parameters:
                continue
            if not self.start_keys(event.node) <= record.key:
                continue  # another start's record
            for p in event.new_parameters:
                record.values.setdefault(p.name, p.value)
