"""The per-topic subscription pool: one subscription per topic, newest sample on demand.

Every method runs on the ROS thread.  A pooled topic costs nothing between
reads: there is no callback; a read takes the newest raw sample out of the
subscription (depth 1) and converts it only if it is newer than the one
already converted, so every reader of the same message shares one JSON text.

A read of a topic whose first message has not arrived yet (cold) parks the
caller as a *waiter* until the message arrives, the entry is evicted, or
its deadline passes.  At most ``cold_wait_cap`` callers wait at once; the
rest are told to retry (503) at once, before their topic is pooled (a refused
read evicts nothing).

A message that cannot be decoded (bad CDR, or a robot built against another
version of the message package) answers its readers ``message-undecodable``
(502) naming the topic and type; it is counted, logged once per topic, and
the topic is left out of the restart state, so a restarted worker does not
subscribe to it again by itself.

Memory is bounded twice: ``max_pool_size`` topics, and ``max_pool_bytes`` of
kept messages (the raw message plus its JSON per byte-array mode).  Past the
byte budget the cached JSON of the least recently read entries goes first,
then whole entries.

The gateway's own endpoints (its subscriptions here, its publishers for PUT)
never count as a topic's publishers or subscribers (``core/endpoints.py``).

A topic the gateway records for its faults (``rosworker/bulk_data/recorder.py``) is not
subscribed twice: ``shared_subscription`` (the recorder's hook, None when nothing is
recorded) gives the recorded subscription, which an entry reads through as through its
own (its ``take_message`` drains the recording's queue and hands over the newest message
not taken yet).  The recorder owns it: the pool never re-subscribes or destroys it
(:meth:`TopicPool.adopt`, :meth:`TopicPool.unshare`).

Evictions: graph change (no publisher left, or the type changed), LRU at
the cap (never an entry somebody waits on: when every entry has waiters, a
new topic is refused with ``pool-busy``), the byte budget, idle sweep,
manual (``evict``), shutdown.  Each wakes the entry's waiters (they get
metadata_only) and destroys the subscription here, on the ROS thread.
"""

from __future__ import annotations

import collections
import logging
import time
from collections.abc import Callable
from typing import Any

from rclpy.serialization import deserialize_message

from ipc.errors import IpcError

from ..core.endpoints import Endpoints
from ..core.executor import RosExecutor
from ..core.stats import Stats
from ..core.task import Task, Timer
from ..ros import msgtypes, qos
from ..ros.encode import to_json

log = logging.getLogger("sovd.rosworker.pool")

UNSUPPORTED_TYPES_CAP = 1024
LAST_TYPES_CAP = 4096
UNDECODABLE_CAP = 4096


class Waiter:
    __slots__ = ("task", "mode", "timer")

    def __init__(self, task: Task, mode: str, timer: Timer):
        self.task = task
        self.mode = mode
        self.timer = timer


class Entry:
    """One pooled topic."""

    __slots__ = ("topic", "type_name", "cls", "sub", "profile", "raw", "received_ns", "json",
                 "failure", "nbytes", "waiters", "last_read", "matched", "publisher_count",
                 "subscriber_count")

    def __init__(self, topic: str, type_name: str, cls: type):
        self.topic = topic
        self.type_name = type_name
        self.cls = cls
        self.sub = None
        self.profile = None                    # the QoSProfile of ``sub``
        self.raw: bytes | None = None
        self.received_ns = 0
        self.json: dict[str, bytes] = {}
        self.failure: IpcError | None = None   # the newest raw message could not be decoded
        self.nbytes = 0                        # raw + cached JSON, counted in the byte budget
        self.waiters: list[Waiter] = []
        self.last_read = time.monotonic()
        self.matched = 0
        self.publisher_count = 0
        self.subscriber_count = 0


class TopicPool:
    def __init__(self, node, executor: RosExecutor, stats: Stats, *, max_pool_size: int,
                 cold_wait_cap: int, idle_safety_net: float, max_pool_bytes: int = 256 * 2**20,
                 endpoints: Endpoints | None = None):
        self.node = node
        self.endpoints = endpoints or Endpoints(node)
        self.executor = executor
        self.stats = stats
        self.max_pool_size = max_pool_size
        self.max_pool_bytes = max_pool_bytes
        self.cold_wait_cap = cold_wait_cap
        self.idle_safety_net = idle_safety_net
        self.entries: collections.OrderedDict[str, Entry] = collections.OrderedDict()
        self.cold: dict[str, Entry] = {}           # entries with waiters
        self.unsupported: collections.OrderedDict[str, None] = collections.OrderedDict()
        self.last_types: collections.OrderedDict[str, str] = collections.OrderedDict()
        self.undecodable: collections.OrderedDict[str, str] = collections.OrderedDict()  # topic -> type
        self.nbytes = 0
        self.closing = False
        # (topic, type or None) -> the recorded subscription of that topic, or None (rosworker/bulk_data/)
        self.shared_subscription: Callable[[str, str | None], Any] | None = None
        stats.pool_bytes_cap = max_pool_bytes

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
            # A new entry has no message yet, so this reader will wait: shed it before the
            # entry evicts a pooled topic and subscribes (see _create).
            entry, reason = self._create(topic, waiter=True)
            if entry is None:
                task.reply(self._metadata(topic, None, reason))
                return
        entry.last_read = time.monotonic()
        self._take(entry)
        if entry.raw is not None:
            task.reply(self._data(entry, mode))
            return
        self._park(task, entry, mode, timeout)

    def peek(self, topic: str, mode: str) -> dict[str, Any] | None:
        """What a read would answer now, without waiting (a stream's tick); None: no first message yet.

        Not counted as a hit or miss: those count reads.  Raises IpcError as ``_data`` does.
        """
        if self.closing:
            return self._metadata(topic, None, "shutdown")
        entry = self.entries.get(topic)
        if entry is None:
            entry, reason = self._create(topic)
            if entry is None:
                return self._metadata(topic, None, reason)
        else:
            self.entries.move_to_end(topic)
        entry.last_read = time.monotonic()
        self._take(entry)
        return None if entry.raw is None else self._data(entry, mode)

    def absent(self, topic: str) -> dict[str, Any]:
        """The answer for a topic the graph does not list at all (the graph monitor's last poll)."""
        return {"topic": topic, "type": None, "status": "metadata_only", "data_json": b"{}",
                "timestamp": time.time_ns(), "publisher_count": 0, "subscriber_count": 0,
                "reason": "not-in-graph"}

    def waiting(self, topic: str) -> dict[str, Any]:
        """The answer for a pooled topic whose first message did not come in time."""
        return self._metadata(topic, self.entries.get(topic), "timeout")

    def subscribe(self, topic: str) -> dict[str, Any]:
        entry = self.entries.get(topic)
        if entry is None:
            entry, reason = self._create(topic)
            if entry is None:
                return {"topic": topic, "type": None, "status": reason}
        return {"topic": topic, "type": entry.type_name, "status": "pooled"}

    def own_subscription_qos(self, topic: str):
        """The QoSProfile of the gateway's subscription to ``topic`` (the pool's, or the recorded one), or None."""
        entry = self.entries.get(topic)
        if entry is not None and entry.sub is not None and entry.profile is not None:
            return entry.profile
        shared = self.shared_subscription(topic, None) if self.shared_subscription is not None else None
        return shared.profile if shared is not None else None

    def restart_topics(self) -> list[str]:
        """Pooled topics worth subscribing to again after a restart: not the undecodable ones."""
        return [t for t, e in self.entries.items() if e.failure is None and t not in self.undecodable]

    def _check_cold_wait_cap(self, topic: str) -> None:
        cap = self.cold_wait_cap
        if cap and self.stats.concurrent_cold_waits >= cap:
            raise IpcError(
                "cold-wait-cap-exceeded",
                f"Too many callers already wait for a first message ({cap}); retry with backoff",
                {"topic": topic, "cold_wait_cap": cap},
            )

    def _park(self, task: Task, entry: Entry, mode: str, timeout: float) -> None:
        self._check_cold_wait_cap(entry.topic)
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

    def cold_entries(self) -> list[Entry]:
        """The entries callers wait on (the executor looks at each when one is ready: on_ready)."""
        return list(self.cold.values())

    def cold_waitables(self) -> list:
        """The subscriptions of the entries callers wait on (a recorded topic's: the recorder's)."""
        if not self.cold:
            return []
        subs = (getattr(entry.sub, "waitable", entry.sub) for entry in self.cold.values())
        return [sub for sub in subs if sub is not None]

    def on_ready(self, entry: Entry) -> None:
        """A look at a cold entry (executor, when a waited subscription is ready)."""
        if entry.sub is None:
            return
        self._take(entry)
        if entry.raw is None:
            return
        for waiter in list(entry.waiters):
            self._release(entry, waiter)
            try:
                waiter.task.reply(self._data(entry, waiter.mode))
            except IpcError as exc:
                waiter.task.fail(exc)

    def _take(self, entry: Entry) -> None:
        taken = entry.sub.handle.take_message(entry.cls, True)
        if taken is not None:
            raw, info = taken
            self._account(entry, -entry.nbytes)
            entry.raw = raw
            entry.received_ns = info.get("received_timestamp") or time.time_ns()
            entry.json.clear()
            entry.failure = None
            self._account(entry, len(raw))
            self._enforce_budget(entry)

    # ---- answers ------------------------------------------------------------------------
    def _data(self, entry: Entry, mode: str) -> dict[str, Any]:
        text = entry.json.get(mode)
        if text is None:
            if entry.failure is not None:
                raise entry.failure
            text = self._convert(entry, mode)
            entry.json[mode] = text
            self._account(entry, len(text))
            self._enforce_budget(entry)
        return {"topic": entry.topic, "type": entry.type_name, "status": "data", "data_json": text,
                "timestamp": entry.received_ns, "publisher_count": entry.publisher_count,
                "subscriber_count": entry.subscriber_count}

    def _convert(self, entry: Entry, mode: str) -> bytes:
        try:
            return to_json(deserialize_message(entry.raw, entry.cls), mode)
        except Exception as exc:  # rclpy raises several types for bad CDR; convert its own
            self.stats.undecodable_messages += 1
            if entry.topic not in self.undecodable:
                log.warning("a message on %s [%s] cannot be decoded (%s: %s); its readers get 502 "
                            "until a decodable message arrives", entry.topic, entry.type_name,
                            type(exc).__name__, str(exc)[:200])
            self.undecodable[entry.topic] = entry.type_name
            self.undecodable.move_to_end(entry.topic)
            if len(self.undecodable) > UNDECODABLE_CAP:
                self.undecodable.popitem(last=False)
            entry.failure = IpcError(
                "message-undecodable",
                f"The newest message on {entry.topic} cannot be decoded as {entry.type_name}: the "
                "publisher may be built against another version of the message package",
                {"topic": entry.topic, "type": entry.type_name},
            )
            raise entry.failure from None

    def _metadata(self, topic: str, entry: Entry | None, reason: str) -> dict[str, Any]:
        if entry is not None:
            type_name = entry.type_name
            counts = (entry.publisher_count, entry.subscriber_count)
        else:
            # The type comes from the graph whatever the endpoint kind (as medkit's does): a
            # command input with subscribers only still says what to PUT to it.
            pubs = self.endpoints.publishers(topic)
            subs = self.endpoints.subscribers(topic)
            types = collections.Counter(i.topic_type for i in pubs or subs if i.topic_type)
            type_name = types.most_common(1)[0][0] if types else None
            counts = (len(pubs), len(subs))
        return {"topic": topic, "type": type_name, "status": "metadata_only", "data_json": b"{}",
                "timestamp": time.time_ns(), "publisher_count": counts[0],
                "subscriber_count": counts[1], "reason": reason}

    # ---- creation -----------------------------------------------------------------------
    def _create(self, topic: str, waiter: bool = False) -> tuple[Entry | None, str]:
        """Pool ``topic`` (evicting the least recently read entry at the cap); None and why not.

        ``waiter``: the caller will wait for the first message, so at the cold-wait cap it is
        refused (IpcError) before anything changes.  A refused read that still evicted a
        pooled topic and subscribed anew would, under load, evict the topics readers keep
        warm faster than new subscriptions get their first message: the pool would thrash
        and warm reads would be refused too.
        """
        infos = self.endpoints.publishers(topic)
        if not infos:
            in_graph = (self.endpoints.subscriber_count(topic) > 0
                        or bool(self.node.get_publishers_info_by_topic(topic)))
            return None, ("no-publishers" if in_graph else "not-in-graph")
        types = collections.Counter(i.topic_type for i in infos)
        type_name = types.most_common(1)[0][0]
        if type_name in self.unsupported:
            return None, "unsupported-type"
        try:
            cls = msgtypes.load_type(type_name)
        except msgtypes.ConversionError:
            self._mark_unsupported(type_name)
            return None, "unsupported-type"
        previous = self.last_types.get(topic)
        if previous is not None and previous != type_name:
            self.stats.type_change_events += 1
        self._remember_type(topic, type_name)
        if waiter:
            self._check_cold_wait_cap(topic)
        victim = None
        if len(self.entries) >= self.max_pool_size:
            victim = next((e for e in self.entries.values() if not e.waiters), None)
            if victim is None:
                raise IpcError("pool-busy", f"Every pooled topic ({self.max_pool_size}, max_pool_size) still "
                                            "waits for its first message; retry with backoff",
                               {"topic": topic, "max_pool_size": self.max_pool_size})
        entry = Entry(topic, type_name, cls)
        entry.publisher_count = len(infos)
        entry.subscriber_count = self.endpoints.subscriber_count(topic)
        same_type = [i for i in infos if i.topic_type == type_name]
        entry.sub, entry.profile = self._subscribe(entry, same_type)
        entry.matched = entry.sub.handle.get_publisher_count()
        if victim is not None:
            self.evict(victim, "lru")
        self.entries[topic] = entry
        self.stats.pool_size = len(self.entries)
        return entry, "pooled"

    def _subscribe(self, entry: Entry, infos: list) -> tuple[Any, Any]:
        """A new subscription for ``entry`` with QoS matched to ``infos`` (or the recorded one, and no
        profile of its own); raises IpcError."""
        if self.shared_subscription is not None:
            shared = self.shared_subscription(entry.topic, entry.type_name)
            if shared is not None:
                return shared, None
        profile = qos.match_qos(infos)
        try:
            sub = self.node.create_subscription(entry.cls, entry.topic, _never_called, profile)
        except Exception as exc:
            log.warning("subscribing to %s failed: %s", entry.topic, exc)
            raise IpcError("subscribe-failed", f"Could not subscribe to {entry.topic}: {exc}",
                           {"topic": entry.topic}) from None
        log.debug("subscribed %s [%s] %s", entry.topic, entry.type_name, qos.describe(profile))
        return sub, profile

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

    # ---- the byte budget ------------------------------------------------------------------
    def _account(self, entry: Entry, delta: int) -> None:
        entry.nbytes += delta
        if self.entries.get(entry.topic) is entry:
            self.nbytes += delta
            self.stats.pool_bytes = self.nbytes

    def _enforce_budget(self, keep: Entry) -> None:
        """Past ``max_pool_bytes``: drop cached JSON, then whole entries, least recently read first."""
        if self.nbytes <= self.max_pool_bytes:
            return
        for entry in list(self.entries.values()):
            if self.nbytes <= self.max_pool_bytes:
                return
            if entry is not keep and entry.json:
                self._account(entry, -sum(map(len, entry.json.values())))
                entry.json.clear()
                self.stats.pool_json_drops += 1
        for entry in list(self.entries.values()):
            if self.nbytes <= self.max_pool_bytes:
                return
            if entry is not keep and not entry.waiters:
                self.evict(entry, "bytes")

    # ---- evictions ----------------------------------------------------------------------
    def evict(self, entry: Entry, reason: str) -> None:
        if self.entries.get(entry.topic) is not entry:
            return
        self._account(entry, -entry.nbytes)
        del self.entries[entry.topic]
        self.stats.pool_size = len(self.entries)
        self.stats.evictions_total += 1
        self.stats.evictions[reason] = self.stats.evictions.get(reason, 0) + 1
        for waiter in list(entry.waiters):
            self._release(entry, waiter)
            waiter.task.reply(self._metadata(entry.topic, entry,
                                             "shutdown" if reason == "shutdown" else "evicted"))
        self._destroy(entry.sub, entry.topic)
        entry.sub = None
        log.debug("evicted %s (%s)", entry.topic, reason)

    def _destroy(self, sub, topic: str) -> None:
        if sub is not None and not getattr(sub, "shared", False):  # a recorded one is the recorder's
            try:
                self.node.destroy_subscription(sub)
            except Exception:
                log.exception("destroying the subscription of %s failed", topic)

    def adopt(self, topic: str) -> None:
        """``topic`` has a recorded subscription now: a pooled entry of its type reads through it and
        its own subscription goes (one subscription per topic)."""
        entry = self.entries.get(topic)
        if entry is None or entry.sub is None or self.shared_subscription is None:
            return
        shared = self.shared_subscription(topic, entry.type_name)
        if shared is None or entry.sub is shared:
            return
        old, entry.sub, entry.profile = entry.sub, shared, None
        entry.matched = shared.handle.get_publisher_count()
        self._destroy(old, topic)

    def unshare(self, topic: str) -> None:
        """The recorded subscription of ``topic`` goes: an entry reading through it is dropped (the next
        read subscribes again)."""
        entry = self.entries.get(topic)
        if entry is not None and getattr(entry.sub, "shared", False):
            self.evict(entry, "graph")

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

    def check_graph(self, full: bool) -> None:
        """Re-check pooled topics against the graph (each entry on its own: one failure is contained).

        ``full``: every entry is re-checked (the graph changed, or the periodic
        sweep); otherwise only entries whose matched-publisher count changed.
        """
        for entry in list(self.entries.values()):
            self.executor.guarded(f"the graph check of {entry.topic}", self._check_entry, entry, full)

    def _check_entry(self, entry: Entry, full: bool) -> None:
        if entry.sub is None:  # evicted meanwhile
            return
        matched = entry.sub.handle.get_publisher_count()
        if not (full or matched != entry.matched):
            return
        entry.matched = matched
        infos = self.endpoints.publishers(entry.topic)
        if not infos:
            self.evict(entry, "graph")
            return
        types = {i.topic_type for i in infos}
        if entry.type_name not in types:
            self.stats.type_change_events += 1
            self._remember_type(entry.topic, next(iter(types)))
            self.evict(entry, "type_change")
            return
        entry.publisher_count = len(infos)
        entry.subscriber_count = self.endpoints.subscriber_count(entry.topic)
        same_type = [i for i in infos if i.topic_type == entry.type_name]
        if entry.profile is not None and qos.key(qos.match_qos(same_type)) != qos.key(entry.profile):
            self._rebuild(entry, same_type)  # a recorded subscription (no profile) is the recorder's

    def _rebuild(self, entry: Entry, infos: list) -> None:
        """Recreate the subscription with QoS matched to the current publishers.

        The new subscription is made before the old one goes: if it cannot be made,
        the entry keeps serving from the old one (and the next check tries again).
        """
        log.info("re-subscribing %s with QoS matched to its publishers", entry.topic)
        sub, profile = self._subscribe(entry, infos)
        old, entry.sub, entry.profile = entry.sub, sub, profile
        entry.matched = sub.handle.get_publisher_count()
        self.stats.evictions["qos_rebuild"] += 1
        self._destroy(old, entry.topic)

    def shutdown(self) -> None:
        for entry in list(self.entries.values()):
            self.evict(entry, "shutdown")


def _never_called(_msg) -> None:  # pragma: no cover - pooled subscriptions are never spun
    pass
