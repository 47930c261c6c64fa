"""rosworker/core/writer.py: the one latest-state writer thread (restart state, store, running goals).

The real thread, a ``write`` that records what it was handed and can be made slow (a gate) or fail.
Its users' own rules are tested with them: test_rosworker_state.py, test_rosworker_faults.py (the
store), tests/rosworker/operations/test_rosworker_operations.py (the goals' record).
"""

from __future__ import annotations

import threading

from common.harness.procs import poll_until
from rosworker.core.writer import LatestWriter, once_written


class Disk:
    """``write``: records each batch; waits for ``gate`` while it is closed; fails ``fail`` times."""

    def __init__(self, fail: int = 0):
        self.batches: list[dict] = []
        self.entered = 0          # writes begun (before the gate)
        self.gate = threading.Event()
        self.gate.set()
        self.fail = fail

    def write(self, batch: dict) -> None:
        self.entered += 1
        assert self.gate.wait(10), "the test never opened the gate"
        if self.fail:
            self.fail -= 1
            raise OSError("disk full")
        self.batches.append(dict(batch))


def test_a_key_written_once_with_its_latest_value_and_each_then_after_its_write():
    disk = Disk()
    posted: list[str] = []
    writer = LatestWriter("w", disk.write, post=lambda fn: (posted.append(threading.current_thread().name), fn()))
    writer.start()
    answered: list[str] = []
    try:
        disk.gate.clear()
        writer.submit("a", 1, lambda: answered.append("a1"))
        poll_until(lambda: disk.entered == 1, 5, message="the first batch under way")  # held at the gate
        writer.submit("a", 2, lambda: answered.append("a2"))
        writer.submit("b", 1, lambda: answered.append("b1"))
        writer.submit("a", 3)
        assert answered == []
        disk.gate.set()
        poll_until(lambda: len(answered) == 3, 5, message="every caller answered")
        assert disk.batches == [{"a": 1}, {"a": 3, "b": 1}]   # a=2 never written: a=3 is newer
        assert answered == ["a1", "a2", "b1"] and set(posted) == {"w"}
        assert writer.writes == 2 and writer.pending == 0
    finally:
        writer.close(5)


def test_after_waits_for_what_was_submitted_and_runs_at_once_when_nothing_waits():
    disk = Disk()
    writer = LatestWriter("w", disk.write)
    writer.start()
    try:
        done: list[int] = []
        writer.after(lambda: done.append(1))
        assert done == [1]                        # nothing pending: at once, on this thread
        disk.gate.clear()
        writer.submit("a", 1)
        writer.after(lambda: done.append(2))
        assert done == [1]
        disk.gate.set()
        poll_until(lambda: done == [1, 2], 5, message="after the write")
    finally:
        writer.close(5)


def test_a_failed_write_is_tried_again_with_what_is_newer_and_then_waits_for_it(monkeypatch):
    disk = Disk(fail=1)
    errors: list[Exception] = []
    writer = LatestWriter("w", disk.write, retry_after=0.05, on_error=errors.append)
    writer.start()
    answered = threading.Event()
    try:
        disk.gate.clear()
        writer.submit("a", 1, answered.set)
        poll_until(lambda: disk.entered == 1, 5, message="the batch under way")
        writer.submit("a", 2)                     # newer than what is failing now
        disk.gate.set()
        assert answered.wait(5)
        assert [str(e) for e in errors] == ["disk full"] and writer.errors == 1
        assert "disk full" in writer.last_error
        poll_until(lambda: disk.batches == [{"a": 2}], 5, message="written once, the newest value")
    finally:
        writer.close(5)


def test_without_retry_a_failed_batch_is_dropped_and_its_callers_answered():
    disk = Disk(fail=1)
    writer = LatestWriter("w", disk.write, on_error=lambda exc: None)
    writer.start()
    answered = threading.Event()
    try:
        writer.submit("a", 1, answered.set)
        assert answered.wait(5) and writer.errors == 1 and disk.batches == []
    finally:
        writer.close(5)


def test_keep_bounds_what_waits_while_the_disk_fails():
    disk = Disk(fail=1000)

    def keep(pending: dict) -> None:
        for key in sorted(pending)[:-3]:
            del pending[key]

    writer = LatestWriter("w", disk.write, retry_after=0.01, on_error=lambda exc: None, keep=keep)
    writer.start()
    try:
        for i in range(50):
            writer.submit(i, i)
        poll_until(lambda: writer.errors >= 3, 5, message="failing")
        assert writer.pending <= 4  # the three newest, and the batch being tried
    finally:
        disk.fail = 0
        writer.close(5)
    assert disk.batches and set(disk.batches[-1]) <= {47, 48, 49}


def test_before_start_and_after_close_a_submit_writes_on_the_callers_thread():
    disk = Disk()
    writer = LatestWriter("w", disk.write, post=lambda fn: (_ for _ in ()).throw(AssertionError("posted")))
    answered: list[int] = []
    writer.submit("a", 1, lambda: answered.append(1))
    assert disk.batches == [{"a": 1}] and answered == [1]
    writer.start()
    assert writer.close(5)
    writer.submit("b", 2, lambda: answered.append(2))
    assert disk.batches[-1] == {"b": 2} and answered == [1, 2]


def test_once_written_answers_once_when_written_or_after_the_wait():
    class Executor:
        def __init__(self):
            self.timers = []

        def call_later(self, delay, fn):
            timer = type("T", (), {"cancelled": False, "cancel": lambda self: setattr(self, "cancelled", True)})()
            self.timers.append((delay, fn, timer))
            return timer

    executor = Executor()
    answered: list[int] = []
    written = once_written(executor, lambda: answered.append(1), 1.0)
    written()
    written()
    assert answered == [1] and executor.timers[0][2].cancelled  # once, and the late answer cancelled
    late = once_written(executor, lambda: answered.append(2), 1.0, "the state")
    executor.timers[1][1]()   # the wait passed first (a slow disk)
    late()
    assert answered == [1, 2]
