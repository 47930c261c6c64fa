"""When a cyclic subscription ends, through a real gateway: on the monotonic clock, whatever the wall clock does.

A step of the wall clock (an NTP step on a robot whose RTC drifted) changes
the ``expires_at`` a client is shown, which is wall-clock time, but neither
keeps a subscription past its duration nor ends it early (issue 18, defect 7).
The step is made in every process of the gateway by
``tests/support/wallclock.py``.  A ROS worker killed and restarted keeps each
subscription's expiry (the restart state holds it as wall-clock time).
Expiry of an open stream at an unchanged clock is in tests/system/subscriptions/test_app_streams.py.
"""

from __future__ import annotations

import os
import signal
import time
from datetime import UTC, datetime

import requests

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.rospub import unique_topic
from tests.support.sse import EventStream
from tests.support.wallclock import WallClock

STEP = 3600  # seconds the wall clock is stepped back
DURATION = 10  # seconds a subscription lasts: long enough to see the step before it expires


def _epoch(stamp: str) -> float:
    """``expires_at`` (``2026-01-01T00:00:00.000Z``) as seconds since the epoch."""
    return datetime.strptime(stamp, "%Y-%m-%dT%H:%M:%S.%fZ").replace(tzinfo=UTC).timestamp()


def _subscribe(gw: Gateway, name: str, duration: int) -> tuple[str, dict]:
    host = gw.host()
    base = f"{gw.api}/components/{host}/cyclic-subscriptions"
    r = requests.post(base, timeout=15, json={"resource": f"/api/v1/components/{host}/data{unique_topic(name)}",
                                              "interval": "fast", "duration": duration})
    assert r.status_code == 201, r.text
    return base, r.json()


def _gateway_clock(gw: Gateway) -> float:
    """The wall clock as the gateway reads it (``/health``'s timestamp), in seconds."""
    return gw.get("/health").json()["timestamp"] / 1e9


def _active(gw: Gateway) -> int:
    return gw.get("/health").json()["x-medkit-streams"]["active_subscriptions"]


def test_a_backwards_wall_clock_step_moves_expires_at_but_the_subscription_still_expires_on_time():
    clock = WallClock()
    gw = Gateway("--log-level", "warning", env=clock.env())
    try:
        base, sub = _subscribe(gw, "stepped", DURATION)
        made = time.monotonic()
        shown = _epoch(sub["expires_at"])
        assert abs(shown - (time.time() + DURATION)) < 5, sub  # the real wall clock, before the step
        with EventStream(gw.port, sub["event_source"]) as stream:
            assert stream.status == 200, stream.body
            assert stream.next(timeout=5) is not None
            clock.step(-STEP)
            poll_until(lambda: _gateway_clock(gw) < time.time() - STEP + 60, 10,
                       message="the gateway's wall clock stepped back")
            # What a client is shown follows the wall clock the gateway reads now: an hour earlier.
            # (Before the fix it stayed where it was, an hour after the gateway's now.)
            poll_until(lambda: abs(_epoch(requests.get(f"{base}/{sub['id']}", timeout=15).json()["expires_at"])
                                   - (shown - STEP)) < 1, 5, message="expires_at an hour earlier after the step")
            later = requests.get(f"{base}/{sub['id']}", timeout=15).json()
            assert 0 < _epoch(later["expires_at"]) - _gateway_clock(gw) <= DURATION, later
            assert stream.ended(timeout=DURATION + 15)
        # The ROS worker forgot it, on its monotonic deadline (before the fix: never, as the wall
        # clock it checked was an hour short of the time it had armed the timer for).
        poll_until(lambda: requests.get(f"{base}/{sub['id']}", timeout=15).status_code == 404,
                   max(1.0, made + DURATION + 15 - time.monotonic()), message="the subscription expired")
        assert _active(gw) == 0
        assert all(s["id"] != sub["id"] for s in requests.get(base, timeout=15).json()["items"])
    finally:
        gw.stop()
        clock.close()


def test_a_restarted_ros_worker_keeps_each_subscriptions_expiry():
    """The restart state holds the deadline as wall-clock time and the new worker makes it monotonic
    again: the same expires_at, and it ends then (not a full duration later, and not at once)."""
    gw = Gateway("--log-level", "warning")
    try:
        duration = 20
        base, sub = _subscribe(gw, "restarted", duration)
        made = time.monotonic()
        state = os.path.join(gw.runtime_dir, "restart-state.json")
        poll_until(lambda: os.path.exists(state) and sub["id"] in open(state).read(), 5,
                   message="the subscription saved")
        old = gw.rosworker_pid()
        os.kill(old, signal.SIGKILL)
        poll_until(lambda: gw.rosworker_pid() != old and gw.get("/health").json()[
            "x-medkit-subscription-executor"]["worker_alive"], 30, message="a new ROS worker")
        again = requests.get(f"{base}/{sub['id']}", timeout=15)
        assert again.status_code == 200, again.text
        assert abs(_epoch(again.json()["expires_at"]) - _epoch(sub["expires_at"])) < 0.05, (sub, again.json())
        assert time.monotonic() - made < duration, "the restart took longer than the subscription lasts"
        poll_until(lambda: requests.get(f"{base}/{sub['id']}", timeout=15).status_code == 404,
                   max(1.0, made + duration + 15 - time.monotonic()), message="the restored subscription expired")
        assert _active(gw) == 0
    finally:
        gw.stop()
