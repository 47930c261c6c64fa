"""Pooled publishers for ``PUT .../data/...``, with their own LRU cap and idle expiry.

Every method runs on the ROS thread.

QoS: a publisher is made with QoS matched to the topic's subscribers
(``qos.publisher_qos``: transient-local when any subscriber is, so that a
latched command input hears it).  When the subscribers change so that the
pooled publisher no longer fits them, the next PUT makes a new one.

Types: a PUT whose type is not one the topic's publishers or subscribers use
(the gateway's own left out) is refused (``type-mismatch``) before any
publisher is made; only a topic without typed endpoints takes any type.

Matching: a publisher made for a PUT has not been discovered by the topic's
subscribers yet; a message published at once would be lost.  So a new
publisher waits (on the ROS thread's timers, never blocking it) until it has
matched the subscribers the graph shows, or ``match_wait`` passes, before it
publishes.  Later PUTs to the same topic publish at once.  The answer says how
many subscribers the message reached (``subscriber_count``, the gateway's own
subscription left out) and how many subscribers the graph shows that it did not
reach (``unmatched_subscriber_count``: their QoS or message-type version cannot
match, or they were not discovered within ``match_wait``).

Publishers not used for ``idle_safety_net`` seconds are destroyed (they would
otherwise keep the topic in the graph).  At shutdown a PUT still waiting for
its subscribers is answered ``shutdown``: it was not published.
"""

from __future__ import annotations

import collections
import logging
import time

from ipc.errors import IpcError

from ..core.endpoints import Endpoints
from ..core.executor import RosExecutor
from ..core.stats import Stats
from ..core.task import Task, Timer
from ..ros import msgtypes, qos
from ..ros.decode import from_plain
from .pool import TopicPool

log = logging.getLogger("sovd.rosworker.publishers")

MATCH_POLL = 0.005


class Pooled:
    __slots__ = ("type_name", "pub", "profile", "last_used")

    def __init__(self, type_name: str, pub, profile):
        self.type_name = type_name
        self.pub = pub
        self.profile = profile
        self.last_used = time.monotonic()


class PublisherPool:
    def __init__(self, node, executor: RosExecutor, stats: Stats, pool: TopicPool, endpoints: Endpoints,
                 max_publishers: int, idle_safety_net: float = 0.0, match_wait: float = 1.0):
        self.node = node
        self.executor = executor
        self.stats = stats
        self.pool = pool
        self.endpoints = endpoints
        self.max_publishers = max_publishers
        self.idle_safety_net = idle_safety_net
        self.match_wait = match_wait
        self.entries: collections.OrderedDict[str, Pooled] = collections.OrderedDict()
        self.pending: dict[Task, Timer | None] = {}   # PUTs waiting for their subscribers

    def publish(self, task: Task, topic: str, type_name: str, data: dict) -> None:
        try:
            cls = msgtypes.load_type(type_name)
            msg = from_plain(cls, data)
        except msgtypes.ConversionError as exc:
            params = {"details": exc.message, "type": type_name} if exc.code == "invalid-type" else {}
            raise IpcError(exc.code, "Invalid message type format" if exc.code == "invalid-type"
                           else exc.message, params) from None
        subscribers = self.endpoints.subscribers(topic)
        self._check_type(topic, type_name, subscribers)
        profile = qos.publisher_qos(subscribers)
        current = self.entries.get(topic)
        if current is not None and current.type_name == type_name and qos.key(current.profile) == qos.key(profile):
            self.entries.move_to_end(topic)
            current.last_used = time.monotonic()
            self._send(task, topic, current, msg, len(subscribers))
            return
        if current is not None:
            self._destroy(topic)
        try:
            pub = self.node.create_publisher(cls, topic, profile)
        except Exception as exc:
            raise IpcError("publish-failed", f"Could not create a publisher on {topic}: {exc}",
                           {"topic": topic}) from None
        if len(self.entries) >= self.max_publishers:
            self._destroy(next(iter(self.entries)))
        pooled = self.entries[topic] = Pooled(type_name, pub, profile)
        self.stats.publishers = len(self.entries)
        expected = len(subscribers) + self._own_heard(topic, profile)
        give_up = time.monotonic() + min(self.match_wait, max(0.0, task.deadline - time.monotonic() - 0.1))

        def attempt():
            self.pending.pop(task, None)
            self.stats.publishes_waiting = len(self.pending)
            if self.entries.get(topic) is not pooled:
                task.fail(IpcError("publish-failed", f"The publisher on {topic} was replaced before it "
                                                     "could publish; retry", {"topic": topic}))
                return
            if pub.get_subscription_count() >= expected or time.monotonic() >= give_up:
                try:
                    self._send(task, topic, pooled, msg, len(subscribers))
                except IpcError as exc:
                    task.fail(exc)
            else:
                self.pending[task] = self.executor.call_later(MATCH_POLL, attempt)
                self.stats.publishes_waiting = len(self.pending)

        attempt()

    def _check_type(self, topic: str, type_name: str, subscribers: list) -> None:
        """Refuse a type the topic's endpoints do not use, before any publisher is made.

        A publisher of a foreign type would sit on the robot's topic (until
        ``idle_safety_net``) and reach nobody.  Only a topic without typed
        endpoints (the gateway's own left out) accepts any type; a topic with
        endpoints of several types accepts each of them.
        """
        types = {i.topic_type for i in (*subscribers, *self.endpoints.publishers(topic)) if i.topic_type}
        if types and type_name not in types:
            used = ", ".join(sorted(types))
            raise IpcError("type-mismatch", f"{topic} carries {used} (the type of its publishers and "
                                            f"subscribers); a {type_name} message cannot be published there",
                           {"topic": topic, "type": type_name, "topic_types": sorted(types)})

    def _own_heard(self, topic: str, profile) -> int:
        """1 when the pool's own subscription to ``topic`` matches a publisher with ``profile``."""
        own = self.pool.own_subscription_qos(topic)
        return int(own is not None and qos.hears(own, profile))

    def _send(self, task: Task, topic: str, pooled: Pooled, msg, known: int) -> None:
        try:
            pooled.pub.publish(msg)
        except Exception as exc:
            raise IpcError("publish-failed", f"Publishing on {topic} failed: {exc}", {"topic": topic}) from None
        self.stats.publishes_total += 1
        reached = max(0, pooled.pub.get_subscription_count() - self._own_heard(topic, pooled.profile))
        task.reply({"topic": topic, "type": pooled.type_name, "status": "published",
                    "subscriber_count": reached,
                    "unmatched_subscriber_count": max(0, known - reached)})

    def _destroy(self, topic: str) -> None:
        pooled = self.entries.pop(topic)
        self.stats.publishers = len(self.entries)
        try:
            self.node.destroy_publisher(pooled.pub)
        except Exception:
            log.exception("destroying the publisher of %s failed", topic)

    def sweep_idle(self) -> None:
        if not self.idle_safety_net:
            return
        limit = time.monotonic() - self.idle_safety_net
        for topic in [t for t, p in self.entries.items() if p.last_used < limit]:
            self._destroy(topic)
            self.stats.publishers_expired += 1

    def shutdown(self) -> None:
        for task, timer in list(self.pending.items()):
            if timer is not None:
                timer.cancel()
            task.fail(IpcError("shutdown", "The gateway shut down before the message could be "
                                           "published; it was not published"))
        self.pending.clear()
        self.stats.publishes_waiting = 0
        for topic in list(self.entries):
            self._destroy(topic)
