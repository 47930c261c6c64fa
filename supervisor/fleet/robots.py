"""The fleet gateway's robots: who is there, how they answer, and the fault events they sent.

:class:`Robots` is the table, bounded by ``fleet_max_robots``: a robot is taken in when its
liveliness token appears (``online``), kept while it is away (``offline``, its tree retained marked
unavailable) for ``fleet_forget_after`` seconds, and then forgotten.  Past the bound, the robot
away the longest makes room; with none away, a newcomer is refused and counted.  Everything the
merged tree, ``/health`` and ``/metrics`` say per robot is read from here, so their size is bounded
by the same number.

:class:`FaultEvents` takes each robot's fault events once (by the robot's own event ids, which its
fault store keeps across restarts), gives each a fleet-wide id and keeps the last ``KEEP`` of them
for ``Last-Event-ID``.  Fleet ids start at the link's start time in µs since the epoch (within
JavaScript's safe integers), so they only grow across restarts of the fleet gateway: a client that
comes back with an id from before a restart gets everything kept since.

Thread safety: Zenoh's callback threads, the refresher and the IPC threads all use these; each
class has one lock, held only while its data is read or changed.
"""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass, field
from typing import Any

ONLINE, OFFLINE = "online", "offline"
LATENCY_WEIGHT = 0.3     # of the newest answer in the smoothed latency


@dataclass
class Robot:
    name: str
    order: int
    state: str = ONLINE
    since: float = field(default_factory=time.time)        # when it came or went (wall clock)
    last_seen: float = field(default_factory=time.time)    # its last answer or token (wall clock)
    offline_at: float = 0.0                                # monotonic, when it went away
    tree: dict[str, Any] | None = None
    tree_bytes: int = 0
    tree_due: float = 0.0                                  # monotonic: read its tree at or after this
    tree_reading: bool = False
    tree_changes: int = 0                                  # changes announced (a read in flight may predate one)
    ping_due: float = 0.0
    latency_ms: float | None = None
    queries: int = 0
    failures: int = 0
    events: int = 0
    last_event: int | None = None                          # the newest of its event ids taken
    catching_up: bool = False

    @property
    def online(self) -> bool:
        return self.state == ONLINE

    def answered(self, seconds: float) -> None:
        ms = seconds * 1000.0
        self.latency_ms = ms if self.latency_ms is None else \
            (1 - LATENCY_WEIGHT) * self.latency_ms + LATENCY_WEIGHT * ms
        self.last_seen = time.time()

    def status(self) -> dict[str, Any]:
        """One entry of ``/health``'s ``peers`` (medkit's name, url, status, and the fleet's own)."""
        return {"name": self.name, "url": f"zenoh:sovd/{self.name}", "status": self.state,
                "since": round(self.since, 3), "last_seen": round(self.last_seen, 3),
                "latency_ms": None if self.latency_ms is None else round(self.latency_ms, 2),
                "entities": sum(len(v) for k, v in (self.tree or {}).items() if isinstance(v, list)),
                "queries": self.queries, "failures": self.failures}


class Robots:
    def __init__(self, max_robots: int, forget_after: float):
        self.max_robots = max_robots
        self.forget_after = forget_after          # 0: never
        self.lock = threading.Lock()
        self.by_name: dict[str, Robot] = {}
        self._order = 0
        self.refused = 0

    def came(self, name: str) -> Robot | None:
        """Its token appeared: the robot, new or back (None: refused, the table is full)."""
        with self.lock:
            robot = self.by_name.get(name)
            if robot is None:
                if len(self.by_name) >= self.max_robots and not self._make_room():
                    self.refused += 1
                    return None
                self._order += 1
                robot = self.by_name[name] = Robot(name, self._order)
            elif robot.state != ONLINE:
                robot.state, robot.since = ONLINE, time.time()
            robot.last_seen = time.time()
            robot.tree_due = robot.ping_due = 0.0
            return robot

    def went(self, name: str) -> Robot | None:
        with self.lock:
            robot = self.by_name.get(name)
            if robot is not None and robot.state == ONLINE:
                robot.state, robot.since, robot.offline_at = OFFLINE, time.time(), time.monotonic()
            return robot

    def _make_room(self) -> bool:
        away = [r for r in self.by_name.values() if r.state != ONLINE]
        if not away:
            return False
        del self.by_name[min(away, key=lambda r: r.offline_at).name]
        return True

    def forget_old(self) -> list[str]:
        if not self.forget_after:
            return []
        limit = time.monotonic() - self.forget_after
        with self.lock:
            gone = [n for n, r in self.by_name.items() if r.state != ONLINE and r.offline_at < limit]
            for name in gone:
                del self.by_name[name]
        return gone

    def get(self, name: str) -> Robot | None:
        return self.by_name.get(name)

    def snapshot(self) -> list[Robot]:
        with self.lock:
            return list(self.by_name.values())

    def online(self) -> list[Robot]:
        return [r for r in self.snapshot() if r.online]

    def per_robot(self) -> dict[str, dict[str, Any]]:
        """The maps of the ``fleet_robots`` section (``ipc/counters.py``): one entry per robot kept."""
        robots = self.snapshot()
        return {"robot_up": {r.name: int(r.online) for r in robots},
                "robot_latency_ms": {r.name: r.latency_ms for r in robots if r.latency_ms is not None},
                "robot_queries": {r.name: r.queries for r in robots},
                "robot_failures": {r.name: r.failures for r in robots},
                "robot_events": {r.name: r.events for r in robots}}


class FaultEvents:
    KEEP = 4096

    def __init__(self, keep: int = KEEP):
        self.lock = threading.Lock()
        self.kept: collections.deque[dict[str, Any]] = collections.deque(maxlen=keep)
        self.next_id = int(time.time() * 1_000_000)

    def take(self, robot: str, event: dict[str, Any]) -> dict[str, Any]:
        """A robot's event as the fleet sends it: a fleet id, and the fault named for its robot."""
        fault = event.get("fault")
        if isinstance(fault, dict):
            fault = attributed(fault, robot)
        with self.lock:
            self.next_id += 1
            taken = {"id": self.next_id, "event_type": event.get("event_type"), "fault": fault,
                     "timestamp": event.get("timestamp")}
            self.kept.append(taken)
        return taken

    def after(self, after: int) -> list[dict[str, Any]]:
        with self.lock:
            return [e for e in self.kept if e["id"] > after]


def attributed(item: dict[str, Any], robot: str) -> dict[str, Any]:
    """An item a robot sent (a fault, a data item ...) with ``x-medkit.contributors``: ``["peer:<robot>"]``."""
    out = dict(item)
    ext = dict(out["x-medkit"]) if isinstance(out.get("x-medkit"), dict) else {}
    ext["contributors"] = ["peer:" + robot]
    out["x-medkit"] = ext
    return out
