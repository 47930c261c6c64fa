"""The access log: off by default, and when on, rate-limited so that it cannot drown the journal.

journald keeps at most 10,000 lines per 30 s of a service (its default
RateLimitBurst/RateLimitIntervalSec) and drops the rest, errors included.
The real-gateway test sends a burst of 20,000 requests with the access log on
(20,000 access lines unlimited) and checks that the gateway's whole output,
up to an error line written after the burst, stays under that budget, so
journald would keep the error line.
"""

from __future__ import annotations

import importlib
import socket
import threading
import time
import uuid

import pytest

from app.core import accesslog
from common import settings
from common.harness.gateway import Gateway
from common.harness.procs import poll_until

JOURNALD_BURST = 10_000  # journald's default RateLimitBurst ...
JOURNALD_WINDOW = 30.0   # ... per RateLimitIntervalSec
BURST_REQUESTS = 20_000


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def test_a_line_budget_lets_a_burst_then_the_rate_through_and_counts_the_rest():
    clock = Clock()
    budget = accesslog.LineBudget(rate=10, burst=5, clock=clock)
    assert [budget.take() for _ in range(8)] == [True] * 5 + [False] * 3
    clock.now += 0.15  # one line's worth (and a half)
    assert budget.take() is True and budget.take() is False
    assert budget.summary_due() == 4  # the first summary is due at once
    assert budget.summary_due() == 0
    budget.take()
    clock.now += 1
    assert budget.summary_due() == 0  # not again within SUMMARY_EVERY
    clock.now += accesslog.SUMMARY_EVERY
    assert budget.summary_due() == 1


def test_the_access_log_is_off_unless_asked_for(monkeypatch):
    import app.gunicorn_conf as conf

    try:
        monkeypatch.delenv("SOVD_ACCESS_LOG", raising=False)
        assert importlib.reload(conf).accesslog is None
        monkeypatch.setenv("SOVD_ACCESS_LOG", "1")
        reloaded = importlib.reload(conf)
        assert reloaded.accesslog == "-"
        assert reloaded.logger_class == "app.core.accesslog.AccessLogger"
        assert "%({x-request-id}o)s" in reloaded.access_log_format
    finally:
        monkeypatch.delenv("SOVD_ACCESS_LOG", raising=False)
        importlib.reload(conf)


def burst(port: int, path: str, total: int, connections: int = 8, batch: int = 100) -> int:
    """``total`` GETs of ``path`` over ``connections`` pipelined keep-alive connections; the 200s."""
    ok = [0] * connections
    request = f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode()

    def run(i: int) -> None:
        share = total // connections + (1 if i < total % connections else 0)
        with socket.create_connection(("127.0.0.1", port), timeout=30) as sock:
            left, pending = share, b""
            while left:
                n = min(batch, left)
                sock.sendall(request * n)
                answered = 0
                while answered < n:
                    data = sock.recv(1 << 20)
                    if not data:
                        raise AssertionError("the gateway closed a connection mid-burst")
                    pending += data
                    answered += pending.count(b"HTTP/1.1 ")
                    ok[i] += pending.count(b"HTTP/1.1 200 ")
                    pending = pending[pending.rfind(b"HTTP/1.1 ") + 1:] if b"HTTP/1.1 " in pending else pending
                    pending = pending[-16:]  # a status line split over two reads
                left -= n

    threads = [threading.Thread(target=run, args=(i,)) for i in range(connections)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(300)
    return sum(ok)


@pytest.fixture(scope="module")
def gw(gateway):
    return gateway("--access-log", "--debug-commands", exit_code=0)


class LineCounts:
    """Samples (time, lines written so far) of a process's output every ``every`` seconds."""

    def __init__(self, gw: Gateway, every: float = 0.25):
        self.gw, self.every = gw, every
        self.samples: list[tuple[float, int]] = [(time.monotonic(), len(gw.output))]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self.every):
            self.samples.append((time.monotonic(), len(self.gw.output)))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.samples.append((time.monotonic(), len(self.gw.output)))

    def most_in(self, window: float) -> int:
        """The most lines written within any ``window`` seconds (counted generously: whole samples)."""
        most = 0
        for t, n in self.samples:
            before = [m for s, m in self.samples if s <= t - window]
            most = max(most, n - (before[-1] if before else 0))
        return most


def test_a_burst_of_20000_requests_leaves_a_later_error_line_in_the_journal(gw):
    started_lines = len(gw.output)
    counts = LineCounts(gw)
    t0 = time.monotonic()
    assert burst(gw.port, "/api/v1/version-info", BURST_REQUESTS) == BURST_REQUESTS
    elapsed = time.monotonic() - t0
    rid = f"after-burst-{uuid.uuid4().hex[:8]}"
    import requests

    r = requests.get(gw.api + "/x-sovd-debug/fail", headers={"X-Request-Id": rid}, timeout=10)
    assert r.status_code == 500

    def error_line() -> int | None:
        return next((i for i, line in enumerate(list(gw.output)) if "ERROR" in line and rid in line), None)

    at = poll_until(error_line, 10, message="the error line after the burst")
    counts.stop()
    lines = gw.output[:at + 1]
    burst_lines = lines[started_lines:]
    access = [line for line in burst_lines if '"GET /api/v1/version-info HTTP/1.1" 200' in line]
    # Everything the service wrote in any 30 s up to the error line (its start-up included) fits
    # journald's budget, so journald drops nothing of it, the error line included.
    assert counts.most_in(JOURNALD_WINDOW) < JOURNALD_BURST, counts.most_in(JOURNALD_WINDOW)
    # The access lines themselves: the burst allowance plus the rate over the burst's duration.
    assert 0 < len(access) <= settings.ACCESS_LOG_BURST + settings.ACCESS_LOG_RATE * (elapsed + 2)
    assert any("lines suppressed" in line for line in burst_lines)
    print(f"\n{BURST_REQUESTS} requests in {elapsed:.1f} s: {len(access)} access lines written, "
          f"{len(lines)} lines in all up to the error line, at most {counts.most_in(JOURNALD_WINDOW)} in 30 s")
