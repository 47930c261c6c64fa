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
"""

from __future__ import annotations

import contextvars
import logging
from collections.abc import Iterator
from contextlib import contextmanager

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
