"""The ROS worker's counters: the two vendor sections of ``/health``.

Counters are plain attributes written by the ROS thread, which also reads the
work socket and keeps the queue (``rosworker/executor.py``), and by the
control thread (the frames it drops; the watchdog sets ``degraded`` and
counts ``watchdog_trips``, the ROS thread clears ``degraded``).  There is no
lock: each store is one attribute under the GIL, and ``ipc_dropped_frames``,
bumped by both threads, may at worst miss a count.  Reading them never waits
behind ROS work: ``snapshot()`` is called by the control thread
(``ipc/server.py``, ``ping``/``stats``) and only reads integers.
``current_task_age_ms`` is computed at read time from the start time of the
task that is running now.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field


@dataclass
class Stats:
    pool_cap: int
    cold_wait_cap: int
    watchdog_threshold_ms: int
    # x-medkit-data-provider
    pool_size: int = 0
    pool_hits: int = 0
    pool_misses: int = 0
    evictions_total: int = 0
    type_change_events: int = 0
    graph_events_received: int = 0
    concurrent_cold_waits: int = 0
    unsupported_type_count: int = 0
    undecodable_messages: int = 0
    pool_bytes: int = 0
    pool_bytes_cap: int = 0
    # x-medkit-subscription-executor
    degraded: bool = False
    queue_depth: int = 0
    queue_max_depth_observed: int = 0
    queue_dropped: int = 0
    tasks_completed: int = 0
    tasks_failed: int = 0
    last_task_latency_us: int = 0
    max_task_latency_us: int = 0
    watchdog_trips: int = 0
    loop_errors: int = 0
    # extra detail, reported under "x-medkit-details"
    evictions: dict = field(default_factory=lambda: {
        "graph": 0, "type_change": 0, "lru": 0, "idle": 0, "qos_rebuild": 0, "manual": 0, "shutdown": 0,
        "bytes": 0,
    })
    pool_json_drops: int = 0
    publishers_expired: int = 0
    publishes_waiting: int = 0
    publishers: int = 0
    publishes_total: int = 0
    ipc_dropped_frames: int = 0
    # queued commands: name -> [count, total µs on the ROS thread] (the names are a fixed set)
    commands: dict = field(default_factory=dict)
    current_task_started: float = 0.0  # monotonic; 0 while idle
    # cyclic subscriptions (rosworker/streams.py) and the HTTP workers' streams (their reports)
    max_subscriptions: int = 0
    active_subscriptions: int = 0
    subscriptions_created: int = 0
    subscriptions_expired: int = 0
    frames_published: int = 0
    ticks: dict = field(default_factory=dict)
    streams: dict = field(default_factory=lambda: {"open_streams": 0, "frames_sent": 0, "frames_dropped": 0})

    def task_started(self) -> float:
        now = time.monotonic()
        self.current_task_started = now
        return now

    def _command_totals(self, command: str) -> list[int]:
        totals = self.commands.get(command)
        if totals is None:
            # A new key: a new dict, so that snapshot() on the control thread never iterates a
            # dict that changes size under it (it iterates whichever dict it read).
            totals = [0, 0]
            self.commands = {**self.commands, command: totals}
        return totals

    def count_command(self, command: str) -> None:
        """One more answered ``command`` (ROS thread, before its reply is sent)."""
        self._command_totals(command)[0] += 1

    def task_finished(self, started: float, ok: bool, command: str | None = None, counted: bool = False) -> None:
        latency_us = int((time.monotonic() - started) * 1e6)
        self.current_task_started = 0.0
        if command is not None:
            totals = self._command_totals(command)
            if not counted:  # not answered yet (a reply that comes later): counted now
                totals[0] += 1
            totals[1] += latency_us
        self.last_task_latency_us = latency_us
        if latency_us > self.max_task_latency_us:
            self.max_task_latency_us = latency_us
        if ok:
            self.tasks_completed += 1
        else:
            self.tasks_failed += 1

    def current_task_age_ms(self, now: float | None = None) -> int:
        started = self.current_task_started
        if not started:
            return 0
        return max(0, int(((now or time.monotonic()) - started) * 1000))

    def check_watchdog(self) -> None:
        """Trip once per episode when the running task exceeds the threshold (control thread)."""
        if self.current_task_age_ms() > self.watchdog_threshold_ms and not self.degraded:
            self.degraded = True
            self.watchdog_trips += 1

    def snapshot(self) -> dict:
        return {
            "data_provider": {
                "pool_size": self.pool_size,
                "pool_cap": self.pool_cap,
                "pool_hits": self.pool_hits,
                "pool_misses": self.pool_misses,
                "evictions_total": self.evictions_total,
                "type_change_events": self.type_change_events,
                "graph_events_received": self.graph_events_received,
                "concurrent_cold_waits": self.concurrent_cold_waits,
                "cold_wait_cap": self.cold_wait_cap,
                "unsupported_type_count": self.unsupported_type_count,
                "undecodable_messages": self.undecodable_messages,
                "pool_bytes": self.pool_bytes,
                "pool_bytes_cap": self.pool_bytes_cap,
            },
            "executor": {
                "worker_alive": True,
                "degraded": self.degraded,
                "queue_depth": self.queue_depth,
                "queue_max_depth_observed": self.queue_max_depth_observed,
                "queue_dropped": self.queue_dropped,
                "tasks_completed": self.tasks_completed,
                "tasks_failed": self.tasks_failed,
                "last_task_latency_us": self.last_task_latency_us,
                "max_task_latency_us": self.max_task_latency_us,
                "current_task_age_ms": self.current_task_age_ms(),
                "watchdog_trips": self.watchdog_trips,
                "graph_events_received": self.graph_events_received,
                "loop_errors": self.loop_errors,
            },
            "streams": {
                "active_subscriptions": self.active_subscriptions,
                "max_subscriptions": self.max_subscriptions,
                **self.streams,
                "frames_published": self.frames_published,
                "subscriptions_created": self.subscriptions_created,
                "subscriptions_expired": self.subscriptions_expired,
            },
            "details": {
                "evictions": dict(self.evictions),
                "publishers": self.publishers,
                "publishes_total": self.publishes_total,
                "publishers_expired": self.publishers_expired,
                "publishes_waiting": self.publishes_waiting,
                "pool_json_drops": self.pool_json_drops,
                "ipc_dropped_frames": self.ipc_dropped_frames,
                "commands": {name: {"count": n, "time_us": t} for name, (n, t) in list(self.commands.items())},
                "ticks": dict(self.ticks),
            },
        }
