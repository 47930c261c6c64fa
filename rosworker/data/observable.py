"""The ``data`` collection as something to observe: every message of a watched topic (triggers).

Provided to the core's notifier (``core/notifier.py``) by the data family; an
observer (a trigger) names a topic as its target.  Per topic, not per
observer: a watched topic gets its own subscription (``KEEP_LAST``
``TRIGGER_DEPTH``, QoS matched to its publishers), apart from the pool's
depth-1 one, so that every message is seen, not only the newest.  A message
wakes the ROS thread (the subscription is in the waiter's wait set, ``core/waiter.py``);
each round of the loop then takes what arrived, at most ``TAKES_PER_ROUND`` messages per topic and
``ROUND_BUDGET`` seconds in all (the rest wait in the subscription's queue for
the next round, after the commands and timers: a busy topic cannot hold the
thread; past its ``TRIGGER_DEPTH`` the middleware drops the oldest), converts
each message once to JSON (``ros/encode.py``; NaN and ±inf as the strings
"NaN", "Infinity", "-Infinity") and hands it to every observer of the topic
(``observer.changed``; its payload in another bytes mode is made once, when
first asked).  A message that cannot be read is ``observer.failed``, at most
once per ``ERROR_EVERY`` s per topic.  A topic nobody watches has no such
subscription: zero per-message work.  A topic that is not in the graph yet (a
restored trigger, a late publisher) is tried again every ``PENDING_RETRY`` s; a
watched topic whose publishers change type is subscribed again with the new one
(looked at every ``GRAPH_CHECK`` s).
"""

from __future__ import annotations

import logging
import time

import orjson

from ..core import args
from ..core.endpoints import Endpoints
from ..core.executor import RosExecutor
from ..core.notifier import Observer
from ..core.stats import Stats
from ..core.task import Timer
from ..ros import msgtypes, qos
from ..ros.encode import to_json

log = logging.getLogger("sovd.rosworker.triggers")

TRIGGER_DEPTH = 256       # messages a watched topic's subscription queues between two rounds
TAKES_PER_ROUND = 256     # messages one topic may take per round of the loop
ROUND_BUDGET = 0.01       # seconds of evaluation per round of the loop, all topics together
PENDING_RETRY = 0.25      # seconds between tries to subscribe a watched topic not in the graph yet
GRAPH_CHECK = 1.0         # seconds between checks of a watched topic's publishers' type
ERROR_EVERY = 1.0         # seconds between two error events of one topic (undecodable messages)


class _TopicWatch:
    __slots__ = ("topic", "type_name", "cls", "sub", "observers", "error_at")

    def __init__(self, topic: str):
        self.topic = topic
        self.type_name: str | None = None
        self.cls = None
        self.sub = None
        self.observers: list[Observer] = []
        self.error_at = 0.0


class DataObservable:
    """The ``data`` collection (``core/notifier.py``): one subscription per watched topic, every message
    taken, converted and handed to its observers once."""

    max_target = 4096

    def __init__(self, node, executor: RosExecutor, endpoints: Endpoints, stats: Stats):
        self.node = node
        self.executor = executor
        self.endpoints = endpoints
        self.stats = stats
        self.watches: dict[str, _TopicWatch] = {}
        self.live: list[_TopicWatch] = []       # the watches with a subscription (waited on)
        self._retry: Timer | None = None
        self._last_check = 0.0
        executor.add_poller("data triggers", self.waitables, self.poll, self.due)

    def waitables(self) -> list:
        """The watched topics' subscriptions: a message wakes the ROS thread."""
        return [w.sub for w in self.live if w.sub is not None and w.observers] if self.live else []

    def due(self) -> float | None:
        """The next look at the watched topics' publishers' type (every ``GRAPH_CHECK`` s)."""
        return self._last_check + GRAPH_CHECK if self.live else None

    def check_target(self, text: str) -> str:
        """A topic name (normalized), or ``invalid-topic``."""
        return args.topic({"topic": text})

    def attach(self, observer: Observer) -> None:
        watch = self.watches.get(observer.target)
        if watch is None:
            watch = self.watches[observer.target] = _TopicWatch(observer.target)
        watch.observers.append(observer)
        if watch.sub is None:
            self.executor.guarded(f"subscribing the trigger topic {watch.topic}", self._subscribe, watch)
            if watch.sub is None:
                self._arm_retry()

    def detach(self, observer: Observer) -> None:
        watch = self.watches.get(observer.target)
        if watch is None or observer not in watch.observers:
            return
        watch.observers.remove(observer)
        if not watch.observers:
            del self.watches[watch.topic]
            self._drop(watch)

    def close(self) -> None:
        for watch in list(self.watches.values()):
            self._drop(watch)
        self.watches.clear()

    # ---- subscriptions --------------------------------------------------------------------------
    def _subscribe(self, watch: _TopicWatch) -> None:
        infos = self.endpoints.publishers(watch.topic)
        if not infos:
            return
        types: dict[str, int] = {}
        for info in infos:
            types[info.topic_type] = types.get(info.topic_type, 0) + 1
        type_name = max(types, key=types.get)
        try:
            cls = msgtypes.load_type(type_name)
        except msgtypes.ConversionError:
            return
        profile = qos.match_qos([i for i in infos if i.topic_type == type_name])
        profile.depth = TRIGGER_DEPTH
        watch.sub = self.node.create_subscription(cls, watch.topic, _never_called, profile)
        watch.type_name, watch.cls = type_name, cls
        self.live.append(watch)
        log.debug("triggers: watching %s [%s]", watch.topic, type_name)

    def _drop(self, watch: _TopicWatch) -> None:
        if watch in self.live:
            self.live.remove(watch)
        if watch.sub is not None:
            try:
                self.node.destroy_subscription(watch.sub)
            except Exception:
                log.exception("destroying the trigger subscription of %s failed", watch.topic)
            watch.sub = None

    def _arm_retry(self) -> None:
        if self._retry is None:
            self._retry = self.executor.call_later(PENDING_RETRY, self._retry_pending)

    def _retry_pending(self) -> None:
        self._retry = None
        pending = [w for w in self.watches.values() if w.sub is None]
        for watch in pending:
            self.executor.guarded(f"subscribing the trigger topic {watch.topic}", self._subscribe, watch)
        if any(w.sub is None for w in self.watches.values()):
            self._arm_retry()

    def _check_types(self) -> None:
        """A watched topic whose publishers changed type is subscribed again with the new one."""
        for watch in list(self.live):
            infos = self.endpoints.publishers(watch.topic)
            if infos and watch.type_name not in {i.topic_type for i in infos}:
                log.info("triggers: %s changed type; subscribing again", watch.topic)
                self._drop(watch)
                self._subscribe(watch)
                if watch.sub is None:
                    self._arm_retry()

    # ---- when a message came -----------------------------------------------------------------------
    def poll(self) -> None:
        now = time.monotonic()
        if now - self._last_check >= GRAPH_CHECK:
            self._last_check = now
            self.executor.guarded("the trigger topics' type check", self._check_types)
        until = now + ROUND_BUDGET
        for watch in list(self.live):
            if watch.sub is not None:
                self.executor.guarded(f"the triggers of {watch.topic}", self._drain, watch, until)
        if len(self.live) > 1:  # the next round starts with the next topic: none waits behind a busy one
            self.live.append(self.live.pop(0))

    def _drain(self, watch: _TopicWatch, until: float) -> None:
        handle = watch.sub.handle
        for _ in range(TAKES_PER_ROUND):
            if watch.sub is None or not watch.observers or time.monotonic() >= until:
                return
            try:
                taken = handle.take_message(watch.cls, False)
            except Exception:
                self._failed(watch, f"A message on {watch.topic} cannot be decoded as {watch.type_name}")
                continue
            if taken is None:
                return
            msg, info = taken
            self.stats.trigger_messages += 1
            stamp = info.get("received_timestamp") or time.time_ns()
            try:
                texts = {"array": to_json(msg, "array")}
                doc = orjson.loads(texts["array"])
            except Exception:
                self._failed(watch, f"A message on {watch.topic} could not be converted to JSON")
                continue

            def payload(mode: str, msg=msg, texts=texts) -> bytes:
                text = texts.get(mode)
                if text is None:
                    text = texts[mode] = to_json(msg, mode)
                return text

            for observer in list(watch.observers):
                observer.changed(stamp, doc, payload)

    def _failed(self, watch: _TopicWatch, message: str) -> None:
        self.stats.undecodable_messages += 1
        now = time.monotonic()
        if now - watch.error_at < ERROR_EVERY:
            return
        watch.error_at = now
        stamp = time.time_ns()
        for observer in list(watch.observers):
            observer.failed(stamp, message)


def _never_called(_msg) -> None:  # pragma: no cover - trigger subscriptions are never spun
    pass
