"""Test and bench routes, registered only with ``debug_commands`` on (never in production).

Under ``/api/v1/x-sovd-debug/``, left out of the OpenAPI document:

- ``GET stream?interval=S&limit=S``: an event stream (``text/event-stream``)
  that sends ``event: tick`` every ``interval`` seconds (default 0.1) until this
  HTTP worker begins to stop (:func:`app.http_worker.stopping`), then one
  ``event: stopping`` frame, and ends; it also ends after ``limit`` seconds
  (default 60).  The tests of a graceful stop use it as the stand-in for a
  long-lived stream.
- ``GET echo``: one request/reply round trip through ``ipc/client.py`` (the
  client every ROS-worker call uses, with its channel pool) to the bench's
  echo process on ``ipc://<runtime_dir>/bench-echo.sock``
  (``bench/echoworker.py``): the pure-hop reference of ``make
  bench``.  503 ``x-medkit-ros-worker-unavailable`` when no echo process runs.
- ``GET worker``: ``{pid, green}``: which HTTP worker answered, and whether
  its ZeroMQ client is ``zmq.green``'s.
- ``GET fail``: an unhandled error on purpose: the contract's bare 500 for the
  client, an error line with its traceback (and the request's id) in the log.

Each runs in the request's greenlet (gevent worker) or thread (test client).
"""

from __future__ import annotations

import os
import time

from flask import Blueprint, Flask, Response, current_app, request

from ipc.client import RosWorkerClient, green

from .common import config, json_response
from .entities import API_BASE
from .errors import ApiError

bp = Blueprint("debug", __name__, url_prefix=API_BASE + "/x-sovd-debug")

ECHO_SOCKET = "bench-echo.sock"
ECHO_EXTENSION = "sovd_bench_echo"
STREAM_LIMIT_MAX_S = 600.0


def echo_endpoint(runtime_dir: str) -> str:
    return f"ipc://{os.path.join(runtime_dir, ECHO_SOCKET)}"


def init_app(app: Flask) -> None:
    """Register the routes and the echo client (made lazily, per process, like every client)."""
    app.extensions[ECHO_EXTENSION] = RosWorkerClient(echo_endpoint(app.config["SOVD"].runtime_dir))
    app.register_blueprint(bp)


def _number(name: str, default: float, low: float, high: float) -> float:
    raw = request.args.get(name)
    if raw is None:
        return default
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not low <= value <= high:
        raise ApiError(400, "invalid-parameter", f"Invalid value of query parameter {name!r}",
                       {"details": f"expected a number of seconds in {low:g}–{high:g}", name: raw[:50]})
    return value


@bp.get("/stream")
def stream():
    from ..http_worker import stopping

    interval = _number("interval", 0.1, 0.01, 10.0)
    limit = _number("limit", 60.0, 0.1, STREAM_LIMIT_MAX_S)
    stop = stopping()

    def frames():
        ends = time.monotonic() + limit
        n = 0
        while time.monotonic() < ends:
            if stop.wait(interval):
                yield b"event: stopping\ndata: {}\n\n"
                return
            n += 1
            yield b"event: tick\ndata: {\"n\": %d}\n\n" % n

    return Response(frames(), mimetype="text/event-stream", headers={"Cache-Control": "no-store"})


@bp.get("/echo")
def echo():
    client: RosWorkerClient = current_app.extensions[ECHO_EXTENSION]
    return json_response(client.call("echo", {"n": 1}, config().ipc_timeout))


@bp.get("/worker")
def worker():
    return json_response({"pid": os.getpid(), "green": green()})


@bp.get("/fail")
def fail():
    raise RuntimeError("x-sovd-debug/fail: a deliberate failure")
