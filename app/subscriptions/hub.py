"""The HTTP worker's side of cyclic subscriptions: one events socket, many SSE streams.

One :class:`StreamHub` per HTTP worker process, made on first use after the
fork.  It holds one ZeroMQ SUB socket on the ROS worker's events channel
(``ipc/events.py``) and every open stream of this process, all on gevent:
no thread per stream.

- The *reader* greenlet receives each data frame once per key (a topic at an
  interval and bytes mode), builds its SSE chunk once per entity (the payload
  is exactly the body a GET of the resource answers, which names the entity;
  its ``type_info`` comes from the process's cache, filled when a stream
  opens, so the reader never waits on IPC) and hands it to every stream
  watching that key.  Control frames retime,
  re-key or end streams; heartbeats and the socket's connect/disconnect
  events tell whether the ROS worker is there.
- Each stream is a bounded buffer (``STREAM_BUFFER`` frames and
  ``STREAM_BUFFER_BYTES``, the oldest dropped first: latest-value semantics)
  and a connection whose kernel send buffer is ``STREAM_SNDBUF``.  Under
  gunicorn the reader writes a pushed frame on the connection at once, with
  one non-blocking send per stream per frame (issue 23: the frame's bytes,
  already framed as an HTTP chunk, are made once per key and entity and
  shared; no greenlet switch per frame); what the kernel does not take is
  written by the stream's response generator, which also sends a ``:``
  keep-alive comment after ``KEEPALIVE`` seconds of silence and ends the
  stream at its expiry.  A client that stops reading only ever holds a few
  frames; it never slows the others; and one whose write lasts more than
  ``stream_send_timeout`` seconds is disconnected by the ticker (a deadline
  stamp per write in progress, not a timer per frame).
- The *ticker* greenlet stands in while the ROS worker is down: every stream
  gets an ``error`` frame per interval (the error a GET would answer), so the
  stream stays open and visibly degraded until data frames come back.  It
  also ends every stream with a last ``error`` frame when the HTTP worker
  shuts down.
- Open streams, frames sent and frames dropped are Prometheus metrics
  (``app/core/metrics.py``): ``/metrics`` and the ``x-medkit-streams`` section of
  ``/health`` sum them over every HTTP worker.  Frames are counted in the
  hub's ``counters`` as they go; the ticker adds them to the Prometheus
  counters once per round (``TICK``), not once per frame.

Before fork / after fork: nothing here runs at import time; the hub, its
socket and its greenlets are made by :func:`get` in the worker process.
"""

from __future__ import annotations

import collections
import errno
import logging
import socket
import time
import weakref
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from typing import Any

import gevent
import gevent.event
import gevent.socket
import orjson
import zmq.green as zmq
from flask import Flask, current_app

from common.process import PerProcess
from ipc import events, protocol
from ipc.errors import IpcError

from ..core import metrics, rosclient
from ..data import model as samples
from ..sse import channel
from . import feeds

log = logging.getLogger("sovd.http.streams")

STREAM_BUFFER = 4          # frames a stream holds for a slow client; the oldest go first
# ... and bytes: past this, older frames go too (the newest is always kept).  An image stream's
# frame is a megabyte or more; a slow client holds one of them here, not four.
STREAM_BUFFER_BYTES = 1 << 20
# SO_SNDBUF of a stream's connection (Linux doubles it for its bookkeeping).  Left to itself the
# kernel grows a send buffer to megabytes for a client that does not read: without this, one
# stalled reader of an image stream held 3 MB in the kernel, beside what STREAM_BUFFER holds.
# 128 KiB in flight still carries 100 MB/s at a LAN's 1 ms round trip.
STREAM_SNDBUF = 128 * 1024
KEEPALIVE = 15.0           # seconds of silence before a ":" comment line
TICK = 0.05                # seconds between the ticker's rounds
LOOKUP_TIMEOUT = 0.5       # seconds a silent stream's sub_get may take (a type_info fetch: 4 times this)
SILENT_CHECK = 2.0         # seconds without frames (worker up) before a stream's subscription is looked up
EXPIRY_SLACK = 1.0         # seconds an expiry from sub_get may differ from a stream's before it is applied
SILENT_SCAN = 0.5          # seconds between two scans of every stream for silence (a scan is O(streams))


UNAVAILABLE = IpcError("unavailable", "The ROS worker is not running; data frames resume when it is back")
SHUTDOWN = IpcError("shutdown", "The gateway is shutting down; this stream ends")


def rfc3339(ns: int) -> bytes:
    """``2026-02-14T10:30:00.250Z``: UTC, milliseconds."""
    return (datetime.fromtimestamp(ns / 1e9, UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z").encode()


def frame(stamp_ns: int, *, payload: bytes | None = None, error: bytes | None = None) -> bytes:
    """One SSE event: ``data: {"timestamp", "payload" | "error"}`` and a blank line."""
    field = b'"payload":' + payload if payload is not None else b'"error":' + error
    return b'data: {"timestamp":"' + rfc3339(stamp_ns) + b'",' + field + b"}\n\n"


def error_frame(stream: Stream, exc: IpcError, stamp_ns: int | None = None) -> bytes:
    """The ``error`` frame of ``stream``: the error body a GET of its resource would answer."""
    if stream.kind != "data":  # feeds: an execution's or a parameter's error body (app/subscriptions/feeds.py)
        return frame(time.time_ns() if stamp_ns is None else stamp_ns,
                     error=feeds.error(stream.kind, stream.entity_id, stream.target, exc))
    body = samples.error(exc, stream.entity_id, stream.topic, stream.topic, 0).to_dict()
    return frame(time.time_ns() if stamp_ns is None else stamp_ns, error=orjson.dumps(body))


class SendStalled(OSError):
    """A frame could not be written within the send timeout: the client is not reading."""

    def __init__(self, seconds: float):
        super().__init__(errno.EPIPE, f"the client took no frame for {seconds:g} s (stream_send_timeout)")


def chunked(data: bytes) -> bytes:
    """``data`` as one HTTP/1.1 chunk (what the server would frame a yielded piece as)."""
    return b"%X\r\n" % len(data) + data + b"\r\n"


KEEPALIVE_FRAME = b": keep-alive\n\n"
KEEPALIVE_CHUNK = chunked(KEEPALIVE_FRAME)


class Stream:
    """One open ``.../events`` response.

    ``sock``: the client's connection (gunicorn's gevent socket), written directly: the response
    head goes through the server (the body's first, empty piece), then each frame is sent on the
    connection by the hub's reader as it is pushed (one non-blocking send; a frame shared by every
    stream of its key and entity, already framed as a chunk when the response is chunked).  What
    the kernel does not take at once is written by the stream's own greenlet; a write that lasts
    longer than the send timeout is cut by the hub's ticker (``sending_since``), no timer per frame.
    Without ``sock`` (a test client), frames are yielded to the server.
    """

    def __init__(self, hub: StreamHub, sub: dict[str, Any], sock: Any = None, framed: bool = False):
        self.hub = hub
        self.id: str = sub["id"]
        self.collection: str = sub["collection"]
        self.entity_id: str = sub["entity_id"]
        self.topic: str = sub["topic"]
        self.key: bytes = sub["key"]
        self.interval: str = sub["interval"]
        self.kind: str = sub.get("kind") or "data"   # feeds: "execution" or "parameter" (app/subscriptions/feeds.py)
        self.target: dict[str, Any] = sub.get("target") or {}
        self.expires = time.monotonic() + max(0.0, (sub["expires_at_ns"] - time.time_ns()) / 1e9)
        self.frames: collections.deque[bytes] = collections.deque()
        self.buffered = 0          # bytes in ``frames``
        self.wake = gevent.event.Event()
        self.ended = False
        self.last_frame = time.monotonic()
        self.next_check = 0.0
        self.sock = sock           # written directly (None: frames are yielded to the server)
        self.framed = framed       # direct and chunked: ``frames`` hold HTTP chunks
        self.partial = b""         # direct: the rest of a write the kernel did not take at once
        self.sending_since = 0.0   # direct: monotonic start of the write in progress (0: none)
        self.cut = False           # the ticker cut this stream's connection (a stalled reader)

    @property
    def period(self) -> float:
        return events.INTERVALS[self.interval]

    def push(self, chunk: bytes, framed: bytes | None = None, now: float | None = None) -> None:
        """Queue one frame (``framed``: the same frame as an HTTP chunk, if the caller has it)."""
        if self.ended:
            return
        if self.framed:
            chunk = framed if framed is not None else chunked(chunk)
        self.frames.append(chunk)
        self.buffered += len(chunk)
        while len(self.frames) > STREAM_BUFFER or (self.buffered > STREAM_BUFFER_BYTES and len(self.frames) > 1):
            self.buffered -= len(self.frames.popleft())
            self.hub.counters["frames_dropped"] += 1
        self.last_frame = time.monotonic() if now is None else now
        if self.sock is not None and not self.sending_since and not self.partial:
            self._send_now()
        else:
            self.wake.set()

    def end(self, last: bytes | None = None) -> None:
        if last is not None:
            self.push(last)
        self.ended = True
        self.wake.set()

    def _take(self) -> bytes:
        """Everything queued, as one write (counted as sent here: metrics are flushed per tick)."""
        count = len(self.frames)
        data = self.frames.popleft() if count == 1 else b"".join(self.frames)
        self.frames.clear()
        self.buffered = 0
        self.hub.counters["frames_sent"] += count
        return data

    def _send_now(self) -> None:
        """One non-blocking send of what is queued (the reader's greenlet); the rest is the stream's."""
        data = self._take()
        try:
            sent = self.sock.send(data, 0, 0.0)
        except BlockingIOError:
            sent = 0
        except OSError:  # the client went away: the body ends, the server closes the connection
            self.ended = True
            self.wake.set()
            return
        if sent < len(data):
            self.partial = data[sent:]
            self.wake.set()

    def _write(self, data: bytes) -> None:
        """A blocking write on this stream's greenlet; the ticker cuts it after the send timeout."""
        hub = self.hub
        self.sending_since = time.monotonic()
        hub.sending.add(self)
        try:
            self.sock.sendall(data)
        except OSError:
            if self.cut:
                raise SendStalled(hub.send_timeout) from None
            raise
        finally:
            self.sending_since = 0.0
            hub.sending.discard(self)

    def body(self) -> Iterator[bytes]:
        """The response body: it opens the stream in the hub when it is first iterated, and its
        ``finally`` gives it back (client gone, expiry, end).

        Yielded pieces are written by the server on this greenlet (no ``sock``); with ``sock`` the
        body yields once, empty (the server sends the response head), and writes the rest itself.
        A write that takes longer than the send timeout ends in :class:`SendStalled` (the server
        closes the connection as it does for a client that went away).
        """
        hub = self.hub
        direct = self.sock is not None
        try:
            if direct:
                yield b""  # the server writes the response head now; the frames follow on the socket
            # Registered here, on the first iteration, and nowhere else: a response whose body
            # is never iterated (a HEAD: the server sends no body) registers nothing, so no
            # stream can be open without this ``finally`` to give it back.
            hub.register(self)
            quiet_since = time.monotonic()
            while True:
                if self.partial or self.frames:
                    if direct:
                        data, self.partial = self.partial or self._take(), b""
                        self._write(data)
                    else:
                        yield self._take()
                    quiet_since = time.monotonic()
                    continue
                if self.ended:
                    return
                now = time.monotonic()
                if now >= self.expires:
                    return
                if now - quiet_since >= KEEPALIVE:
                    if direct:
                        self._write(KEEPALIVE_CHUNK if self.framed else KEEPALIVE_FRAME)
                    else:
                        yield KEEPALIVE_FRAME
                    quiet_since = now
                    continue
                self.wake.clear()
                if not self.frames and not self.partial and not self.ended:
                    self.wake.wait(min(self.expires - now, KEEPALIVE - (now - quiet_since)))
        finally:
            hub.close(self)


class StreamHub(channel.Subscriber):
    # Frames come every tick: a subscription that takes a moment to arrive costs one tick, so this
    # hub's streams do not wait for confirmations (app/sse/channel.py) as the event streams do.
    KEYS = (events.CONTROL_KEY, events.HEARTBEAT_KEY)

    def __init__(self, runtime_dir: str, lookup: Callable[[Stream], dict[str, Any]],
                 stopping: Callable[[], bool] = lambda: False,
                 send_timeout: float = 30.0):
        super().__init__(runtime_dir)
        self.send_timeout = send_timeout
        self._lookup = lookup                  # a stream's subscription from the ROS worker (IpcError)
        self._stopping = stopping              # true once this HTTP worker is shutting down
        self.by_key: dict[bytes, set[Stream]] = {}
        self.by_id: dict[str, set[Stream]] = {}
        self.counters = {"open_streams": 0, "frames_sent": 0, "frames_dropped": 0}  # this hub's own
        self.prom = metrics.http()             # the same, as /metrics and /health sum them (app/core/metrics.py)
        self._flushed = {"frames_sent": 0, "frames_dropped": 0}  # counted into ``prom`` so far (per tick)
        self.sending: set[Stream] = set()      # direct streams in a blocking write (the ticker's deadline)
        self._next_scan = 0.0
        self._last_payload: dict[tuple[bytes, str], tuple[float, bytes]] = {}
        # x-medkit.type_info of a frame, as a GET has it: ``type_info`` answers from the process's
        # cache only (the reader never waits on IPC); ``warm`` fills that cache when a stream opens.
        self.type_info: Callable[[Any], bytes | None] = lambda _type: None
        self.warm: Callable[[str], None] = lambda _topic: None

    # ---- lifecycle ------------------------------------------------------------------------
    def loops(self) -> list:
        return [self._tick]

    # ---- streams ----------------------------------------------------------------------------
    def register(self, stream: Stream) -> None:
        """Start feeding ``stream`` (called by its body, on its first iteration only)."""
        self.warm(stream.topic)
        self._add(stream)
        self.by_id.setdefault(stream.id, set()).add(stream)
        self.counters["open_streams"] += 1
        self.prom.streams_open.inc()
        cached = self._last_payload.get((stream.key, stream.entity_id))
        if cached is not None and time.monotonic() - cached[0] < stream.period * 2:
            stream.push(cached[1])  # the latest value at once, not one interval later

    def close(self, stream: Stream) -> None:
        stream.ended = True
        streams = self.by_id.get(stream.id)
        if streams is None or stream not in streams:
            return
        streams.discard(stream)
        if not streams:
            del self.by_id[stream.id]
        self._remove(stream)
        self.counters["open_streams"] -= 1
        self.prom.streams_open.dec()

    def _add(self, stream: Stream) -> None:
        watchers = self.by_key.get(stream.key)
        if watchers is None:
            watchers = self.by_key[stream.key] = set()
            self._sock.setsockopt(zmq.SUBSCRIBE, stream.key)
        watchers.add(stream)

    def _remove(self, stream: Stream) -> None:
        watchers = self.by_key.get(stream.key)
        if watchers is None:
            return
        watchers.discard(stream)
        if not watchers:
            del self.by_key[stream.key]
            self._last_payload = {k: v for k, v in self._last_payload.items() if k[0] != stream.key}
            if self._sock is not None:
                self._sock.setsockopt(zmq.UNSUBSCRIBE, stream.key)

    def end_all(self, last: Callable[[Stream], bytes | None]) -> None:
        for streams in list(self.by_id.values()):
            for stream in list(streams):
                stream.end(last(stream))

    # ---- the reader (channel.Subscriber's greenlet) -------------------------------------------
    def dispatch(self, frames: list[bytes]) -> None:
        key = frames[0]
        if key.startswith(events.DATA_PREFIX):
            if len(frames) == 3:
                self._data(key, protocol.unpack(frames[1]), frames[2])
        elif key == events.HEARTBEAT_KEY:
            self.heartbeat = time.monotonic()
        elif key.startswith(events.CONTROL_KEY) and len(frames) == 2:
            self._control(protocol.unpack(frames[1]))

    def _data(self, key: bytes, meta: dict[str, Any], data: bytes) -> None:
        watchers = self.by_key.get(key)
        if not watchers:
            return
        now = time.monotonic()
        self.heartbeat = max(self.heartbeat, now)  # frames prove the worker is there
        stamp = meta.get("ts") if isinstance(meta.get("ts"), int) else time.time_ns()
        # Each frame's bytes are built once per entity (and framed as an HTTP chunk once), then shared.
        chunks: dict[str, list[bytes | None]] = {}
        for stream in list(watchers):
            made = chunks.get(stream.entity_id)
            if made is None:
                raw = self._chunk(stream, stamp, meta, data)
                made = chunks[stream.entity_id] = [raw, None]
                self._last_payload[(key, stream.entity_id)] = (now, raw)
            if stream.framed:
                if made[1] is None:
                    made[1] = chunked(made[0])
                stream.push(made[0], made[1], now)
            else:
                stream.push(made[0], None, now)
            if meta.get("last"):  # feeds: a finished execution's last frame ends its streams
                stream.end()

    def _chunk(self, stream: Stream, stamp: int, meta: dict[str, Any], data: bytes) -> bytes:
        if stream.kind != "data":  # feeds: the body a GET of the execution or parameter answers
            if "error" in meta:
                return error_frame(stream, IpcError.from_wire(meta["error"]), stamp)
            return frame(stamp, payload=feeds.payload(stream.kind, stream.entity_id, orjson.loads(data)))
        if "error" in meta:
            return error_frame(stream, IpcError.from_wire(meta["error"]), stamp)
        head, payload, tail = samples.body_parts(stream.topic, {**meta, "data_json": data}, stream.entity_id,
                                                 self.type_info(meta.get("type")))
        return frame(stamp, payload=head + payload + tail)

    def _control(self, event: dict[str, Any]) -> None:
        streams = list(self.by_id.get(event.get("id"), ()))
        kind = event.get("event")
        if kind in ("deleted", "expired"):
            for stream in streams:
                stream.end()
        elif kind == "updated":
            for stream in streams:
                self._apply(stream, event["key"], event["interval"], float(event["expires_in"]))

    def _apply(self, stream: Stream, key: bytes, interval: str, expires_in: float) -> None:
        """Give ``stream`` its subscription's current key, interval and expiry (from an ``updated``
        event, or from a ``sub_get`` of the silence check when that event was lost)."""
        if stream.ended:
            return
        if key != stream.key:
            self._remove(stream)
            stream.key = key
            self._add(stream)
        stream.interval = interval
        stream.expires = time.monotonic() + expires_in
        stream.wake.set()

    # ---- the ticker -------------------------------------------------------------------------
    def _tick(self) -> None:
        while True:
            try:
                gevent.sleep(TICK)
                now = time.monotonic()
                self._flush_metrics()
                self._cut_stalled(now)
                if self._stopping():
                    self.end_all(lambda s: error_frame(s, SHUTDOWN))
                    return
                if self.by_id and not self.worker_up:
                    for streams in list(self.by_id.values()):
                        for stream in list(streams):
                            if now - stream.last_frame >= stream.period:
                                stream.push(error_frame(stream, UNAVAILABLE))
                elif self.by_id and now >= self._next_scan:
                    self._next_scan = now + SILENT_SCAN
                    self._check_silent(now)
            except gevent.GreenletExit:
                raise
            except Exception:
                log.exception("stream ticker failed a round")

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

    def _check_silent(self, now: float) -> None:
        """Streams that get no frames while the ROS worker is there: is their subscription gone,
        or was it changed by an ``updated`` event this process never got?

        (A ROS worker killed before it saved a new subscription comes back without it; a PUB
        socket drops what it sends while a SUB is reconnecting, see ``ipc/PROTOCOL.md``.)
        """
        for streams in list(self.by_id.values()):
            for stream in list(streams):
                if now - stream.last_frame >= max(SILENT_CHECK, 5 * stream.period) and now >= stream.next_check:
                    stream.next_check = now + SILENT_CHECK
                    gevent.spawn(self._verify, stream)

    def _verify(self, stream: Stream) -> None:
        """Apply what the ROS worker says of a silent stream's subscription: it is gone (the
        stream ends), or its key, interval or expiry moved (the stream follows)."""
        try:
            sub = self._lookup(stream)
        except IpcError as exc:
            if exc.code == "no-such-subscription":
                stream.end(error_frame(stream, exc))
            return
        expires_in = max(0.0, (sub["expires_at_ns"] - time.time_ns()) / 1e9)
        if sub["key"] != stream.key or sub["interval"] != stream.interval \
                or abs(stream.expires - time.monotonic() - expires_in) > EXPIRY_SLACK:
            log.info("stream of %s: applying the subscription's current interval %s (an update was "
                     "not received on the events channel)", stream.id, sub["interval"])
            self._apply(stream, sub["key"], sub["interval"], expires_in)


EXTENSION = "sovd_streams"


class _PerProcess:
    """The app's hub, made in the process that first opens a stream (never before the fork)."""

    def __init__(self, runtime_dir: str, ros: rosclient.RosClient, send_timeout: float):
        self.runtime_dir = runtime_dir
        self.ros = ros
        self.send_timeout = send_timeout
        # Through a weak method: a bound one would make a reference cycle, so that the app's
        # RosClient (and its ZeroMQ context) would wait for the cyclic collector to be freed.
        make = weakref.WeakMethod(self._make_hub)
        self._hub: PerProcess[StreamHub] = PerProcess(lambda: make()(), StreamHub.stop)
        self._fetching: set[str] = set()

    def get(self) -> StreamHub:
        return self._hub.get()

    def _make_hub(self) -> StreamHub:
        hub = StreamHub(self.runtime_dir, self._lookup, _worker_stopping, self.send_timeout)
        hub.type_info = self._type_info
        hub.warm = self._warm
        hub.start()
        return hub

    def _type_info(self, type_name: Any) -> bytes | None:
        """The cached type_info of a frame's type; a miss is fetched in the background, once."""
        if not isinstance(type_name, str):
            return None
        cached = self.ros.cached_type_info_json(type_name)
        if cached is None and type_name not in self._fetching:
            self._fetching.add(type_name)
            gevent.spawn(self._fetch, type_name)
        return cached or None

    def _fetch(self, type_name: str) -> None:
        try:
            self.ros.type_info(type_name, timeout=LOOKUP_TIMEOUT * 4)
        except IpcError as exc:
            log.info("type_info %s: %s", type_name, exc.message)
        finally:
            self._fetching.discard(type_name)

    def _warm(self, topic: str) -> None:
        """Before a stream's first frame (in its request's greenlet): its type's type_info cached."""
        try:
            table = self.ros.entities().topics.get(topic) or {}
            types = table.get("types")
            if isinstance(types, list) and types and isinstance(types[0], str):
                self.ros.type_info(types[0], timeout=self.ros.ipc_timeout)
        except IpcError as exc:
            log.info("type_info for %s: %s", topic, exc.message)

    def _lookup(self, stream: Stream) -> dict[str, Any]:
        return self.ros.call("sub_get", {"collection": stream.collection, "entity_id": stream.entity_id,
                                  "id": stream.id}, timeout=LOOKUP_TIMEOUT)

    def close(self) -> None:
        self._hub.reset()


def _worker_stopping() -> bool:
    """True once the HTTP worker this process is has begun to stop (its streams must end)."""
    from ..http_worker import stopping

    return stopping().is_set()


def init_app(app: Flask) -> None:
    cfg = app.config["SOVD"]
    app.extensions[EXTENSION] = _PerProcess(cfg.runtime_dir, app.extensions[rosclient.EXTENSION],
                                            cfg.stream_send_timeout)


def get() -> StreamHub:
    return current_app.extensions[EXTENSION].get()


def body(sub: dict[str, Any], environ: dict[str, Any]) -> Iterator[bytes]:
    """The body of one ``.../events`` response for ``sub`` (a ``sub_get`` answer).

    Nothing happens until the server iterates it (not even this process's hub
    being made): a HEAD, whose body is never iterated, opens no stream.
    """
    # The app and the connection are looked up now, in the request.
    return _serve(current_app.extensions[EXTENSION], sub, environ.get("gunicorn.socket"),
                  environ.get("SERVER_PROTOCOL", "HTTP/1.1"))


def _serve(per_process: _PerProcess, sub: dict[str, Any], sock: Any, protocol_: str = "HTTP/1.1") -> Iterator[bytes]:
    if sock is not None:  # gunicorn's connection (not there under a test client)
        # The connection keeps this buffer after the stream if it is used again (keep-alive).
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, STREAM_SNDBUF)
        except OSError as exc:
            log.warning("could not bound a stream's send buffer: %s", exc)
    direct = isinstance(sock, gevent.socket.socket)  # gunicorn's gevent worker: written directly
    # gunicorn frames the body in chunks for HTTP/1.1 (no Content-Length, not a HEAD: a HEAD never
    # iterates this body), as-is for HTTP/1.0; a direct stream frames its writes the same way.
    framed = direct and protocol_ not in ("HTTP/1.0", "HTTP/0.9")
    yield from Stream(per_process.get(), sub, sock if direct else None, framed).body()
