"""The per-topic subscription pool: one subscription per topic, newest sample on demand.

Every method runs on the ROS thread.  A pooled topic costs nothing between
reads: there is no callback; a read takes the newest raw sample out of the
subscription (depth 1) and converts it only if it is newer than the one
already converted, so every reader of the same message shares one JSON text.

A read of a topic whose first message has not arrived yet (cold) parks the
caller as a *waiter* until the message arrives, the entry is evicted, or
its deadline passes.  At most ``cold_wait_cap`` callers wait at once; the
rest are told to retry (503) at once.

Evictions: graph change (no publisher left, or the type changed), LRU at
the cap, idle sweep, manual (``evict``), shutdown.  Each wakes the entry's
waiters (they get metadata_only) and destroys the subscription here, on the
ROS thread.
"""

from __future__ import annotations

import collections
import logging
import time
from typing import Any

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.serialization import deserialize_message

from ipc.errors import IpcError

from . import convert, qos
from .executor import RosExecutor, Task, Timer
from .stats import Stats

log = logging.getLogger("sovd.rosworker.pool")

UNSUPPORTED_TYPES_CAP = 1024
LAST_TYPES_CAP = 4096
BYTES_MODES = ("array", "base64")


class Waiter:
    __slots__ = ("task", "mode", "timer")

    def __init__(self, task: Task, mode: str, timer: Timer):
        self.task = task
        self.mode = mode
        self.timer = timer


class Entry:
    """One pooled topic."""

    __slots__ = ("topic", "type_name", "cls", "sub", "qos_key", "raw", "received_ns", "json",
                 "waiters", "last_read", "matched", "publisher_count", "subscriber_count",
                 "incompatible")

    def __init__(self, topic: str, type_name: str, cls: type):
        self.topic = topic
        self.type_name = type_name
        self.cls = cls
        self.sub = None
        self.qos_key: tuple | None = None
        self.raw: bytes | None = None
        self.received_ns = 0
        self.json: dict[str, bytes] = {}
        self.waiters: list[Waiter] = []
        self.last_read = time.monotonic()
        self.matched = 0
        self.publisher_count = 0
        self.subscriber_count = 0
        self.incompatible = False


class TopicPool:
    def __init__(self, node, executor: RosExecutor, stats: Stats, *, max_pool_size: int,
                 cold_wait_cap: int, idle_safety_net: float):
        self.node = node
        self.executor = executor
        self.stats = stats
        self.max_pool_size = max_pool_size
        self.cold_wait_cap = cold_wait_cap
        self.idle_safety_net = idle_safety_net
        self.entries: collections.OrderedDict[str, Entry] = collections.OrderedDict()
        self.cold: dict[str, Entry] = {}           # entries with waiters
        self.unsupported: collections.OrderedDict[str, None] = collections.OrderedDict()
        self.last_types: collections.OrderedDict[str, str] = collections.OrderedDict()
        self.closing = False
        executor.cold_entries = lambda: list(self.cold.values())
        executor.on_ready = self._on_ready

    # ---- reads --------------------------------------------------------------------------
    def sample(self, task: Task, topic: str, timeout: float, mode: str) -> None:
        if self.closing:
            task.reply(self._metadata(topic, None, "shutdown"))
            return
        entry = self.entries.get(topic)
        if entry is not None:
            self.stats.pool_hits += 1
            self.entries.move_to_end(topic)
        else:
            self.stats.pool_misses += 1
            entry, reason = self._create(topic)
            if entry is None:
                task.reply(self._metadata(topic, None, reason))
                return
        entry.last_read = time.monotonic()
        self._take(entry)
        if entry.raw is not None:
            task.reply(self._data(entry, mode))
            return
        self._park(task, entry, mode, timeout)

    def subscribe(self, topic: str) -> dict[str, Any]:
        entry = self.entries.get(topic)
        if entry is None:
            entry, reason = self._create(topic)
            if entry is None:
                return {"topic": topic, "type": None, "status": reason}
        return {"topic": topic, "type": entry.type_name, "status": "pooled"}

    def _park(self, task: Task, entry: Entry, mode: str, timeout: float) -> None:
        cap = self.cold_wait_cap
        if cap and self.stats.concurrent_cold_waits >= cap:
            raise IpcError(
                "cold-wait-cap-exceeded",
                f"Too many callers already wait for a first message ({cap}); retry with backoff",
                {"topic": entry.topic, "cold_wait_cap": cap},
            )
        wait = min(timeout, task.deadline - time.monotonic() - 0.05)
        waiter = Waiter(task, mode, None)  # type: ignore[arg-type]
        waiter.timer = self.executor.call_later(max(0.0, wait), lambda: self._expire(entry, waiter))
        entry.waiters.append(waiter)
        self.cold[entry.topic] = entry
        self.stats.concurrent_cold_waits += 1

    def _expire(self, entry: Entry, waiter: Waiter) -> None:
        if waiter in entry.waiters:
            self._release(entry, waiter)
            waiter.task.reply(self._metadata(entry.topic, entry, "timeout"))

    def _release(self, entry: Entry, waiter: Waiter) -> None:
        entry.waiters.remove(waiter)
        waiter.timer.cancel()
        self.stats.concurrent_cold_waits -= 1
        if not entry.waiters:
            self.cold.pop(entry.topic, None)

    def _on_ready(self, entry: Entry) -> None:
        self._take(entry)
        if entry.raw is None:
            return
        for waiter in list(entry.waiters):
            self._release(entry, waiter)
            waiter.task.reply(self._data(entry, waiter.mode))

    def _take(self, entry: Entry) -> None:
        taken = entry.sub.handle.take_message(entry.cls, True)
        if taken is not None:
            raw, info = taken
            entry.raw = raw
            entry.received_ns = info.get("received_timestamp") or time.time_ns()
            entry.json.clear()

    # ---- answers ------------------------------------------------------------------------
    def _data(self, entry: Entry, mode: str) -> dict[str, Any]:
        text = entry.json.get(mode)
        if text is None:
            msg = deserialize_message(entry.raw, entry.cls)
            text = convert.to_json(msg, mode)
            entry.json[mode] = text
        return {"topic": entry.topic, "type": entry.type_name, "status": "data", "data_json": text,
                "timestamp": entry.received_ns, "publisher_count": entry.publisher_count,
                "subscriber_count": entry.subscriber_count}

    def _metadata(self, topic: str, entry: Entry | None, reason: str, type_name: str | None = None,
                  counts: tuple[int, int] | None = None) -> dict[str, Any]:
        if entry is not None:
            type_name = entry.type_name
            counts = (entry.publisher_count, entry.subscriber_count)
        elif counts is None:
            counts = (self.node.count_publishers(topic), self.node.count_subscribers(topic))
        return {"topic": topic, "type": type_name, "status": "metadata_only", "data_json": b"{}",
                "timestamp": time.time_ns(), "publisher_count": counts[0],
                "subscriber_count": counts[1], "reason": reason}

    # ---- creation -----------------------------------------------------------------------
    def _create(self, topic: str) -> tuple[Entry | None, str]:
        infos = self.node.get_publishers_info_by_topic(topic)
        if not infos:
            in_graph = self.node.count_subscribers(topic) > 0
            return None, ("no-publishers" if in_graph else "not-in-graph")
        types = collections.Counter(i.topic_type for i in infos)
        type_name = types.most_common(1)[0][0]
        if type_name in self.unsupported:
            return None, "unsupported-type"
        try:
            cls = convert.load_type(type_name)
        except convert.ConversionError:
            self._mark_unsupported(type_name)
            return None, "unsupported-type"
        previous = self.last_types.get(topic)
        if previous is not None and previous != type_name:
            self.stats.type_change_events += 1
        self._remember_type(topic, type_name)
        entry = Entry(topic, type_name, cls)
        entry.publisher_count = len(infos)
        entry.subscriber_count = self.node.count_subscribers(topic)
        self._subscribe(entry, [i for i in infos if i.topic_type == type_name])
        if len(self.entries) >= self.max_pool_size:
            _, oldest = next(iter(self.entries.items()))
            self.evict(oldest, "lru")
        self.entries[topic] = entry
        self.stats.pool_size = len(self.entries)
        return entry, "pooled"

    def _subscribe(self, entry: Entry, infos: list) -> None:
        profile = qos.match_qos(infos)

        def incompatible(_event, entry=entry):
            entry.incompatible = True

        try:
            entry.sub = self.node.create_subscription(
                entry.cls, entry.topic, _never_called, profile,
                event_callbacks=SubscriptionEventCallbacks(incompatible_qos=incompatible,
                                                           use_default_callbacks=False),
            )
        except Exception as exc:
            log.warning("subscribing to %s failed: %s", entry.topic, exc)
            raise IpcError("subscribe-failed", f"Could not subscribe to {entry.topic}: {exc}",
                           {"topic": entry.topic}) from None
        entry.qos_key = qos.key(profile)
        entry.matched = entry.sub.handle.get_publisher_count()
        entry.incompatible = False
        log.debug("subscribed %s [%s] %s", entry.topic, entry.type_name, qos.describe(profile))

    def _mark_unsupported(self, type_name: str) -> None:
        if type_name not in self.unsupported:
            log.warning("message type %s is not installed: its topics are served as metadata only",
                        type_name)
            self.unsupported[type_name] = None
            self.stats.unsupported_type_count += 1
            if len(self.unsupported) > UNSUPPORTED_TYPES_CAP:
                self.unsupported.popitem(last=False)

    def _remember_type(self, topic: str, type_name: str) -> None:
        self.last_types[topic] = type_name
        self.last_types.move_to_end(topic)
        if len(self.last_types) > LAST_TYPES_CAP:
            self.last_types.popitem(last=False)

    # ---- evictions ----------------------------------------------------------------------
    def evict(self, entry: Entry, reason: str) -> None:
        if self.entries.get(entry.topic) is not entry:
            return
        del self.entries[entry.topic]
        self.stats.pool_size = len(self.entries)
        self.stats.evictions_total += 1
        self.stats.evictions[reason] = self.stats.evictions.get(reason, 0) + 1
        for waiter in list(entry.waiters):
            self._release(entry, waiter)
            waiter.task.reply(self._metadata(entry.topic, entry,
                                             "shutdown" if reason == "shutdown" else "evicted"))
        self._destroy(entry)
        log.debug("evicted %s (%s)", entry.topic, reason)

    def _destroy(self, entry: Entry) -> None:
        if entry.sub is not None:
            try:
                self.node.destroy_subscription(entry.sub)
            except Exception:
                log.exception("destroying the subscription of %s failed", entry.topic)
            entry.sub = None

    def evict_topic(self, topic: str) -> bool:
        entry = self.entries.get(topic)
        if entry is None:
            return False
        self.evict(entry, "manual")
        return True

    def sweep_idle(self) -> None:
        if not self.idle_safety_net:
            return
        limit = time.monotonic() - self.idle_safety_net
        for entry in [e for e in self.entries.values() if e.last_read < limit and not e.waiters]:
            self.evict(entry, "idle")

    def check_graph(self, publisher_types: dict[str, collections.Counter] | None, full: bool) -> None:
        """Re-check pooled topics against the graph.

        ``full``: every entry is re-checked (the graph changed, or the periodic
        sweep); otherwise only entries whose matched-publisher count changed or
        that saw an incompatible-QoS event.
        """
        for entry in list(self.entries.values()):
            matched = entry.sub.handle.get_publisher_count()
            if not (full or matched != entry.matched or entry.incompatible):
                continue
            entry.matched = matched
            infos = self.node.get_publishers_info_by_topic(entry.topic)
            if not infos:
                self.evict(entry, "graph")
                continue
            types = {i.topic_type for i in infos}
            if entry.type_name not in types:
                self.stats.type_change_events += 1
                self._remember_type(entry.topic, next(iter(types)))
                self.evict(entry, "type_change")
                continue
            entry.publisher_count = len(infos)
            entry.subscriber_count = max(0, self.node.count_subscribers(entry.topic) - 1)
            same_type = [i for i in infos if i.topic_type == entry.type_name]
            wanted = qos.key(qos.match_qos(same_type))
            if wanted != entry.qos_key or entry.incompatible:
                self._rebuild(entry, same_type)

    def _rebuild(self, entry: Entry, infos: list) -> None:
        """Recreate the subscription with QoS matched to the current publishers."""
        log.info("re-subscribing %s with QoS matched to its publishers%s", entry.topic,
                 " (incompatible QoS reported)" if entry.incompatible else "")
        self.stats.evictions["qos_rebuild"] += 1
        self._destroy(entry)
        self._subscribe(entry, infos)

    def shutdown(self) -> None:
        for entry in list(self.entries.values()):
            self.evict(entry, "shutdown")


def _never_called(_msg) -> None:  # pragma: no cover - pooled subscriptions are never spun
    pass
