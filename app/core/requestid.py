"""Every HTTP request's id: ``X-Request-Id`` on every response, in the access log and across the IPC.

Registered first by the app factory, so that every later hook, error and
refusal (a 429 included) is answered with it.  Before each request
(:func:`_assign`, on the request's greenlet): a valid incoming
``X-Request-Id`` (1–128 characters of ``[A-Za-z0-9._-]``,
``ipc.protocol.valid_request_id``) is kept, anything else is replaced by a
new random id.  After it (:func:`_echo`) the response carries the id; the
access line reads it from there (``%({x-request-id}o)s``,
``app/gunicorn_conf.py``).  :func:`current` gives it to the ROS-worker client
(``app/core/rosclient.py``), which sends it in the IPC envelope, so the ROS
worker's log lines of that command carry it too (``rosworker/core/requestlog.py``).

:class:`RequestIdFilter` adds `` [request <id>]`` to the HTTP worker's own log
lines written inside a request (Flask's handler: an unhandled error's
traceback, for one).
"""

from __future__ import annotations

import logging
import os

from flask import Flask, Response, has_request_context, request
from flask.logging import default_handler

from ipc.protocol import valid_request_id

HEADER = "X-Request-Id"


ENVIRON_KEY = "sovd.request_id"


def current() -> str | None:
    """The id of the request being served on this greenlet/thread, or None outside a request."""
    if not has_request_context():
        return None
    return request.environ.get(ENVIRON_KEY)


def _assign() -> None:
    environ = request.environ
    incoming = environ.get("HTTP_X_REQUEST_ID")
    environ[ENVIRON_KEY] = incoming if valid_request_id(incoming) else os.urandom(16).hex()


def _echo(response: Response) -> Response:
    request_id = request.environ.get(ENVIRON_KEY)
    if request_id is not None:
        response.headers.set(HEADER, request_id)
    return response


class RequestIdFilter(logging.Filter):
    """Sets ``record.request_tag``: `` [request <id>]`` inside a request, else empty."""

    def filter(self, record: logging.LogRecord) -> bool:
        request_id = current()
        record.request_tag = f" [request {request_id}]" if request_id else ""
        return True


def init_app(app: Flask) -> None:
    """Register before every other hook (the app factory calls this first)."""
    app.before_request(_assign)
    app.after_request(_echo)
    if not any(isinstance(f, RequestIdFilter) for f in default_handler.filters):
        default_handler.addFilter(RequestIdFilter())
        default_handler.setFormatter(logging.Formatter(
            "[%(asctime)s] %(levelname)s in %(module)s: %(message)s%(request_tag)s"))
