"""The ``data`` sampler: cyclic subscriptions on topics, framed once per topic per tick.

Registered with the core's samplers (``core/samplers.py``) by the data family;
the subscriptions family hands it every subscription of kind ``data`` and knows
nothing of this.  Every method runs on the ROS thread.

Cost per topic, not per stream: for each interval class (``fast`` 50 ms,
``normal`` 200 ms, ``slow`` 500 ms) one timer ticks on a fixed rate; a tick
takes and converts each watched ``(topic, bytes mode)`` once (the pool
reuses the converted JSON until a newer message arrives) and publishes one
frame for it on the events socket (a PUB beside the command ROUTER, see
``ipc/PROTOCOL.md``), however many streams watch it.  ZeroMQ delivers that
frame once to each HTTP worker that subscribed to its key; the HTTP worker
fans it out to its streams.

A tick's frame is what a ``sample`` would answer at that moment, except that
it never waits: a topic whose first message has not arrived is subscribed
and gets no frame until the message arrives or ``sample_timeout`` passes
(then a ``metadata_only``/``timeout`` frame, as a GET would answer).

A watched topic that is not pooled (nobody publishes on it, or it does not
exist at all) costs nothing per tick: its ``metadata_only`` answer is built
once per graph change and reused (``_unpooled``).  A name missing from the
graph monitor's last poll has no endpoint, so its answer is built without a
single graph query and kept until the graph's ``generation`` changes (a
publisher that appears adds the name, and the next tick pools the topic).  A
name in the graph without a publisher of ours to read (only subscribers, or
only the gateway's own publisher) is asked again at each full re-check
(``epoch``, every second), since an endpoint joining an existing topic may
leave the names alone.

Tick phase per topic: a topic's ticks are phased to its messages' arrivals
(rmw's received timestamp, known at each take), so that a message is framed
``PHASE_MARGIN`` after it arrives, not up to an interval later.  Until a
topic's first message, its watches tick on the interval's grid (one timer for
all of them, as a topic nobody publishes keeps).  Its first message sets the
phase; afterwards ``PHASE_MISSES`` new messages in a row taken later than
``PHASE_MARGIN + PHASE_SLACK`` after they arrived set it again (at most once
per ``PHASE_HOLD``, so a client's grid stays put while a topic's rate drifts).
Watches of the same phase (to the millisecond) share one timer.  The cadence
is unchanged: one frame per interval with the latest value, whether or not it
changed; a topic whose messages stop keeps ticking at its last phase; a watch
moved to a new phase skips a tick that would come within half an interval of
its last one.  A group's timer runs only while it has watches: with no stream
open, nothing ticks.

A watched topic is a ``(topic, bytes mode)`` at an interval, counted by the
subscriptions that watch it: the last one gone, its watch goes.

For other families, :meth:`TopicTicks.read` (the pool's ``peek``: never waits)
and :meth:`TopicTicks.warm` (subscribe now, so that a read finds a message):
the faults' freeze frames.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from ipc import events, protocol
from ipc.errors import IpcError

from .pool import TopicPool

PHASE_MARGIN = 0.002  # seconds after a message's arrival that its topic's phased tick comes
PHASE_SLACK = 0.005   # a new message taken later than MARGIN + this after it arrived is out of phase
PHASE_MISSES = 3      # ... so many of them in a row phase the topic again
PHASE_HOLD = 5.0      # seconds between two phase changes of a topic at most


class _Watch:
    """A ``(topic, bytes mode)`` watched at one interval: its frames' key, when it was first ticked, its
    tick group (``slot``: None on the interval's grid, else its phase in ms) and when it last ticked."""

    __slots__ = ("key", "since", "count", "slot", "last")

    def __init__(self, key: bytes):
        self.key = key
        self.since = time.monotonic()
        self.count = 0
        self.slot: int | None = None
        self.last = 0.0


class _Phase:
    """A watched topic's phase: ``anchor`` (a monotonic time its ticks fall on, None until its first
    message), the received stamp of the last message seen, misses in a row, and the last change."""

    __slots__ = ("anchor", "last_ns", "misses", "changed")

    def __init__(self):
        self.anchor: float | None = None
        self.last_ns = 0
        self.misses = 0
        self.changed = 0.0


class TopicTicks:
    """The ``data`` sampler (``core/samplers.py``): tick groups per interval and phase over the pool."""

    def __init__(self, core: Any, pool: TopicPool, sample_timeout: float):
        self.executor = core.executor
        self.events = core.events
        self.graph = core.graph
        self.stats = core.stats
        self.pool = pool
        self.sample_timeout = sample_timeout
        # topic -> ((generation, epoch or -1), the answer a read would give): see the module's doc
        self._unpooled: dict[str, tuple[tuple[int, int], dict[str, Any]]] = {}
        self.watches: dict[str, dict[tuple[str, str], _Watch]] = {i: {} for i in events.INTERVALS}
        # (interval, slot) -> the watches ticked together; slot None: the interval's grid (from _grid)
        self._groups: dict[tuple[str, int | None], dict[tuple[str, str], _Watch]] = {
            (i, None): {} for i in events.INTERVALS}
        self._timed: set[tuple[str, int | None]] = set()   # the groups whose timer runs (none empty for long)
        self._grid = time.monotonic()
        self._phases: dict[str, _Phase] = {}   # watched topic -> its phase

    # ---- the sampler ------------------------------------------------------------------------
    def check(self, sub: Any) -> None:
        """A topic's subscription names its topic (checked by the subscriptions' commands)."""

    def watch(self, sub: Any, end: Callable[[], None]) -> None:
        watches = self.watches[sub.interval]
        watch = watches.get((sub.topic, sub.bytes))
        if watch is None:
            watch = watches[(sub.topic, sub.bytes)] = _Watch(sub.key)
            phase = self._phases.setdefault(sub.topic, _Phase())
            self._join(sub.interval, (sub.topic, sub.bytes), watch, phase.anchor)
        watch.count += 1

    def unwatch(self, sub: Any) -> None:
        watches = self.watches[sub.interval]
        watch = watches.get((sub.topic, sub.bytes))
        if watch is not None:
            watch.count -= 1
            if watch.count <= 0:
                del watches[(sub.topic, sub.bytes)]
                self._leave(sub.interval, (sub.topic, sub.bytes), watch)
                if not any((sub.topic, m) in w for w in self.watches.values() for m in protocol.BYTES_MODES):
                    self._unpooled.pop(sub.topic, None)
                    self._phases.pop(sub.topic, None)

    def read(self, topic: str, mode: str = "array") -> dict[str, Any] | None:
        """The topic's newest message as a sample answers it, never waiting (None: none yet)."""
        return self.pool.peek(topic, mode)

    def warm(self, topic: str) -> None:
        """Pool ``topic`` now, so that a later :meth:`read` finds its message."""
        self.pool.subscribe(topic)

    # ---- phases ---------------------------------------------------------------------------
    def _join(self, interval: str, key: tuple[str, str], watch: _Watch, anchor: float | None) -> None:
        """Put ``watch`` in the tick group of ``anchor`` (None: the interval's grid)."""
        period = events.INTERVALS[interval]
        slot = None if anchor is None else int((anchor % period) * 1000)
        watch.slot = slot
        group = self._groups.setdefault((interval, slot), {})
        if (interval, slot) not in self._timed:  # its timer starts at the next tick time of its anchor
            self._timed.add((interval, slot))
            now = time.monotonic()
            if anchor is None:
                self._schedule(interval, slot, self._grid + max(1, -(-(now - self._grid) // period)) * period)
            else:
                self._schedule(interval, slot, anchor + -(-(now - anchor) // period) * period)
        group[key] = watch

    def _leave(self, interval: str, key: tuple[str, str], watch: _Watch) -> None:
        group = self._groups.get((interval, watch.slot))
        if group is not None:
            group.pop(key, None)  # an empty group's timer ends at its next tick

    def _follow(self, topic: str, received_ns: int, scheduled: float, offset_s: float) -> None:
        """A tick of ``topic`` took the message received at ``received_ns`` (wall clock): phase the
        topic's ticks to it if it is its first one, or if its messages keep coming out of phase."""
        phase = self._phases.get(topic)
        if phase is None or received_ns == phase.last_ns:
            return
        phase.last_ns = received_ns
        arrival = received_ns / 1e9 - offset_s
        if phase.anchor is not None:
            if scheduled - arrival <= PHASE_MARGIN + PHASE_SLACK:
                phase.misses = 0
                return
            phase.misses += 1
            if phase.misses < PHASE_MISSES or scheduled - phase.changed < PHASE_HOLD:
                return
        phase.anchor = arrival + PHASE_MARGIN
        phase.misses = 0
        phase.changed = scheduled
        self.stats.phase_changes += 1
        for interval, watches in self.watches.items():
            for mode in protocol.BYTES_MODES:
                watch = watches.get((topic, mode))
                if watch is not None:
                    self._leave(interval, (topic, mode), watch)
                    self._join(interval, (topic, mode), watch, phase.anchor)

    # ---- ticks ----------------------------------------------------------------------------
    def _schedule(self, interval: str, slot: int | None, when: float) -> None:
        self.executor.call_later(max(0.0, when - time.monotonic()), lambda: self._tick(interval, slot, when))

    def _tick(self, interval: str, slot: int | None, scheduled: float) -> None:
        period = events.INTERVALS[interval]
        group = self._groups.get((interval, slot))
        if not group:  # every watch of this group left it: its timer ends (a phase's group goes)
            self._timed.discard((interval, slot))
            if slot is not None:
                self._groups.pop((interval, slot), None)
            return
        now = time.monotonic()
        following = scheduled + period
        if following <= now:  # late by more than a period: skip to the next slot ahead
            following = now + period - ((now - scheduled) % period)
        self._schedule(interval, slot, following)
        stamp = time.time_ns()
        offset_s = stamp / 1e9 - now  # the wall clock minus the monotonic one: arrivals to ticks
        framed = False
        for (topic, mode), watch in list(group.items()):
            if scheduled - watch.last < period / 2:  # just moved to this phase: one frame per interval
                continue
            watch.last = scheduled
            framed = True
            self.executor.guarded(f"the {interval} tick of {topic}", self._frame, interval, topic, mode,
                                  watch, stamp, scheduled, offset_s)
        if framed:
            self.stats.ticks[interval] = self.stats.ticks.get(interval, 0) + 1

    def _frame(self, interval: str, topic: str, mode: str, watch: _Watch, stamp: int, scheduled: float = 0.0,
               offset_s: float = 0.0) -> None:
        try:
            result = self._peek(topic, mode)
        except IpcError as exc:
            self._publish(watch.key, {"ts": stamp, "error": exc.to_wire()})
            return
        if result is None:  # subscribed, no first message yet
            if time.monotonic() - watch.since < self.sample_timeout:
                return
            result = self.pool.waiting(topic)
        meta = {k: v for k, v in result.items() if k != "data_json"}
        meta["ts"] = stamp
        if result["status"] == "metadata_only":
            meta["timestamp"] = stamp  # a kept answer says "now", as a fresh one would
        self._publish(watch.key, meta, result["data_json"])
        if result["status"] == "data" and isinstance(result.get("timestamp"), int):
            self._follow(topic, result["timestamp"], scheduled, offset_s)

    def _peek(self, topic: str, mode: str) -> dict[str, Any] | None:
        """``pool.peek``, except that an unpooled topic's answer is kept until the graph changes."""
        graph = self.graph
        if graph is None or self.pool.closing or topic in self.pool.entries:
            return self.pool.peek(topic, mode)
        listed = topic in graph.topics
        when = (graph.generation, graph.epoch if listed else -1)
        kept = self._unpooled.get(topic)
        if kept is not None and kept[0] == when:
            return kept[1]
        if listed:
            result = self.pool.peek(topic, mode)  # pools it if it has a publisher now
            if topic in self.pool.entries:
                self._unpooled.pop(topic, None)
                return result
        else:  # no endpoint at all as of the last poll: not a single graph query
            result = self.pool.absent(topic)
        self._unpooled[topic] = (when, result)
        return result

    def _publish(self, key: bytes, meta: dict[str, Any], data: bytes = b"{}") -> None:
        self.events.publish(key, meta, data)
