"""Which HTTP request a ROS-worker log line belongs to: its ``X-Request-Id``, in the line.

An HTTP worker sends the id of the request it serves in the IPC envelope
(``request_id``, ``ipc/PROTOCOL.md``).  The ROS thread binds it with
:func:`bound` while it runs that command (``rosworker/core/executor.py``) and while
it answers it, which for a cold sample is later, when the first message came.
:class:`RequestIdFilter`, on the worker's log handler (``rosworker/main.py``),
adds `` [request <id>]`` to every line written meanwhile, so that
``journalctl -u sovd-gateway | grep <id>`` finds the HTTP side's access line
and the ROS worker's lines of the same request.  Other threads (the control
thread) never see an id: a context variable is per thread.

:class:`SlowCommands`: one info line per command answered ``SLOW_COMMAND`` s or
more after it came (at most ``SLOW_LOG_PER_S`` a second), with what it was.
"""

from __future__ import annotations

import contextvars
import logging
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

SLOW_COMMAND = 0.5      # seconds from receipt to answer past which a command is logged (info)
SLOW_LOG_PER_S = 20     # at most this many such lines per second; the rest are counted only

current: contextvars.ContextVar[str | None] = contextvars.ContextVar("sovd_request_id", default=None)


@contextmanager
def bound(request_id: str | None) -> Iterator[None]:
    """Log lines written inside carry ``request_id`` (nothing when it is None)."""
    token = current.set(request_id)
    try:
        yield
    finally:
        current.reset(token)


class RequestIdFilter(logging.Filter):
    """Sets ``record.request_tag``: `` [request <id>]`` inside :func:`bound`, else empty."""

    def filter(self, record: logging.LogRecord) -> bool:
        request_id = current.get()
        record.request_tag = f" [request {request_id}]" if request_id else ""
        return True


class SlowCommands:
    """The slow-command lines of one ROS thread (see the module's docstring)."""

    def __init__(self, log: logging.Logger):
        self._log = log
        self._second = 0   # the second (monotonic) whose lines are counted
        self._logged = 0

    def answered(self, cmd: str, args: Any, message: dict, took: float, now: float) -> None:
        """``cmd`` was answered ``message`` ``took`` s after it came (``now``: monotonic)."""
        if took < SLOW_COMMAND:
            return
        if int(now) != self._second:
            self._second, self._logged = int(now), 0
        self._logged += 1
        if self._logged > SLOW_LOG_PER_S:
            return
        topic = args.get("topic") if isinstance(args, dict) else None
        what = f"{cmd} {topic}" if isinstance(topic, str) else cmd
        if message.get("ok"):
            result = message.get("result") or {}
            outcome = result.get("status", "ok") if isinstance(result, dict) else "ok"
            if isinstance(result, dict) and result.get("reason"):
                outcome += f" ({result['reason']})"
        else:
            outcome = f"error {(message.get('error') or {}).get('code')}"
        self._log.info("slow command: %s answered after %d ms: %s", what[:300], int(took * 1000), outcome)
