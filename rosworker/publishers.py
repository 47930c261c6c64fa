"""Pooled publishers for ``PUT .../data/...``, with their own LRU cap.

A publisher made for a first PUT has not been discovered by the topic's
subscribers yet; a message published at once would be lost.  So a new
publisher waits (on the ROS thread's timers, never blocking it) until it has
matched the subscribers the graph shows, or ``MATCH_WAIT`` passes, before it
publishes.  Later PUTs to the same topic publish at once.
"""

from __future__ import annotations

import collections
import logging
import time

from rclpy.qos import QoSProfile

from ipc.errors import IpcError

from . import convert
from .executor import RosExecutor, Task
from .stats import Stats

log = logging.getLogger("sovd.rosworker.publishers")

MATCH_WAIT = 1.0     # seconds a new publisher waits for its subscribers
MATCH_POLL = 0.005


class PublisherPool:
    def __init__(self, node, executor: RosExecutor, stats: Stats, max_publishers: int):
        self.node = node
        self.executor = executor
        self.stats = stats
        self.max_publishers = max_publishers
        self.entries: collections.OrderedDict[str, tuple[str, object]] = collections.OrderedDict()

    def publish(self, task: Task, topic: str, type_name: str, data: dict) -> None:
        try:
            cls = convert.load_type(type_name)
            msg = convert.from_plain(cls, data)
        except convert.ConversionError as exc:
            params = {"details": exc.message, "type": type_name} if exc.code == "invalid-type" else {}
            raise IpcError(exc.code, "Invalid message type format" if exc.code == "invalid-type"
                           else exc.message, params) from None
        current = self.entries.get(topic)
        if current is not None and current[0] == type_name:
            self.entries.move_to_end(topic)
            self._send(task, topic, type_name, current[1], msg)
            return
        if current is not None:
            self._destroy(topic)
        expected = self.node.count_subscribers(topic)
        try:
            pub = self.node.create_publisher(cls, topic, QoSProfile(depth=10))
        except Exception as exc:
            raise IpcError("publish-failed", f"Could not create a publisher on {topic}: {exc}",
                           {"topic": topic}) from None
        if len(self.entries) >= self.max_publishers:
            oldest = next(iter(self.entries))
            self._destroy(oldest)
        self.entries[topic] = (type_name, pub)
        self.stats.publishers = len(self.entries)
        give_up = time.monotonic() + min(MATCH_WAIT, max(0.0, task.deadline - time.monotonic() - 0.1))

        def attempt():
            if self.entries.get(topic, (None, None))[1] is not pub:
                task.fail(IpcError("publish-failed", f"The publisher on {topic} was replaced before it "
                                                     "could publish; retry", {"topic": topic}))
                return
            if pub.get_subscription_count() >= expected or time.monotonic() >= give_up:
                try:
                    self._send(task, topic, type_name, pub, msg)
                except IpcError as exc:
                    task.fail(exc)
            else:
                self.executor.call_later(MATCH_POLL, attempt)

        attempt()

    def _send(self, task: Task, topic: str, type_name: str, pub, msg) -> None:
        try:
            pub.publish(msg)
        except Exception as exc:
            raise IpcError("publish-failed", f"Publishing on {topic} failed: {exc}", {"topic": topic}) from None
        self.stats.publishes_total += 1
        task.reply({"topic": topic, "type": type_name, "status": "published",
                    "subscriber_count": pub.get_subscription_count()})

    def _destroy(self, topic: str) -> None:
        _, pub = self.entries.pop(topic)
        self.stats.publishers = len(self.entries)
        try:
            self.node.destroy_publisher(pub)
        except Exception:
            log.exception("destroying the publisher of %s failed", topic)

    def shutdown(self) -> None:
        for topic in list(self.entries):
            self._destroy(topic)
