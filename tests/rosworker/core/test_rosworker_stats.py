"""rosworker/core/stats.py: the shape of ``snapshot()`` (what ``stats`` answers), and the counters behind it.

In-process.  What the HTTP side makes of a snapshot (``/health``, ``/metrics``)
is checked in tests/app/core/test_app_root.py and tests/app/core/test_app_metrics.py, and a real
worker's counters throughout tests/rosworker/*/test_rosworker_*.py; that a snapshot never
fails while the ROS thread counts is in tests/rosworker/core/test_rosworker_control.py.
"""

from __future__ import annotations

import time

from ipc import counters
from rosworker.core.stats import Stats

SECTIONS = set(counters.SECTIONS)  # the declared sections, each in the answer
NOT_REPORTED = {"watchdog_threshold_ms", "current_task_started"}  # a setting, and a clock reading


def stats() -> Stats:
    return Stats(pool_cap=8, cold_wait_cap=2, watchdog_threshold_ms=100)  # as rosworker/main.py builds it


def leaves(tree: dict, path: tuple = ()):
    for key, value in tree.items():
        if isinstance(value, dict):
            yield from leaves(value, (*path, key))
        else:
            yield (*path, key), value


def test_a_snapshot_has_the_declared_sections_of_plain_numbers_and_flags():
    snap = stats().snapshot()
    assert set(snap) == SECTIONS
    found = list(leaves(snap))
    assert found
    for path, value in found:
        assert type(value) in (int, bool), (path, value)  # msgpack-able, and what /metrics can read
    # A fresh worker: nothing counted yet, the caps as configured, alive.
    assert snap["data_provider"]["pool_cap"] == 8 and snap["data_provider"]["cold_wait_cap"] == 2
    assert snap["executor"]["worker_alive"] is True and snap["executor"]["degraded"] is False
    assert all(v == 0 for p, v in found if p not in {("data_provider", "pool_cap"), ("data_provider", "cold_wait_cap"),
                                                     ("executor", "worker_alive")}), found


def test_every_counter_is_reported_under_its_own_name():
    """A counter added to Stats and forgotten in snapshot() fails here."""
    s = stats()
    numbers = {}
    ints = sorted(name for name, value in vars(s).items()
                  if name not in NOT_REPORTED and type(value) is int)  # every counter attribute
    for n, name in enumerate(ints):
        numbers[name] = 1000 + n
        setattr(s, name, 1000 + n)
    assert len(numbers) > 30
    reported = {path[-1]: value for path, value in leaves(s.snapshot())}
    for name, value in numbers.items():
        assert reported.get(name) == value, name
    # graph_events_received is reported in both sections that medkit has it in
    snap = s.snapshot()
    assert snap["data_provider"]["graph_events_received"] == snap["executor"]["graph_events_received"]


def test_the_dictionaries_are_reported_and_copied():
    s = stats()
    s.evictions["lru"] = 3
    s.ticks["fast"] = 7
    snap = s.snapshot()
    assert snap["details"]["evictions"]["lru"] == 3
    assert set(snap["details"]["evictions"]) == {"graph", "type_change", "lru", "idle", "qos_rebuild", "manual",
                                                 "shutdown", "bytes"}
    assert snap["details"]["ticks"] == {"fast": 7}
    # The HTTP workers' stream counters are theirs (summed from /metrics' files), never the ROS worker's.
    assert not {"open_streams", "frames_sent", "frames_dropped"} & set(snap["streams"])
    snap["details"]["evictions"]["lru"] = 99   # the answer is the caller's: the counters stay
    snap["details"]["ticks"]["fast"] = 99
    assert s.evictions["lru"] == 3 and s.ticks["fast"] == 7


def test_commands_are_counted_with_their_time_on_the_ros_thread():
    s = stats()
    for _ in range(3):
        s.task_finished(s.task_started(), True, "sample")
    s.count_command("publish")                                   # answered first...
    s.task_finished(s.task_started(), False, "publish", counted=True)  # ...then finished: not twice
    s.task_finished(s.task_started(), True)                      # a timer: no command
    commands = s.snapshot()["details"]["commands"]
    assert set(commands) == {"sample", "publish"}
    assert commands["sample"]["count"] == 3 and commands["publish"]["count"] == 1
    assert all(c["time_us"] >= 0 for c in commands.values())
    executor = s.snapshot()["executor"]
    assert (executor["tasks_completed"], executor["tasks_failed"]) == (4, 1)
    assert executor["current_task_age_ms"] == 0  # idle


def test_the_running_tasks_age_and_the_watchdog_trip_once_per_episode():
    s = stats()
    s.current_task_started = time.monotonic() - 0.5  # a task running for half a second (threshold 100 ms)
    assert s.snapshot()["executor"]["current_task_age_ms"] >= 500
    s.check_watchdog()
    s.check_watchdog()
    snap = s.snapshot()["executor"]
    assert snap["degraded"] is True and snap["watchdog_trips"] == 1
    s.task_finished(s.current_task_started, True)  # the task ends; the executor clears `degraded` when idle
    s.degraded = False
    s.current_task_started = time.monotonic() - 0.5  # a second episode
    s.check_watchdog()
    assert s.snapshot()["executor"]["watchdog_trips"] == 2
    assert s.snapshot()["executor"]["max_task_latency_us"] >= 500_000
