"""A settable wall-clock step for every Python process of a test gateway (an NTP step, in effect).

``tests/support/wallclock.py`` (``WallClock.env()``) puts this directory first on ``PYTHONPATH``
and names a file in ``SOVD_TEST_WALL_STEP_FILE``; Python imports this module at start-up in the
supervisor, the HTTP workers and the ROS worker (the supervisor passes its environment on).  From
then on ``time.time`` and ``time.time_ns`` return the real wall clock plus the number of
nanoseconds written in that file (read again at most every ``RECHECK`` seconds), on every thread.
The monotonic clock is left alone, as a real step of the system clock leaves it.

Why not libfaketime: Debian's 0.9.10 makes Python's ``time.sleep`` fail with EINVAL
(``clock_nanosleep`` on CLOCK_MONOTONIC) as soon as ``FAKETIME_DONT_FAKE_MONOTONIC=1`` is set,
and without that setting it steps the monotonic clock too, which no NTP step does.
"""

from __future__ import annotations

import os
import time

RECHECK = 0.05  # seconds

_path = os.environ.get("SOVD_TEST_WALL_STEP_FILE")

if _path:
    _real_time_ns = time.time_ns
    _next_read = 0.0
    _step_ns = 0

    def _step() -> int:
        global _next_read, _step_ns
        now = time.monotonic()
        if now >= _next_read:
            _next_read = now + RECHECK
            try:
                with open(_path) as fh:
                    _step_ns = int(fh.read().strip() or 0)
            except (OSError, ValueError):
                pass  # keep the last step (a write in progress)
        return _step_ns

    def _time_ns() -> int:
        return _real_time_ns() + _step()

    def _time() -> float:
        return _time_ns() / 1e9

    time.time_ns = _time_ns
    time.time = _time
