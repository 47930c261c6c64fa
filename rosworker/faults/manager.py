"""Faults: the robot's ``/diagnostics`` as SOVD faults, kept in the state dir's store (``store.py``).

One subscription to ``/diagnostics`` (``diagnostic_msgs/msg/DiagnosticArray``,
reliable, depth ``DEPTH``), no callback: the ROS thread takes at most
``TAKE_PER_ROUND`` arrays or ``STATUSES_PER_ROUND`` statuses when arrays come
(``core/batched.py``: woken by the first, then at most every ``TAKE_EVERY`` s
while they keep coming), and before each check of the timers, so a flood of arrays costs bounded time per round and the
commands queued meanwhile are answered between rounds (the rest wait in the
subscription's queue, whose depth bounds them: the oldest are dropped).

The mapping is medkit's diagnostic bridge's:

- level OK reports a pass (healing); WARN is severity 1, ERROR 2, STALE 3
  (CRITICAL);
- the fault code is the status name upper-cased, every run of other
  characters than letters and digits one ``_`` (``motor: Temperature`` ->
  ``MOTOR_TEMPERATURE``), or what ``fault_codes`` names for it;
- the reporting source: the node the status names, else a guess
  (``sources.py``).  A guess is replaced, not joined, by the first source the
  status itself names: one status is one source, not two.

The lifecycle (medkit's fault manager's states): a failing report makes a
new fault PREFAILED (``occurrence_count`` 1); it is CONFIRMED after
``fault_confirm_count`` failing reports or ``fault_confirm_s`` seconds of
failing, whichever comes first, or at once at severity CRITICAL; a passing
report makes it PREPASSED, and ``fault_heal_count`` passing reports HEALED.
A failing report on a HEALED fault makes it PREFAILED again, the same
occurrence; DELETE makes it CLEARED, and a failing report on a CLEARED fault
is a new occurrence (``occurrence_count`` + 1, ``first_occurred`` anew).
Reports that go on only advance ``last_occurred`` (medkit's edge counting).

Stale: a status that stops arriving for ``fault_stale_s`` seconds (a dead
driver) is reported failing at CRITICAL with the message "stale".  Silence is
judged against what has been taken: only up to the last moment the
subscription's queue was seen empty (a round that took everything), so a
status that arrived on time but waits in the queue (the ROS thread was busy,
a flood ran past a round's budget) is never stale.  ``seen`` (the time of
each status's last report) holds at most ``SEEN_PER_FAULT`` × ``max_faults``
statuses; past that the least recently reported one that is not a fault the
gateway holds goes, so every held fault can still go stale under a flood of
new names.

At confirmation freeze frames are taken (``snapshots.py``): the status's
key/value pairs, and the newest message of each topic that
``fault_snapshot_topics`` names for the code.

Each change of a confirmed fault is an event (``fault_confirmed``,
``fault_updated``, ``fault_cleared``): ``events.py`` numbers, keeps, stores,
publishes it and tells the observers of ``faults``.
"""

from __future__ import annotations

import collections
import logging
import time
from collections.abc import Callable
from typing import Any

from ipc.errors import IpcError

from ..core.batched import Batched
from .events import FaultEvents
from .model import (
    ACTIVE,
    CLEARED,
    CODE_MAX,
    CONFIRMED,
    HEALED,
    LABELS,
    PREFAILED,
    PREPASSED,
    STATUSES,
    TOPIC,
    TYPE,
    fault_code,
    level,
    parse_codes,
    public,
)
from .observable import FaultObservable
from .snapshots import FreezeFrames
from .sources import Attribution
from .store import FaultTables

log = logging.getLogger("sovd.rosworker.faults")

DEPTH = 100                # arrays the subscription holds between two takes
TAKE_EVERY = 0.05          # seconds between two takes
TAKE_PER_ROUND = 20        # arrays taken per round at most ...
STATUSES_PER_ROUND = 500   # ... and statuses: a round stays short (tens of ms) whatever is sent; past
                           # that the subscription's queue (DEPTH) drops the oldest arrays
STATUSES_PER_ARRAY = 1000  # statuses of one array looked at, at most
TICK_EVERY = 0.1           # seconds between checks of the timers (confirm by time, stale), at least ...
TICK_IDLE = 1.0            # ... and at most (nothing can confirm or go stale sooner)
PERSIST_EVERY = 1.0        # seconds between writes of a fault whose status did not change
SEEN_PER_FAULT = 2         # statuses whose last report is kept: this many per max_faults
SOURCES_MAX = 16           # reporting sources kept per fault
VALUES_MAX = 64            # key/value pairs of a status kept for its freeze frame
VALUE_CHARS = 1024
REFUSED_LOG_EVERY = 60.0


class FaultManager:
    """Every fault, on the ROS thread; the store writes them on its own thread."""

    def __init__(self, node, executor, samplers, stats, store: FaultTables, *, graph=None, endpoints=None,
                 send: Callable[[list[bytes]], None] = lambda frames: None, confirm_count: int = 3,
                 confirm_s: float = 1.0, heal_count: int = 3, stale_s: float = 10.0, max_faults: int = 1000,
                 codes: str = "", snapshot_topics: str = ""):
        self.node = node
        self.executor = executor
        self.stats = stats
        self.store = store
        self.attribution = Attribution(node, graph, endpoints)
        self.frames = FreezeFrames(samplers, snapshot_topics)
        self.confirm_count = confirm_count
        self.confirm_s = confirm_s
        self.heal_count = heal_count
        self.stale_s = stale_s
        self.max_faults = max_faults
        self.codes = parse_codes(codes)
        self.faults: dict[str, dict[str, Any]] = {}
        # code -> [monotonic last report, status name, source, stale already reported, source guessed]
        self.seen: collections.OrderedDict[str, list] = collections.OrderedDict()
        self.values: dict[str, dict[str, Any]] = {}       # code -> the last failing status (freeze frame)
        self._dirty: dict[str, float] = {}                 # code -> monotonic of the last write
        self._unwritten: set[str] = set()
        self._code_cache: dict[str, str] = {}
        self._refused_logged = -REFUSED_LOG_EVERY
        self.sub = None
        self.cls = None
        self.arrays = 0
        self.refused = 0
        self._drained = time.monotonic()  # the last moment the subscription's queue was seen empty
        self._flushed = False             # the last check wrote faults whose times changed
        # faults as an observable collection (triggers; core/notifier.py): told of every fault event
        self.observable = FaultObservable(stats)
        self.events = FaultEvents(executor, store, send, self.observable)
        self.left: dict[str, Any] = {}  # /health's counts of the faults left by absent nodes (left.py)
        # the extension points "fault_confirmed" and "fault_snapshots" (core/family.py Core.extend; the
        # faults family hands their lists here): fn(code, sources) told of each confirmation, and
        # fn(code) -> a fault's extra snapshots (bulk data's recordings: type rosbag, newest first)
        self.on_confirmed: list[Callable[[str, list[str]], None]] = []
        self.snapshot_sources: list[Callable[[str], list[dict[str, Any]]]] = []
        self.publish_stats()

    # ---- set-up (ROS thread, before the loop) -------------------------------------------------------
    def load(self) -> None:
        faults, events = self.store.load()
        now = time.monotonic()
        for code, record in faults.items():
            if isinstance(record, dict) and record.get("status") in STATUSES and record.get("code") == code:
                self.faults[code] = record
                if record["status"] in ACTIVE:
                    # reported again, or stale after fault_stale_s: a driver that died with the gateway
                    self.seen[code] = [now, record.get("name", code), (record.get("sources") or [TOPIC])[0], False,
                                       bool(record.get("guessed"))]
        self.events.load(events)
        self.publish_stats()

    def start(self) -> None:
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from ..ros import msgtypes

        self.executor.call_later(TICK_EVERY, self._tick_round)
        Batched(self.executor, TOPIC, lambda: self.sub, self._take_round, TAKE_EVERY)
        try:
            self.cls = msgtypes.load_type(TYPE)
            self.sub = self.node.create_subscription(self.cls, TOPIC, lambda _msg: None,
                                                     QoSProfile(depth=DEPTH, reliability=ReliabilityPolicy.RELIABLE))
        except Exception as exc:  # diagnostic_msgs missing or broken: the gateway still serves the rest
            log.error("faults: cannot subscribe to %s (%s): no new faults are seen; the stored ones are "
                      "still served", TOPIC, exc)
            return

    def shutdown(self) -> None:
        """Hand what is not written yet to the store (which the caller closes) and unsubscribe."""
        self._flush(force=True)
        if self.sub is not None:
            self.node.destroy_subscription(self.sub)
            self.sub = None

    # ---- the timers ------------------------------------------------------------------------------------
    def _take_round(self) -> int:
        """Take what came (within the round's budget); how many arrays were taken."""
        if self.sub is None:
            return 0
        statuses = 0
        arrays = 0
        for _ in range(TAKE_PER_ROUND):
            taken = self.sub.handle.take_message(self.cls, False)
            if taken is None:
                self._drained = time.monotonic()  # everything that came before now has been taken
                break
            self.arrays += 1
            arrays += 1
            statuses += len(taken[0].status)
            self.executor.guarded("a /diagnostics array", self.on_array, taken[0])
            if statuses >= STATUSES_PER_ROUND:
                break
        return arrays

    def _tick_round(self) -> None:
        self._take_round()  # what waits in the queue first: silence is judged against what was taken
        now = time.monotonic()
        self.tick(now if self.sub is None else min(now, self._drained))
        self.executor.call_later(self._next_tick(now), self._tick_round)

    def _next_tick(self, now: float) -> float:
        """Seconds to the next check: the first confirmation, staleness or due write that can come, within
        [``TICK_EVERY``, ``TICK_IDLE``] (a quiet robot's gateway wakes once a second for its faults)."""
        if any(record["status"] == PREFAILED for record in self.faults.values()) or self._flushed:
            self._flushed = False  # written just now: /health shows the store caught up at the next check
            return TICK_EVERY
        first = now + TICK_IDLE
        for code in self._unwritten:  # a fault whose times changed is written PERSIST_EVERY after its last write
            first = min(first, self._dirty.get(code, 0.0) + PERSIST_EVERY)
        if self.stale_s:
            first = min(first, now + self.stale_s / 4)  # a status first seen after this check
            for seen in self.seen.values():
                if not seen[3]:
                    first = min(first, seen[0] + self.stale_s)
        return max(TICK_EVERY, first - now)

    def tick(self, now: float) -> None:
        """Confirm by time; report as stale what has not been reported for ``stale_s`` s before ``now``
        (the last moment everything that arrived had been taken, see the module's docstring)."""
        wall = time.time_ns()
        for record in list(self.faults.values()):
            if record["status"] == PREFAILED and wall - record["since_ns"] >= self.confirm_s * 1e9:
                self._confirm(record, wall)
        if self.stale_s:
            for code, seen in list(self.seen.items()):
                if not seen[3] and now - seen[0] >= self.stale_s:
                    seen[3] = True
                    if seen[4]:  # its source was a guess: the graph may know the node its name names by now
                        seen[2], seen[4] = self.attribution.source_of(seen[1], "", lambda seen=seen: seen[2])
                    self._failed(code, seen[1], 3, f"stale: no report for {self.stale_s:g} s", seen[2], None,
                                 wall, stale=True, guessed=seen[4])
        self._flush()
        self.publish_stats()

    # ---- reports ---------------------------------------------------------------------------------------
    def on_array(self, msg) -> None:
        now, wall = time.monotonic(), time.time_ns()
        for status in msg.status[:STATUSES_PER_ARRAY]:
            name = status.name[:CODE_MAX]
            code = self._code(name)
            if not code:
                continue
            source, guessed = self.attribution.source(status)
            seen = self.seen.get(code)
            if seen is None:
                self._make_room_in_seen()
                self.seen[code] = [now, name, source, False, guessed]
            else:
                seen[0], seen[1], seen[2], seen[3], seen[4] = now, name, source, False, guessed
                self.seen.move_to_end(code)
            status_level = level(status.level)
            if status_level == 0:
                self._passed(code, wall)
                continue
            values = {"level": status_level, "name": name, "message": status.message[:VALUE_CHARS],
                      "hardware_id": status.hardware_id[:VALUE_CHARS],
                      "values": {kv.key[:VALUE_CHARS]: kv.value[:VALUE_CHARS] for kv in status.values[:VALUES_MAX]}}
            self._failed(code, name, min(status_level, 3), status.message[:VALUE_CHARS], source, values, wall,
                         guessed=guessed)

    def _make_room_in_seen(self) -> None:
        """At the cap, the least recently reported status that is not a fault held goes (held ones are
        passed over: they stay watched for staleness; there are at most ``max_faults`` of them)."""
        cap = SEEN_PER_FAULT * max(self.max_faults, 1)
        passed_over = 0
        while len(self.seen) >= cap and passed_over < len(self.seen):
            code, entry = self.seen.popitem(last=False)
            if code in self.faults:
                self.seen[code] = entry  # to the end; its time is in the entry, not in the order
                passed_over += 1

    def _code(self, name: str) -> str:
        code = self._code_cache.get(name)
        if code is None:
            code = self.codes.get(name) or fault_code(name)
            if len(self._code_cache) >= 4096:
                self._code_cache.clear()
            self._code_cache[name] = code
        return code

    def _failed(self, code: str, name: str, severity: int, message: str, source: str,
                values: dict[str, Any] | None, wall: int, stale: bool = False, guessed: bool = False) -> None:
        record = self.faults.get(code)
        changed = False
        if record is None:
            if not self._room():
                return
            record = self.faults[code] = {
                "code": code, "name": name, "severity": severity, "description": message, "first_ns": wall,
                "last_ns": wall, "passed_ns": 0, "count": 1, "status": PREFAILED, "sources": [source],
                "snapshots": [], "fails": 1, "oks": 0, "since_ns": wall, "confirmed": False, "guessed": guessed}
            self.frames.warm(code)
            changed = True
        elif record["status"] == CLEARED:  # reported again after a clear: a new occurrence (medkit's)
            record.update(status=PREFAILED, first_ns=wall, fails=1, oks=0, since_ns=wall, confirmed=False,
                          count=min(record["count"] + 1, 2**32 - 1))
            self.frames.warm(code)
            changed = True
        elif record["status"] == HEALED:  # failing again after it healed: the same occurrence
            record.update(status=PREFAILED, fails=1, oks=0, since_ns=wall, confirmed=False)
            self.frames.warm(code)
            changed = True
        elif record["status"] == PREPASSED:
            record.update(oks=0, fails=record["fails"] + 1,
                          status=CONFIRMED if record["confirmed"] else PREFAILED)
            if not record["confirmed"]:
                record["since_ns"] = wall
            changed = True
        else:
            record["fails"] = min(record["fails"] + 1, 2**31)
        if record["severity"] != severity or record["description"] != message:
            changed = changed or record["status"] == CONFIRMED
            record["severity"], record["description"] = severity, message
        if record.get("guessed", record["sources"] == [TOPIC]):
            # The first reports came before the graph knew their node (DDS delivers a status before the
            # node's name is discovered): the node the status names replaces the guess, and the only
            # publisher replaces the topic; one guess never replaces another.
            if not guessed or record["sources"] == [TOPIC]:
                changed = changed or record["sources"] != [source]
                record["sources"], record["guessed"] = [source], guessed
        elif not guessed and source not in record["sources"] and len(record["sources"]) < SOURCES_MAX:
            record["sources"] = [*record["sources"], source]  # a guess adds nothing to named sources
            changed = True
        record["last_ns"] = wall
        record["name"] = name
        if values is not None:
            self.values[code] = values
        if record["status"] == PREFAILED and (record["fails"] >= self.confirm_count or severity >= 3
                                              or wall - record["since_ns"] >= self.confirm_s * 1e9):
            self._confirm(record, wall, stale)
            return
        if changed:
            if record["confirmed"]:
                self.events.add("fault_updated", record)
            self._write(code)
        else:
            self._unwritten.add(code)

    def _passed(self, code: str, wall: int) -> None:
        record = self.faults.get(code)
        if record is None or record["status"] in (HEALED, CLEARED):
            return
        record["passed_ns"] = wall
        record["oks"] = 1 if record["status"] != PREPASSED else record["oks"] + 1
        before = record["status"]
        record["status"] = HEALED if record["oks"] >= self.heal_count else PREPASSED
        if record["status"] != before:
            if record["confirmed"]:
                self.events.add("fault_updated", record)
            self._write(code)
        else:
            self._unwritten.add(code)

    def _confirm(self, record: dict[str, Any], wall: int, stale: bool = False) -> None:
        record["status"] = CONFIRMED
        record["confirmed"] = True
        record["snapshots"] = self.frames.take(record, self.values.get(record["code"]), wall, stale)
        self.events.add("fault_confirmed", record)
        self._write(record["code"])
        for fn in self.on_confirmed:  # e.g. bulk data: what led up to it is recorded
            self.executor.guarded("the fault's confirmation hook", fn, record["code"], list(record["sources"]))

    def _room(self) -> bool:
        """Room for one more fault: the oldest healed or cleared one goes at ``max_faults``."""
        if len(self.faults) < self.max_faults:
            return True
        done = [r for r in self.faults.values() if r["status"] in (HEALED, CLEARED)]
        if done:
            oldest = min(done, key=lambda r: r["last_ns"])
            del self.faults[oldest["code"]]
            self.values.pop(oldest["code"], None)
            self._dirty.pop(oldest["code"], None)
            self._unwritten.discard(oldest["code"])
            self.store.put(oldest["code"], None)
            return True
        self.refused += 1
        now = time.monotonic()
        if now - self._refused_logged >= REFUSED_LOG_EVERY:
            self._refused_logged = now
            log.warning("max_faults (%d) active faults held: a new fault is not recorded (%d refused so far); "
                        "raise max_faults or clear faults", self.max_faults, self.refused)
        return False

    # ---- writes -----------------------------------------------------------------------------------------
    def _write(self, code: str, changed: bool = True) -> None:
        self._unwritten.discard(code)
        self._dirty[code] = time.monotonic()
        self.store.put(code, self.faults[code])
        if changed:  # a status changed: /health shows it at once
            self.publish_stats()

    def _flush(self, force: bool = False) -> None:
        """Write the faults whose last report changed only their times, at most every PERSIST_EVERY s."""
        now = time.monotonic()
        for code in list(self._unwritten):
            if code in self.faults and (force or now - self._dirty.get(code, 0.0) >= PERSIST_EVERY):
                self._write(code, changed=False)
                self._flushed = True
            elif code not in self.faults:
                self._unwritten.discard(code)

    def publish_stats(self) -> None:
        by_severity = dict.fromkeys(LABELS.values(), 0)
        active = confirmed = 0
        for record in self.faults.values():
            if record["status"] in ACTIVE:
                active += 1
                by_severity[LABELS.get(record["severity"], "ERROR")] += 1
            if record["status"] == CONFIRMED:
                confirmed += 1
        store = self.store.store
        self.stats.set_section("faults", {  # replaced whole: the control thread reads it (core/stats.py)
            "active": active, "confirmed": confirmed, "store_size": len(self.faults),
            "max_faults": self.max_faults, "refused": self.refused, "active_by_severity": by_severity,
            "diagnostics_arrays": self.arrays, "store_enabled": store.enabled, "store_path": store.path,
            "store_writes": store.writes, "store_write_errors": store.write_errors,
            "store_pending": store.pending + len(self._unwritten),
            "last_write_error": store.last_write_error, "moved_aside": store.moved_aside, **self.left,
        })

    # ---- commands ---------------------------------------------------------------------------------------
    def listing(self, statuses: list[str]) -> list[dict[str, Any]]:
        wanted = set(statuses)
        return [public(self.faults[c]) for c in sorted(self.faults) if self.faults[c]["status"] in wanted]

    def get(self, code: str) -> dict[str, Any]:
        record = self.faults.get(code)
        if record is None:
            raise IpcError("no-such-fault", "Fault not found", {"fault_code": code[:CODE_MAX]})
        snapshots = list(record["snapshots"])
        for fn in self.snapshot_sources:  # e.g. its recordings (bulk data), as medkit lists them
            snapshots += fn(code)
        return {"fault": public(record), "snapshots": snapshots,
                "first_ns": record["first_ns"], "last_ns": record["last_ns"]}

    def clear(self, codes: list[str]) -> list[str]:
        cleared = []
        wall = time.time_ns()
        for code in codes:
            record = self.faults.get(code)
            if record is None or record["status"] == CLEARED:
                continue
            record.update(status=CLEARED, fails=0, oks=0, confirmed=False, cleared_ns=wall)
            self.events.add("fault_cleared", record)
            self._write(code, changed=False)  # /health once, below
            cleared.append(code)
        if cleared:
            self.publish_stats()
        return cleared

    def events_after(self, after: int) -> list[dict[str, Any]]:
        return self.events.after(after)

    @property
    def next_event_id(self) -> int:
        return self.events.next_id


