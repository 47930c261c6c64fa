"""Cyclic subscriptions: the registry, and the ticks that publish their frames once per topic.

Every method runs on the ROS thread.  The ROS worker is the single owner of
the subscriptions (SOVD "cyclic subscriptions"), so that a POST answered by
one HTTP worker streams through any other, and the registry survives an HTTP
worker's restart; it is kept in the restart state too, so it survives the
ROS worker's.

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

Caps: ``max_subscriptions`` in all, and ``max_subscriptions_per_client`` per
client address (the HTTP side sends it with ``sub_create``), so that one
client cannot take the whole registry.

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
its last one.

Control events (``updated``, ``deleted``, ``expired``) and a heartbeat go on
the same socket, so HTTP workers end or retime their streams at once.

Expiry runs on the monotonic clock (``Subscription.deadline``): a step of the
wall clock neither ends a subscription early nor keeps it for ever.
``expires_at_ns`` is derived from it for the answers, and for the restart
state, where the wall clock is the clock the next worker shares.

Saving: each subscription's restart record (its JSON) is made once, when it
is created or changed; after a change ``save()`` hands the list of records
(a copy of references, not a serialisation) to the restart state's writer
thread (``rosworker/core/state.py``), and a command that changed the registry is
answered once the writer has written it (``when_saved``: ``save(then)``): a
subscription that was answered survives a ROS worker killed right after, and
the ROS thread's cost of a change does not grow with the registry.
"""

from __future__ import annotations

import json
import logging
import os
import secrets
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import zmq

from ipc import events, protocol
from ipc.errors import IpcError
from ipc.server import bind_publisher, send_frames

from ..core.executor import RosExecutor, Timer
from ..core.graph import GraphMonitor
from ..core.stats import Stats
from ..data.pool import TopicPool

log = logging.getLogger("sovd.rosworker.streams")

HEARTBEAT_EVERY = 1.0
CONFIRM_BATCH = 1000  # subscription messages confirmed per round of the loop at most
SAVE_WAIT = 1.0     # seconds a changed registry waits for the writer before it is answered anyway
PHASE_MARGIN = 0.002  # seconds after a message's arrival that its topic's phased tick comes
PHASE_SLACK = 0.005   # a new message taken later than MARGIN + this after it arrived is out of phase
PHASE_MISSES = 3      # ... so many of them in a row phase the topic again
PHASE_HOLD = 5.0      # seconds between two phase changes of a topic at most


def wall_minus_monotonic_ns() -> int:
    """The wall clock minus the monotonic one, in ns: what turns a deadline into ``expires_at``.

    The two clocks are read as a pair, and again when the thread was preempted between the
    reads (a loaded robot): a pair read a scheduler slice apart would shift a displayed or
    restored expiry by that slice.
    """
    best = None
    for _ in range(3):
        before = time.monotonic_ns()
        wall = time.time_ns()
        after = time.monotonic_ns()
        if best is None or after - before < best[0]:
            best = (after - before, wall - (before + after) // 2)
        if after - before < 200_000:
            break
    return best[1]


@dataclass
class Subscription:
    id: str
    collection: str
    entity_id: str
    resource: str
    topic: str
    bytes: str
    interval: str
    duration: int
    created_at_ns: int
    client: str = ""        # the client address that made it ("" when the HTTP side did not say)
    # feeds (rosworker/configurations/feed.py): "data" (a topic), "execution" or "parameter", and what it names
    kind: str = "data"
    target: dict[str, Any] = field(default_factory=dict)
    deadline: float = field(default=0.0, compare=False)  # time.monotonic() at which it expires

    @property
    def expires_at_ns(self) -> int:
        """The wall-clock time of ``deadline``, for display and the restart state only."""
        return wall_minus_monotonic_ns() + int(self.deadline * 1e9)

    def wire(self) -> dict[str, Any]:
        """What the ``sub_*`` commands answer (the HTTP side makes the SOVD body of it)."""
        out = asdict(self)
        del out["deadline"]
        return {**out, "expires_at_ns": self.expires_at_ns, "key": self.key}

    def record(self) -> bytes:
        """Its restart record: the fields, with the deadline as wall-clock ``expires_at_ns``."""
        out = asdict(self)
        del out["deadline"]
        out["expires_at_ns"] = self.expires_at_ns
        return json.dumps(out, separators=(",", ":")).encode()

    @property
    def key(self) -> bytes:
        if self.kind != "data":  # a feed's frames are its own (rosworker/configurations/feed.py)
            return events.data_key(self.interval, self.kind, self.id)
        return events.data_key(self.interval, self.bytes, self.topic)


def _saved_at_once(then: Callable[[], None] | None = None) -> None:
    if then is not None:
        then()


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


class StreamRegistry:
    def __init__(self, zctx: zmq.Context, runtime_dir: str, executor: RosExecutor, pool: TopicPool,
                 stats: Stats, *, max_subscriptions: int, max_duration: int, sample_timeout: float,
                 max_per_client: int | None = None, graph: GraphMonitor | None = None,
                 save: Callable[[Callable[[], None] | None], None] | None = None):
        self.zctx = zctx
        self.runtime_dir = runtime_dir
        self.executor = executor
        self.pool = pool
        self.stats = stats
        self.max_subscriptions = max_subscriptions
        self.max_per_client = max_per_client or max_subscriptions
        self.graph = graph
        self.max_duration = max_duration
        self.sample_timeout = sample_timeout
        self.subs: dict[str, Subscription] = {}
        self.feeds: Any = None  # executions' and parameters' subscriptions (rosworker/configurations/feed.py), set by main
        self._records: dict[str, bytes] = {}  # id -> Subscription.record(), made when it changes
        self.version = 0                      # bumped at each change of the registry
        self.per_client: dict[str, int] = {}
        # topic -> ((generation, epoch or -1), the answer a read would give): see the module's doc
        self._unpooled: dict[str, tuple[tuple[int, int], dict[str, Any]]] = {}
        self.watches: dict[str, dict[tuple[str, str], _Watch]] = {i: {} for i in events.INTERVALS}
        # (interval, slot) -> the watches ticked together; slot None: the interval's grid (always timed)
        self._groups: dict[tuple[str, int | None], dict[tuple[str, str], _Watch]] = {
            (i, None): {} for i in events.INTERVALS}
        self._phases: dict[str, _Phase] = {}   # watched topic -> its phase
        self._expiry: dict[str, Timer] = {}
        self._pub: zmq.Socket | None = None
        # save(): after every change of the registry, hands the records to the restart state's
        # writer; save(then) also runs ``then`` once they are written (see when_saved).
        # Without it (a registry that is not kept), ``then`` runs at once.
        self._save = save or _saved_at_once
        stats.max_subscriptions = max_subscriptions

    # ---- set-up (ROS thread, before the loop) ---------------------------------------------
    def bind(self) -> None:
        self._pub = bind_publisher(self.zctx, self.runtime_dir)
        self.executor.add_reader("the events channel's subscriptions", self._pub, self._confirm)
        for interval, seconds in events.INTERVALS.items():
            self._schedule(interval, None, time.monotonic() + seconds)
        self.executor.call_later(0, self._heartbeat)

    def restore(self, saved: list[dict[str, Any]]) -> None:
        """Subscriptions of a previous worker (restart state); the expired ones are dropped."""
        offset = wall_minus_monotonic_ns()
        for item in saved:
            item = dict(item)
            expires_at_ns = item.pop("expires_at_ns", None)
            item.pop("deadline", None)
            try:
                sub = Subscription(**item)
            except TypeError:
                continue
            if not isinstance(expires_at_ns, int) or isinstance(expires_at_ns, bool):
                continue
            sub.deadline = (expires_at_ns - offset) / 1e9  # the wall clock is the one both workers share
            if sub.kind != "data" and self.feeds is None:  # feeds (rosworker/configurations/feed.py) not served here
                continue
            if sub.deadline > time.monotonic() and sub.interval in events.INTERVALS \
                    and len(self.subs) < self.max_subscriptions and self._held_by(sub.client) < self.max_per_client:
                self._add(sub)
        if self.subs:
            log.info("restored %d cyclic subscriptions from before the restart", len(self.subs))

    def saved(self) -> list[dict[str, Any]]:
        return [json.loads(r) for r in self._records.values()]

    def records(self) -> list[bytes]:
        """The restart records (JSON texts made at each change): a copy of references, O(n) pointers."""
        return list(self._records.values())

    def when_saved(self, then: Callable[[], None]) -> None:
        """Run ``then`` (a command's reply) once the latest change is written, or after SAVE_WAIT."""
        done = False
        timer: Timer | None = None

        def once() -> None:
            nonlocal done
            if not done:
                done = True
                if timer is not None:
                    timer.cancel()
                then()

        def late() -> None:
            log.warning("the restart state was not written within %g s; answering anyway", SAVE_WAIT)
            once()

        timer = self.executor.call_later(SAVE_WAIT, late)
        self._save(once)

    def close(self) -> None:
        if self._pub is not None:
            self._send([events.CONTROL_KEY + b"shutdown", protocol.pack({"event": "shutdown"})])
            self.executor.remove_reader(self._pub)
            self._pub.close(linger=200)
            self._pub = None

    # ---- commands ---------------------------------------------------------------------------
    def create(self, collection: str, entity_id: str, resource: str, topic: str, mode: str, interval: str,
               duration: int, client: str = "", kind: str = "data",
               target: dict[str, Any] | None = None) -> dict[str, Any]:
        if len(self.subs) >= self.max_subscriptions:
            raise IpcError("subscriptions-full",
                           f"The gateway already holds {self.max_subscriptions} cyclic subscriptions "
                           "(max_subscriptions); delete one or retry later",
                           {"max_subscriptions": self.max_subscriptions})
        if client and self._held_by(client) >= self.max_per_client:
            raise IpcError("subscriptions-full",
                           f"This client ({client}) already holds {self.max_per_client} cyclic subscriptions "
                           "(max_subscriptions_per_client); delete one or retry later",
                           {"max_subscriptions_per_client": self.max_per_client})
        sub = Subscription(id="sub_" + secrets.token_hex(8), collection=collection, entity_id=entity_id,
                           resource=resource, topic=topic, bytes=mode, interval=interval, duration=duration,
                           created_at_ns=time.time_ns(), client=client, deadline=time.monotonic() + duration,
                           kind=kind, target=target or {})
        if kind != "data":
            self.feeds.check(sub)  # the execution or parameter it names exists (else IpcError)
        self._add(sub)
        self.stats.subscriptions_created += 1
        self._save()
        return sub.wire()

    def get(self, collection: str, entity_id: str, sub_id: str) -> Subscription:
        """The subscription, if it belongs to this entity (else ``no-such-subscription``)."""
        sub = self.subs.get(sub_id)
        if sub is None or sub.collection != collection or sub.entity_id != entity_id:
            raise IpcError("no-such-subscription", "Subscription not found", {"subscription_id": sub_id})
        return sub

    def listing(self, collection: str, entity_id: str) -> list[dict[str, Any]]:
        return [s.wire() for s in sorted(self.subs.values(), key=lambda s: s.created_at_ns)
                if s.collection == collection and s.entity_id == entity_id]

    def update(self, collection: str, entity_id: str, sub_id: str, interval: str | None,
               duration: int | None) -> dict[str, Any]:
        sub = self.get(collection, entity_id, sub_id)
        self._unwatch(sub)
        if interval is not None:
            sub.interval = interval
        if duration is not None:
            sub.duration = duration
            sub.deadline = time.monotonic() + duration
            self._arm_expiry(sub)
        self._watch(sub)
        self._records[sub.id] = sub.record()
        self.version += 1
        self._control(sub, "updated")
        self._save()
        return sub.wire()

    def delete(self, collection: str, entity_id: str, sub_id: str) -> None:
        self._remove(self.get(collection, entity_id, sub_id), "deleted")

    def end(self, sub: Subscription) -> None:
        """A feed's subscription whose resource finished (rosworker/configurations/feed.py): it ends as an expiry does."""
        if self.subs.get(sub.id) is sub:
            self._remove(sub, "expired")

    def publish(self, key: bytes, meta: dict[str, Any], data: bytes = b"{}") -> None:
        """One frame on the events channel (the feeds' ticks)."""
        self._publish(key, meta, data)

    # ---- registry -------------------------------------------------------------------------
    def _held_by(self, client: str) -> int:
        return self.per_client.get(client, 0) if client else 0

    def _add(self, sub: Subscription) -> None:
        self.subs[sub.id] = sub
        self._records[sub.id] = sub.record()
        self.version += 1
        if sub.client:
            self.per_client[sub.client] = self.per_client.get(sub.client, 0) + 1
        self._watch(sub)
        self._arm_expiry(sub)
        self.stats.active_subscriptions = len(self.subs)

    def _remove(self, sub: Subscription, event: str) -> None:
        if self.subs.pop(sub.id, None) is None:
            return
        self._records.pop(sub.id, None)
        self.version += 1
        if sub.client:
            held = self.per_client.get(sub.client, 0) - 1
            if held > 0:
                self.per_client[sub.client] = held
            else:
                self.per_client.pop(sub.client, None)
        self._unwatch(sub)
        timer = self._expiry.pop(sub.id, None)
        if timer is not None:
            timer.cancel()
        self.stats.active_subscriptions = len(self.subs)
        self._control(sub, event)
        self._save()

    def _arm_expiry(self, sub: Subscription) -> None:
        old = self._expiry.pop(sub.id, None)
        if old is not None:
            old.cancel()
        delay = max(0.0, sub.deadline - time.monotonic())
        self._expiry[sub.id] = self.executor.call_later(delay, lambda: self._expire(sub))

    def _expire(self, sub: Subscription) -> None:
        if self.subs.get(sub.id) is not sub:
            return
        if sub.deadline > time.monotonic() + 0.001:  # woken early: arm again (never left unarmed)
            self._arm_expiry(sub)
            return
        self.stats.subscriptions_expired += 1
        self._remove(sub, "expired")

    def _watch(self, sub: Subscription) -> None:
        if sub.kind != "data":
            self.feeds.watch(sub)
            return
        watches = self.watches[sub.interval]
        watch = watches.get((sub.topic, sub.bytes))
        if watch is None:
            watch = watches[(sub.topic, sub.bytes)] = _Watch(sub.key)
            phase = self._phases.setdefault(sub.topic, _Phase())
            self._join(sub.interval, (sub.topic, sub.bytes), watch, phase.anchor)
        watch.count += 1

    def _unwatch(self, sub: Subscription) -> None:
        if sub.kind != "data":
            self.feeds.unwatch(sub)
            return
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

    # ---- phases ---------------------------------------------------------------------------
    def _join(self, interval: str, key: tuple[str, str], watch: _Watch, anchor: float | None) -> None:
        """Put ``watch`` in the tick group of ``anchor`` (None: the interval's grid)."""
        period = events.INTERVALS[interval]
        slot = None if anchor is None else int((anchor % period) * 1000)
        watch.slot = slot
        group = self._groups.get((interval, slot))
        if group is None:  # a new phase: its timer starts at the next tick time of the anchor
            group = self._groups[(interval, slot)] = {}
            now = time.monotonic()
            self._schedule(interval, slot, anchor + -(-(now - anchor) // period) * period)
        group[key] = watch

    def _leave(self, interval: str, key: tuple[str, str], watch: _Watch) -> None:
        group = self._groups.get((interval, watch.slot))
        if group is not None:
            group.pop(key, None)  # an empty phase group's timer ends at its next tick

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
        if slot is not None and not group:  # every watch of this phase left it: its timer ends
            self._groups.pop((interval, slot), None)
            return
        now = time.monotonic()
        following = scheduled + period
        if following <= now:  # late by more than a period: skip to the next slot ahead
            following = now + period - ((now - scheduled) % period)
        self._schedule(interval, slot, following)
        if not group or self._pub is None:
            return
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
        self._send([key, protocol.pack(meta), data])
        self.stats.frames_published += 1

    def _control(self, sub: Subscription, event: str) -> None:
        self._send([events.CONTROL_KEY + sub.id.encode(), protocol.pack({
            "event": event, "id": sub.id, "key": sub.key, "interval": sub.interval,
            "expires_in": max(0.0, sub.deadline - time.monotonic())})])

    def _heartbeat(self) -> None:
        self.executor.call_later(HEARTBEAT_EVERY, self._heartbeat)
        self._send([events.HEARTBEAT_KEY, protocol.pack({"pid": os.getpid(), "t": time.time_ns()})])

    def _confirm(self) -> None:
        """Each subscription an HTTP worker made is answered with a one-frame message of its prefix
        (``ipc/events.py``): the XPUB applies a subscription before it hands it over, so that message,
        and every frame of the prefix sent after it, reaches the subscriber."""
        for _ in range(CONFIRM_BATCH):
            try:
                message = self._pub.recv(zmq.NOBLOCK)
            except zmq.Again:
                return
            if len(message) > 1 and message[0] == 1:
                self.stats.subscriptions_confirmed += 1
                self._send([message[1:]])

    # Other pieces (faults: rosworker/faults/manager.py; triggers: rosworker/triggers/registry.py) send their events
    # on this channel too.
    def send(self, frames: list[bytes]) -> None:
        """Publish ``frames`` (a key, then its parts) on the events channel (ROS thread; never blocks;
        dropped when it is closed)."""
        self._send(frames)

    def _send(self, frames: list[bytes]) -> None:
        if self._pub is None:
            return
        try:
            send_frames(self._pub, frames)
        except zmq.ZMQError:
            pass  # PUB never blocks: a subscriber past its high-water mark misses this frame
