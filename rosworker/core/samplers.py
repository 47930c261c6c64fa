"""What cyclic subscriptions can stream: one sampler per kind (medkit's ``ResourceSamplerRegistry``).

A family registers a sampler for each kind of resource a cyclic subscription
may watch: ``data`` (a topic: the data family's tick groups, ``data/ticks.py``),
``execution`` (an action goal, ``operations/feed.py``), ``parameter``
(``configurations/feed.py``).  The subscriptions family keeps the subscriptions
(caps, expiry, updates, the restart state, control events) and knows no family:
it hands each one to the sampler of its kind.

A sampler (ROS thread only):

- ``check(sub)``: refuse (:class:`IpcError`) a subscription whose target is
  malformed or unknown, before it is kept;
- ``watch(sub, end)``: frame it on the events channel from now on
  (``core.events.publish(sub.key, meta, data)``), once per ``sub.interval``;
  ``end()`` ends the subscription as an expiry does (a goal that finished);
- ``unwatch(sub)``: stop framing it;

and, for other families, one-off reads (the faults' freeze frames read ``data``):

- ``read(resource, mode)``: what a GET would answer now, never waiting (None:
  no value yet);
- ``warm(resource)``: make a later ``read`` find a value.

What a sampler may read of ``sub``: ``id``, ``key``, ``kind``, ``interval``,
``topic``, ``bytes``, ``target`` (a dict of strings) and ``deadline``.

:class:`TimedSampler` is the base of a sampler that frames each subscription on
a timer of its own (a goal, a parameter: nothing to share between them).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Protocol

from ipc import events

from .registry import Registry
from .task import Timer


class Sampler(Protocol):
    def check(self, sub: Any) -> None: ...

    def watch(self, sub: Any, end: Callable[[], None]) -> None: ...

    def unwatch(self, sub: Any) -> None: ...


class SamplerRegistry(Registry):
    def __init__(self) -> None:
        super().__init__(lambda kinds: "kind: expected " + ", ".join(f"'{k}'" for k in kinds))

    def register(self, kind: str, sampler: Sampler) -> None:
        """A family's start: subscriptions of ``kind`` are streamed by ``sampler``."""
        self.add(kind, sampler, f"a sampler of {kind!r} is registered already")

    @property
    def kinds(self) -> tuple[str, ...]:
        return self.names

    def read(self, kind: str, resource: str, mode: str = "array") -> dict[str, Any] | None:
        """What a GET of ``resource`` would answer now (None: no value yet, or nobody samples ``kind``)."""
        sampler = self._items.get(kind)
        return sampler.read(resource, mode) if sampler is not None else None

    def warm(self, kind: str, resource: str) -> None:
        sampler = self._items.get(kind)
        if sampler is not None:
            sampler.warm(resource)


class Feed:
    """One subscription of a :class:`TimedSampler`: its timer and its ``end``; a sampler adds its state."""

    def __init__(self, sub: Any, end: Callable[[], None]):
        self.sub = sub
        self.end = end
        self.timer: Timer | None = None


class TimedSampler:
    """Frames each subscription on a timer of its own at its interval: ``frame(feed)`` every tick.

    A subclass gives ``check``, ``frame`` and, when it keeps more per subscription, ``make``
    (its :class:`Feed`) and ``dropped`` (what ``unwatch`` gives back)."""

    kind = ""

    def __init__(self, core: Any):
        self.executor = core.executor
        self.events = core.events
        self.feeds: dict[str, Feed] = {}

    def make(self, sub: Any, end: Callable[[], None]) -> Feed:
        return Feed(sub, end)

    def check(self, sub: Any) -> None:
        raise NotImplementedError

    def frame(self, feed: Feed) -> None:
        raise NotImplementedError

    def dropped(self, feed: Feed) -> None:
        pass

    def watch(self, sub: Any, end: Callable[[], None]) -> None:
        feed = self.feeds[sub.id] = self.make(sub, end)
        self._arm(feed, 0.0)

    def unwatch(self, sub: Any) -> None:
        feed = self.feeds.pop(sub.id, None)
        if feed is None:
            return
        if feed.timer is not None:
            feed.timer.cancel()
        self.dropped(feed)

    def publish(self, feed: Feed, data: bytes = b"{}", **meta: Any) -> None:
        """One frame of ``feed``: meta ``{"ts", "kind", **meta}`` and ``data`` (JSON)."""
        self.events.publish(feed.sub.key, {"ts": time.time_ns(), "kind": feed.sub.kind, **meta}, data)

    def _arm(self, feed: Feed, delay: float) -> None:
        feed.timer = self.executor.call_later(delay, lambda: self._tick(feed))

    def _tick(self, feed: Feed) -> None:
        if self.feeds.get(feed.sub.id) is not feed:
            return
        self._arm(feed, events.INTERVALS[feed.sub.interval])
        self.executor.guarded(f"the {feed.sub.kind} feed of {feed.sub.id}", self.frame, feed)
