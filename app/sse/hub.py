"""The one hub base: an HTTP worker's streams of one kind, fed from the events channel.

A family's hub (cyclic subscriptions, triggers, faults) subclasses :class:`Hub`:
it says which keys of the channel it reads (``KEYS``, and ``subscribe`` for more),
what a message does (``dispatch``, on the reader greenlet) and, optionally, what
its ticker does besides the common work (``tick``) and what a stream's last frame
is when the HTTP worker stops (``last``).  The base keeps the rest, the same for
every kind:

- the SUB socket, its connection monitor, the ROS worker's heartbeat and the
  confirmations of its subscriptions (``channel.py``);
- every open stream of the process (``streams``), registered by the stream's
  body (``stream.py``) and given back by its ``finally``;
- one set of counters (``open_streams``, ``frames_sent``, ``frames_dropped``),
  added to the Prometheus metrics (``core/metrics.py``) once per round of the
  ticker, not once per frame: ``/health`` and ``/metrics`` sum them over every
  HTTP worker, whatever the kind of stream;
- the ticker (every ``TICK`` while a stream is open): the stall cut (a write that lasts
  ``stream_send_timeout``), the look at silent streams' connections (their client
  left), and, once the HTTP worker stops, the end of every stream (with ``last``).
  A hub with no stream open sleeps until one opens (``IDLE_TICK`` at most, for its
  stop check): an idle gateway's HTTP workers do not wake 20 times a second per kind.

A hub is made per process, after the fork, when its first stream opens
(:func:`hub_of`; nothing at import time).
"""

from __future__ import annotations

import logging
import socket
import time
import weakref
from collections.abc import Callable, Iterator
from typing import Any

import gevent
import gevent.event
import gevent.socket
from flask import Flask, current_app

from common.process import PerProcess

from ..core import metrics
from . import channel
from .stream import GONE_CHECK, STREAM_SNDBUF, Stream, gone

log = logging.getLogger("sovd.http.sse")

TICK = 0.05          # seconds between the ticker's rounds while a stream is open
IDLE_TICK = 1.0      # seconds at most between its rounds while none is (a stream's opening wakes it)
EXTENSION = "sovd_sse_hubs"


class Hub(channel.Subscriber):
    """The streams of one kind in one HTTP worker process (see the module's docstring)."""

    def __init__(self, runtime_dir: str, send_timeout: float = 30.0,
                 stopping: Callable[[], bool] = lambda: False):
        super().__init__(runtime_dir)
        self.send_timeout = send_timeout
        self._stopping = stopping              # true once this HTTP worker is shutting down
        self.streams: set[Stream] = set()
        self.counters = {"open_streams": 0, "frames_sent": 0, "frames_dropped": 0}  # this hub's own
        self.prom = metrics.http()             # the same, as /metrics and /health sum them
        self._flushed = {"frames_sent": 0, "frames_dropped": 0}  # counted into ``prom`` so far
        self.sending: set[Stream] = set()      # direct streams in a blocking write (the stall cut)
        self._next_gone_scan = 0.0
        self._wake = gevent.event.Event()      # set by a stream's opening and the last one's end
        # for the kinds that index their streams (index()): resource id -> its streams; key -> its watchers
        self.by_id: dict[Any, set[Stream]] = {}
        self.by_key: dict[bytes, set[Stream]] = {}

    # ---- what a kind of hub says ----------------------------------------------------------------
    def added(self, stream: Stream) -> None:
        """A stream opened (its body's first iteration): start feeding it."""

    def removed(self, stream: Stream) -> None:
        """A stream ended: stop feeding it."""

    def tick(self, now: float) -> None:
        """The hub's own work on each round of the ticker (the worker is gone, silent streams)."""

    def last(self, stream: Stream) -> bytes | None:
        """The frame a stream ends with when the HTTP worker stops (None: none)."""
        return None

    # ---- streams ----------------------------------------------------------------------------------
    def register(self, stream: Stream) -> None:
        self.streams.add(stream)
        self.counters["open_streams"] += 1
        self.prom.streams_open.inc()
        self.added(stream)
        self._wake.set()

    def close(self, stream: Stream) -> None:
        stream.ended = True
        if stream not in self.streams:
            return
        self.streams.discard(stream)
        self.counters["open_streams"] -= 1
        self.prom.streams_open.dec()
        self.removed(stream)
        if not self.streams:
            self._wake.set()   # one more round at once: its counters into the metrics

    def index(self, stream: Stream) -> None:
        """``stream`` in ``by_id`` (the open streams of one resource) and watching its ``key`` in ``by_key``."""
        self.by_id.setdefault(stream.id, set()).add(stream)
        self.watch(self.by_key, stream.key, stream, stream.key)

    def unindex(self, stream: Stream) -> bool:
        """Out of ``by_id`` and ``by_key``; True when it was the key's last stream (unsubscribed)."""
        streams = self.by_id.get(stream.id)
        if streams is not None:
            streams.discard(stream)
            if not streams:
                del self.by_id[stream.id]
        return self.unwatch(self.by_key, stream.key, stream, stream.key)

    def watch(self, index: dict[Any, set[Stream]], name: Any, stream: Stream, key: bytes) -> None:
        """``stream`` watches ``name`` of ``index`` (a kind's own: a key, a trigger id); the first
        watcher of a name subscribes the channel to ``key``."""
        watchers = index.get(name)
        if watchers is None:
            watchers = index[name] = set()
            self.subscribe(key)
        watchers.add(stream)

    def unwatch(self, index: dict[Any, set[Stream]], name: Any, stream: Stream, key: bytes) -> bool:
        """``stream`` no longer watches ``name``; the last one gone unsubscribes ``key`` (True then)."""
        watchers = index.get(name)
        if watchers is None:
            return False
        watchers.discard(stream)
        if watchers:
            return False
        del index[name]
        self.unsubscribe(key)
        return True

    def end_all(self, last: Callable[[Stream], bytes | None]) -> None:
        for stream in list(self.streams):
            stream.end(last(stream))

    # ---- the ticker ---------------------------------------------------------------------------------
    def loops(self) -> list:
        return [self._tick]

    def _tick(self) -> None:
        while True:
            try:
                if self.streams:
                    gevent.sleep(TICK)
                else:
                    self._wake.wait(IDLE_TICK)
                self._wake.clear()
                now = time.monotonic()
                self._flush_metrics()
                self._cut_stalled(now)
                if self._stopping():
                    self.end_all(self.last)
                    return
                if self.streams and now >= self._next_gone_scan:
                    self._next_gone_scan = now + GONE_CHECK
                    self._look_for_gone(now)
                self.tick(now)
            except gevent.GreenletExit:
                raise
            except Exception:
                log.exception("%s: the stream ticker failed a round", self.NAME)

    def _flush_metrics(self) -> None:
        """Frames sent and dropped since the last tick, into the Prometheus counters at once."""
        for name, counter in (("frames_sent", self.prom.frames_sent), ("frames_dropped", self.prom.frames_dropped)):
            delta = self.counters[name] - self._flushed[name]
            if delta:
                counter.inc(delta)
                self._flushed[name] += delta

    def _cut_stalled(self, now: float) -> None:
        """A direct stream whose write has lasted the send timeout: its reader is not reading."""
        for stream in list(self.sending):
            if stream.sending_since and now - stream.sending_since >= self.send_timeout:
                stream.cut = True
                self.sending.discard(stream)
                try:
                    stream.sock.shutdown(socket.SHUT_RDWR)   # the blocked write fails at once
                except OSError:
                    pass

    def _look_for_gone(self, now: float) -> None:
        """Silent streams whose client closed its connection end (a write would tell only later)."""
        for stream in list(self.streams):
            if stream.sock is not None and stream.opened and not stream.sending_since \
                    and now - stream.last_frame >= GONE_CHECK and gone(stream.sock):
                stream.ended = True
                stream.wake.set()


# ---- a hub per process, and a stream's response -------------------------------------------------------
def register(app: Flask, name: str, make: Callable[[Flask], Hub]) -> None:
    """A family's setup: the hub ``name`` of this app is ``make(app)`` (started), made in the process that
    first opens one of its streams (never before the fork)."""
    hubs = app.extensions.setdefault(EXTENSION, {})
    # Through a weak reference to the app: the hub's factory must not keep the app (and its
    # RosClient and ZeroMQ context) alive in a reference cycle.
    ref = weakref.ref(app)
    hubs[name] = PerProcess(lambda: _started(make(ref())), Hub.stop)


def _started(hub: Hub) -> Hub:
    hub.start()
    return hub


def hub_of(name: str, app: Flask | None = None) -> Any:
    """This process's hub ``name`` of the app (the current one: a request's), made now if need be."""
    return (app or current_app).extensions[EXTENSION][name].get()


def close(app: Flask) -> None:
    """Stop this process's hubs of the app (a test app dropped)."""
    for per_process in app.extensions.get(EXTENSION, {}).values():
        per_process.reset()


def worker_stopping() -> bool:
    """True once the HTTP worker this process is has begun to stop (its streams must end)."""
    from ..http_worker import stopping

    return stopping().is_set()


def connection(environ: dict[str, Any]) -> tuple[Any, bool]:
    """``(sock, framed)`` of a stream's response: gunicorn's gevent connection (None under a test client),
    and whether it is chunked (HTTP/1.1; a HEAD never iterates a stream's body)."""
    sock = environ.get("gunicorn.socket")
    if sock is not None:
        # The connection keeps this buffer after the stream if it is used again (keep-alive).
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, STREAM_SNDBUF)
        except OSError as exc:
            log.warning("could not bound a stream's send buffer: %s", exc)
    direct = isinstance(sock, gevent.socket.socket)  # gunicorn's gevent worker: written directly
    framed = direct and environ.get("SERVER_PROTOCOL", "HTTP/1.1") not in ("HTTP/1.0", "HTTP/0.9")
    return (sock if direct else None), framed


def response_body(name: str, make: Callable[[Hub, Any, bool], Iterator[bytes]],
                  environ: dict[str, Any]) -> Iterator[bytes]:
    """A stream's response body: ``make(hub, sock, framed)`` (a :meth:`Stream.body`) once the server
    iterates it; nothing happens before (not even this process's hub being made)."""
    per_process = current_app.extensions[EXTENSION][name]  # looked up now, in the request

    def body() -> Iterator[bytes]:
        sock, framed = connection(environ)
        yield from make(per_process.get(), sock, framed)

    return body()


def response(body: Iterator[bytes]) -> Any:
    """A stream's response: ``body`` (a family's ``hub.body``) as ``text/event-stream``, never cached,
    never buffered by a proxy (nginx's ``X-Accel-Buffering``)."""
    return current_app.response_class(body, mimetype="text/event-stream",
                                      headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})
