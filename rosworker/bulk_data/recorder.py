"""What led up to each fault: a ring buffer of the recorded topics' serialized messages (ROS thread).

The topics ``fault_rosbag_topics`` names are subscribed by this module alone, on the
ROS thread, with QoS matched to their publishers by the pool's rules (``qos.match_qos``)
and a deeper queue (``DEPTH``).  Like the pool's, these subscriptions are never spun: a
timer takes what came every ``DRAIN_EVERY`` s as CDR bytes (``take_message(..., raw=True)``,
no conversion) with the middleware's receive and source timestamps.  Each message goes
into the ring buffer: ``fault_rosbag_duration_s`` of messages (by receive time), at most
``fault_rosbag_max_buffer_mb`` of them; past the cap the oldest go first, counted in
``rosbag_buffer_drops``.

One subscription per topic.  A recorded topic that is also read over HTTP is not
subscribed twice: the pool (``rosworker/data/pool.py``, through ``core/topics.py``) asks :meth:`Recorder.shared_for` before
it subscribes, and reads the newest message through :class:`SharedSubscription`, whose
``take_message`` drains the recorder's subscription into the ring and hands the pool the
newest message it has not seen yet.  A topic pooled before its recorded subscription
existed is moved onto it (:meth:`TopicPool.adopt`).  A topic nobody records costs
nothing: with no topics named there is no subscription, no timer and no hook.

A confirmed fault (``FaultManager.on_confirmed``) takes the ring's messages and records
``fault_rosbag_duration_after_s`` more; then the recording goes to the writer thread
(``writer.py``), which writes the MCAP file.  Faults confirmed while a recording is open
join it (a burst shares one recording, as in medkit), up to ``MAX_ATTACHED`` more.  While a
recording is open, messages go into it instead of the ring (medkit's rule), so a fault
confirmed just after it closed gets what came after it only.

Graph changes are looked at every ``CHECK_EVERY`` s: a topic whose publishers appear is
subscribed, one whose type changes is subscribed anew (the old messages stay in the
ring, written under their own type), one whose publishers' QoS changes is re-subscribed
(the new subscription first).  A topic whose publishers leave keeps its subscription: the
messages before a driver died are what a recording is for.
"""

from __future__ import annotations

import collections
import logging
import time
from typing import Any

from rclpy.qos import QoSProfile

from ..ros import msgtypes, qos

log = logging.getLogger("sovd.rosworker.bulk_data")

DEPTH = 100             # messages a recorded subscription holds between two takes
DRAIN_EVERY = 0.05      # seconds between takes
TAKE_PER_ROUND = 2000   # messages taken per topic and round at most (40,000/s): a flood costs bounded time
CHECK_EVERY = 1.0       # seconds between looks at the recorded topics' publishers
MAX_ATTACHED = 32       # faults that join an open recording on top of the first (medkit's)
ENTRY_OVERHEAD = 120    # bytes counted per buffered message besides its CDR bytes
ID_CODE_CHARS = 120     # characters of the fault code in a recording id (a file name stays short)


class Tap:
    """One recorded topic and its subscription."""

    __slots__ = ("topic", "type_name", "cls", "sub", "profile", "channel", "newest", "fresh", "shared",
                 "problem")

    def __init__(self, topic: str):
        self.topic = topic
        self.type_name: str | None = None
        self.cls = None
        self.sub = None
        self.profile: QoSProfile | None = None
        self.channel: tuple[str, str] | None = None   # (topic, type): what a buffered message is written as
        self.newest: tuple[bytes, dict] | None = None  # the newest message, for the pool
        self.fresh = False                            # ... which the pool has not taken yet
        self.shared: SharedSubscription | None = None
        self.problem: str | None = None               # why it is not subscribed (logged once)


class SharedHandle:
    """The pool's view of a recorded subscription: ``take_message`` as on an rclpy handle."""

    __slots__ = ("_recorder", "_tap")

    def __init__(self, recorder: Recorder, tap: Tap):
        self._recorder = recorder
        self._tap = tap

    def take_message(self, _cls, _raw: bool = True):
        tap = self._tap
        self._recorder.drain_tap(tap)
        if not tap.fresh:
            return None
        tap.fresh = False
        return tap.newest

    def get_publisher_count(self) -> int:
        return self._tap.sub.handle.get_publisher_count() if self._tap.sub is not None else 0


class SharedSubscription:
    """What the pool keeps as its entry's subscription for a recorded topic (never destroyed by it)."""

    shared = True
    __slots__ = ("handle", "_tap")

    def __init__(self, handle: SharedHandle, tap: Tap):
        self.handle = handle
        self._tap = tap

    @property
    def profile(self) -> QoSProfile | None:
        return self._tap.profile

    @property
    def waitable(self):
        """The recorder's rclpy subscription (None while it has none): what the waiter waits on."""
        return self._tap.sub


class Ring:
    """Messages as taken, ``(received_ns, published_ns, channel, cdr)``, oldest first; bounded twice."""

    def __init__(self, window_ns: int, cap_bytes: int, stats):
        self.window_ns = window_ns
        self.cap_bytes = cap_bytes
        self.stats = stats
        self.items: collections.deque[tuple[int, int, tuple[str, str], bytes]] = collections.deque()
        self.nbytes = 0

    def add(self, item: tuple[int, int, tuple[str, str], bytes]) -> None:
        self.items.append(item)
        self.nbytes += len(item[3]) + ENTRY_OVERHEAD
        items = self.items
        # Older than the window (by the newest message's receive time: a quiet robot keeps its
        # last window, as in medkit), then past the byte cap (those are the drops).
        cutoff = item[0] - self.window_ns
        while items and items[0][0] < cutoff:
            self.nbytes -= len(items.popleft()[3]) + ENTRY_OVERHEAD
        while self.nbytes > self.cap_bytes and len(items) > 1:
            self.nbytes -= len(items.popleft()[3]) + ENTRY_OVERHEAD
            self.stats.rosbag_buffer_drops += 1
        self._publish()

    def take(self) -> list[tuple[int, int, tuple[str, str], bytes]]:
        """Everything buffered, oldest first; the ring is empty after."""
        out = list(self.items)
        self.items.clear()
        self.nbytes = 0
        self._publish()
        return out

    def _publish(self) -> None:
        self.stats.rosbag_buffer_bytes = self.nbytes
        self.stats.rosbag_buffer_messages = len(self.items)


class Recording:
    """One recording: its faults, and its messages (those of the ring, then those that come after)."""

    def __init__(self, recording_id: str, code: str, sources: list[str], created_ns: int,
                 items: list, cap_bytes: int, nbytes: int = 0):
        self.id = recording_id
        self.codes = [code]
        self.sources: dict[str, list[str]] = {code: list(sources)}
        self.created_ns = created_ns
        self.ended_ns = created_ns
        self.items = items          # in the order taken: each topic's in receive order (the writer merges them)
        self.nbytes = nbytes        # the ring's count (nothing is walked on the ROS thread)
        self.cap_bytes = cap_bytes

    def add(self, item, stats) -> bool:
        """Keep a message that came while the recording is open; False past the byte cap (a drop)."""
        size = len(item[3]) + ENTRY_OVERHEAD
        if self.nbytes + size > self.cap_bytes:
            stats.rosbag_buffer_drops += 1
            return False
        self.items.append(item)
        self.nbytes += size
        return True



class Recorder:
    """The recorded topics' subscriptions, the ring buffer and the open recording (ROS thread)."""

    def __init__(self, node, executor, stats, endpoints, shared, submit, *, topics: list[str],
                 duration_s: float, duration_after_s: float, max_buffer_bytes: int):
        self.node = node
        self.executor = executor
        self.stats = stats
        self.endpoints = endpoints
        self.shared = shared   # core/topics.py SharedTopics: the data family's pool reads through ours
        self.submit = submit            # hands a closed Recording to the writer thread; False: refused
        self.after_s = duration_after_s
        self.cap_bytes = max_buffer_bytes
        self.taps: dict[str, Tap] = {t: Tap(t) for t in dict.fromkeys(topics)}
        self.ring = Ring(int(duration_s * 1e9), max_buffer_bytes, stats)
        self.active: Recording | None = None
        self._close_timer = None
        stats.rosbag_topics_configured = len(self.taps)

    # ---- set-up and shutdown (ROS thread) ------------------------------------------------------
    def start(self) -> None:
        """Subscribe what can be, and look again every ``CHECK_EVERY`` s; nothing at all without topics."""
        if not self.taps:
            return
        self.shared.provide(self.shared_for)
        self.check()
        self._every(CHECK_EVERY, self.check)
        self._every(DRAIN_EVERY, self.drain)

    def _every(self, seconds: float, fn) -> None:
        def tick() -> None:
            if not self.executor.stopping:
                self.executor.call_later(seconds, tick)
            fn()
        self.executor.call_later(seconds, tick)

    def shutdown(self) -> None:
        """Close an open recording (the writer gets what it has) and unsubscribe (after the pool's shutdown)."""
        if self.active is not None:
            self._close()
        self.shared.provide(None)
        for tap in self.taps.values():
            self._unsubscribe(tap)

    # ---- subscriptions ------------------------------------------------------------------------
    def shared_for(self, topic: str, type_name: str | None) -> SharedSubscription | None:
        """The pool's hook: the recorded subscription of ``topic`` if it is of ``type_name`` (or of any
        type: None)."""
        tap = self.taps.get(topic)
        if tap is None or tap.sub is None or type_name not in (None, tap.type_name):
            return None
        return tap.shared

    def check(self) -> None:
        for tap in self.taps.values():
            self.executor.guarded(f"the recorded topic {tap.topic}", self._check_tap, tap)

    def _check_tap(self, tap: Tap) -> None:
        infos = self.endpoints.publishers(tap.topic)
        if not infos:
            return  # none yet, or gone: a subscription made stays (the last messages matter most)
        type_name = collections.Counter(i.topic_type for i in infos).most_common(1)[0][0]
        if tap.sub is not None and type_name != tap.type_name:
            log.info("recorded topic %s changed type %s -> %s: subscribing anew", tap.topic, tap.type_name,
                     type_name)
            self._unsubscribe(tap)
        same_type = [i for i in infos if i.topic_type == type_name]
        profile = qos.match_qos(same_type)
        profile.depth = DEPTH
        if tap.sub is not None and qos.key(profile) == qos.key(tap.profile):
            return
        if tap.sub is None:
            try:
                cls = msgtypes.load_type(type_name)
            except msgtypes.ConversionError as exc:
                self._problem(tap, f"its type {type_name} is not installed ({exc.message})")
                return
        else:
            cls = tap.cls
        try:
            sub = self.node.create_subscription(cls, tap.topic, _never_called, profile, raw=True)
        except Exception as exc:
            self._problem(tap, f"subscribing failed: {exc}")
            return
        old = tap.sub
        if old is not None:
            self.drain_tap(tap)  # what the old subscription still holds goes first
            log.info("re-subscribing the recorded topic %s with QoS matched to its publishers", tap.topic)
        tap.sub, tap.profile, tap.cls, tap.type_name, tap.problem = sub, profile, cls, type_name, None
        tap.channel = (tap.topic, type_name)
        if tap.shared is None:
            tap.shared = SharedSubscription(SharedHandle(self, tap), tap)
        if old is not None:
            self._destroy(old, tap.topic)
        else:
            self.stats.rosbag_topics_recorded += 1
            log.info("recording %s [%s] %s", tap.topic, type_name, qos.describe(profile))
        self.shared.adopted(tap.topic)

    def _problem(self, tap: Tap, why: str) -> None:
        if tap.problem != why:
            tap.problem = why
            log.warning("recorded topic %s: %s; it is left out of the recordings until that changes",
                        tap.topic, why)

    def _unsubscribe(self, tap: Tap) -> None:
        if tap.sub is None:
            return
        self.shared.unshared(tap.topic)
        sub, tap.sub, tap.type_name, tap.newest, tap.fresh = tap.sub, None, None, None, False
        self.stats.rosbag_topics_recorded -= 1
        self._destroy(sub, tap.topic)

    def _destroy(self, sub, topic: str) -> None:
        try:
            self.node.destroy_subscription(sub)
        except Exception:
            log.exception("destroying the recorded subscription of %s failed", topic)

    # ---- taking messages --------------------------------------------------------------------------
    def drain(self) -> None:
        for tap in self.taps.values():
            if tap.sub is not None:
                self.drain_tap(tap)

    def drain_tap(self, tap: Tap) -> None:
        """Take what ``tap``'s subscription holds into the ring (or the open recording)."""
        sub = tap.sub
        if sub is None:
            return
        take = sub.handle.take_message
        cls, channel, stats = tap.cls, tap.channel, self.stats
        for _ in range(TAKE_PER_ROUND):
            taken = take(cls, True)
            if taken is None:
                return
            raw, info = taken
            received = info.get("received_timestamp") or time.time_ns()
            item = (received, info.get("source_timestamp") or received, channel, raw)
            tap.newest, tap.fresh = taken, True
            stats.rosbag_messages += 1
            if self.active is not None:
                self.active.add(item, stats)
            else:
                self.ring.add(item)

    # ---- faults --------------------------------------------------------------------------------------
    def on_confirmed(self, code: str, sources: list[str]) -> None:
        """A fault was confirmed (the fault manager's hook, ROS thread)."""
        if not self.taps:
            return
        active = self.active
        if active is not None:  # a burst: the fault joins the open recording
            if code in active.codes:
                return
            if len(active.codes) > MAX_ATTACHED:
                self.stats.rosbag_faults_unattached += 1
                log.warning("fault %s confirmed while recording %s is open with %d faults already: it is in "
                            "that recording's data but not listed with it", code, active.id, len(active.codes))
                return
            active.codes.append(code)
            active.sources[code] = list(sources)
            return
        self.drain()  # what came up to the confirmation belongs to the history
        nbytes = self.ring.nbytes
        items = self.ring.take()
        if not items and self.after_s <= 0:
            log.warning("no message of the recorded topics buffered for fault %s and no time after it "
                        "(fault_rosbag_duration_after_s 0): no recording", code)
            return
        now = time.time_ns()
        recording = Recording(f"fault_{code[:ID_CODE_CHARS]}_{now // 1_000_000}", code, sources, now, items,
                              self.cap_bytes, nbytes)
        if not items:
            log.info("no pre-fault data buffered for fault %s: recording the %g s after it only", code,
                     self.after_s)
        if self.after_s > 0:
            self.active = recording
            self.stats.rosbag_recording_active = True
            self._close_timer = self.executor.call_later(self.after_s, self._close)
        else:
            self._hand_over(recording)

    def _close(self) -> None:
        recording, self.active = self.active, None
        self.stats.rosbag_recording_active = False
        if self._close_timer is not None:
            self._close_timer.cancel()
            self._close_timer = None
        if recording is None:
            return
        self.drain()  # what arrived up to the end of the window
        self._hand_over(recording)

    def _hand_over(self, recording: Recording) -> None:
        recording.ended_ns = time.time_ns()
        if not self.submit(recording):
            self.stats.rosbag_write_errors += 1
            log.error("recording %s (faults %s) dropped: the writer is still busy with earlier recordings",
                      recording.id, ", ".join(recording.codes))

    def status(self) -> dict[str, Any]:
        return {"topics": {t.topic: (t.type_name or "") for t in self.taps.values()},
                "active": self.active.id if self.active is not None else None}


def _never_called(_msg) -> None:  # pragma: no cover - recorded subscriptions are never spun
    pass
