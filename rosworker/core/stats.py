"""The ROS worker's counters: its ``stats`` answer, whose sections ``/health`` shows.

Which counters there are, their kinds and sections, is declared once in
``ipc/counters.py``; this class holds the values of those the ROS worker counts.

Counters are plain attributes written by the ROS thread, which also reads the
work socket and keeps the queue (``rosworker/core/executor.py``), and by the
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

from ipc import counters

# The stats answer, section by section, in the declared order (ipc/counters.py): the keys the
# ROS worker counts, and how each is read.  Two are computed at read time; the rest are attributes.
_COMPUTED = ("worker_alive", "current_task_age_ms")
_PLAN = tuple((name, tuple((c.name, c.kind) for c in counters.section(name, counters.ROS)))
              for name in counters.SECTIONS)


class Stats:
    """The ROS worker's counters: one attribute per counter of ``ipc/counters.py`` (zero at start)."""

    def __init__(self, pool_cap: int, cold_wait_cap: int, watchdog_threshold_ms: int):
        for c in counters.ROS_COUNTERS:
            if c.kind in (counters.COUNTER, counters.GAUGE, counters.FLAG) and c.name not in _COMPUTED:
                setattr(self, c.name, c.zero)
        self.pool_cap = pool_cap
        self.cold_wait_cap = cold_wait_cap
        self.watchdog_threshold_ms = watchdog_threshold_ms
        # details by cause; "x-medkit-data-provider" of /health shows them too
        self.evictions: dict[str, int] = dict.fromkeys(counters.EVICTION_CAUSES, 0)
        # queued commands: name -> [count, total µs on the ROS thread] (the names are a fixed set)
        self.commands: dict[str, list[int]] = {}
        self.ticks: dict[str, int] = {}  # stream timer rounds by interval
        self.phase_changes = 0  # tick phase per topic: times a topic's ticks were phased to its arrivals
        self.current_task_started = 0.0  # monotonic; 0 while idle
        # sections a family sends whole (faults: /health's x-medkit-faults), see set_section
        self.sections: dict[str, dict] = {}

    def set_section(self, name: str, part: dict) -> None:
        """A section of the stats answer that a family keeps as one dict (not counters of
        ``ipc/counters.py``): replaced whole, never changed in place (the control thread reads it)."""
        self.sections = {**self.sections, name: part}

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
        """The ``stats`` answer (the control thread: reads attributes, never waits)."""
        answer: dict = {}
        for name, keys in _PLAN:
            part = answer[name] = {}
            for key, kind in keys:
                if kind == counters.BY:
                    part[key] = dict(getattr(self, key))
                elif kind == counters.TIMINGS:  # a dict replaced, never resized, by the ROS thread
                    part[key] = {n: {"count": c, "time_us": t} for n, (c, t) in list(getattr(self, key).items())}
                elif key == "worker_alive":
                    part[key] = True
                elif key == "current_task_age_ms":
                    part[key] = self.current_task_age_ms()
                else:
                    part[key] = getattr(self, key)
        answer.update(self.sections)  # replaced whole by set_section, never changed in place
        return answer
