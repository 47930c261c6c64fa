"""The access log (``access_log``, off by default): rate-limited so that it cannot drown the journal.

journald drops a service's lines beyond 10,000 per 30 s (its default
``RateLimitIntervalSec``/``RateLimitBurst``), and then the errors go with
the access lines.  A dashboard polling a few hundred times a second would
cross that in under a minute, so when the access log is on, each HTTP worker
writes at most its share of ``ACCESS_LOG_RATE`` lines per second (after a
burst of its share of ``ACCESS_LOG_BURST``), all workers together well below
journald's budget.  Lines over it are counted, and the count is written
(``access log: N lines suppressed ...``) with the next line that passes, at
most once every ``SUMMARY_EVERY`` seconds.  Only access lines are limited: warnings
and errors never pass through here.  nginx in front logs every request anyway.

gunicorn loads :class:`AccessLogger` as its ``logger_class``
(``app/gunicorn_conf.py``): made in the master, copied into each worker by the
fork; :meth:`AccessLogger.access` runs on the request's greenlet after the
response was sent.  The line carries the request's id (``X-Request-Id``).
"""

from __future__ import annotations

import time

from gunicorn.glogging import Logger

from common import settings

SUMMARY_EVERY = 10.0  # seconds between "suppressed" summaries


class LineBudget:
    """A token bucket of log lines: ``rate`` per second, at most ``burst`` at once (one process)."""

    def __init__(self, rate: float, burst: float, clock=time.monotonic):
        self.bucket = settings.Rate(rate, burst)
        self.tokens = burst
        self.clock = clock
        self.last = clock()
        self.suppressed = 0
        self.summarised = -SUMMARY_EVERY  # the first summary comes with the first line after a gap

    def take(self) -> bool:
        now = self.clock()
        self.tokens = self.bucket.refill(self.tokens, now - self.last)
        self.last = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        self.suppressed += 1
        return False

    def summary_due(self) -> int:
        """Lines suppressed since the last summary, when one is due now (else 0)."""
        now = self.clock()
        if self.suppressed and now - self.summarised >= SUMMARY_EVERY:
            count, self.suppressed, self.summarised = self.suppressed, 0, now
            return count
        return 0


class AccessLogger(Logger):
    """gunicorn's logger, whose access lines are rate-limited per worker (see the module docstring)."""

    def __init__(self, cfg):
        super().__init__(cfg)
        workers = max(1, int(cfg.workers or 1))
        self.budget = LineBudget(settings.ACCESS_LOG_RATE / workers,
                                 max(1.0, settings.ACCESS_LOG_BURST / workers))

    def access(self, resp, req, environ, request_time):
        if not self.access_log_enabled:
            return
        budget = self.budget
        if not budget.take():
            return
        suppressed = budget.summary_due()
        if suppressed:
            self.access_log.info("access log: %d lines suppressed in the last %g s or more (at most %g "
                                 "lines/s in all; nginx logs every request)", suppressed, SUMMARY_EVERY,
                                 settings.ACCESS_LOG_RATE)
        super().access(resp, req, environ, request_time)
