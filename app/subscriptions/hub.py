"""The HTTP worker's side of cyclic subscriptions: one events socket, many SSE streams.

One :class:`StreamHub` per HTTP worker process (``app/sse/hub.py``: the SUB
socket, the counters, the stall cut, the ticker are the base's; a stream is
``app/sse/stream.py``'s, with at most ``STREAM_BUFFER`` frames and
``STREAM_BUFFER_BYTES``, the oldest dropped first: latest-value semantics).

- The *reader* receives each data frame once per key (a topic at an interval
  and bytes mode; a goal's or a parameter's subscription), builds its SSE chunk
  once per entity (the payload is exactly the body a GET of the resource
  answers, made by the family that streams it: ``core/resources.py``'s
  ``Streamable``; a topic's ``type_info`` comes from the process's cache,
  filled when a stream opens, so the reader never waits on IPC) and hands it to
  every stream watching that key (issue 23: the frame's bytes, already framed
  as an HTTP chunk, are made once per key and entity and shared; one
  non-blocking send per stream per frame).  Control frames retime, re-key or
  end streams; a frame with ``last`` (a goal that finished) ends its streams.
- A new stream gets the latest frame of its key at once, not one interval
  later (when it is younger than two intervals).
- The ticker stands in while the ROS worker is down: every stream gets an
  ``error`` frame per interval (the error a GET would answer), so the stream
  stays open and visibly degraded until data frames come back; it ends every
  stream with a last ``error`` frame when the HTTP worker shuts down; and it
  looks up the subscription of a stream that gets no frames (``SILENT_CHECK``):
  gone, or changed by an ``updated`` event this process never got.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from typing import Any

import gevent
from flask import Flask

from ipc import events, protocol
from ipc.errors import IpcError

from ..core import rosclient
from ..core.resources import Streamable, stream_kinds
from ..sse import hub as sse
from ..sse.hub import Hub
from ..sse.stream import Stream, chunked, frame

log = logging.getLogger("sovd.http.streams")

NAME = "subscriptions"
STREAM_BUFFER = 4          # frames a stream holds for a slow client; the oldest go first
LOOKUP_TIMEOUT = 0.5       # seconds a silent stream's sub_get may take
SILENT_CHECK = 2.0         # seconds without frames (worker up) before a stream's subscription is looked up
EXPIRY_SLACK = 1.0         # seconds an expiry from sub_get may differ from a stream's before it is applied
SILENT_SCAN = 0.5          # seconds between two scans of every stream for silence (a scan is O(streams))

UNAVAILABLE = IpcError("unavailable", "The ROS worker is not running; data frames resume when it is back")
SHUTDOWN = IpcError("shutdown", "The gateway is shutting down; this stream ends")


class StreamHub(Hub):
    # Frames come every tick: a subscription that takes a moment to arrive costs one tick, so this
    # hub's streams do not wait for confirmations (app/sse/channel.py) as the event streams do.
    KEYS = (events.CONTROL_KEY, events.HEARTBEAT_KEY)
    NAME = "events channel (cyclic subscriptions)"

    def __init__(self, runtime_dir: str, lookup: Callable[[Stream], dict[str, Any]],
                 stopping: Callable[[], bool] = lambda: False, send_timeout: float = 30.0,
                 kinds: dict[str, Streamable] | None = None):
        super().__init__(runtime_dir, send_timeout, stopping)
        self._lookup = lookup                  # a stream's subscription from the ROS worker (IpcError)
        self.kinds = kinds or {}               # what renders each kind's frames (core/resources.py)
        self._next_scan = 0.0
        self._last_payload: dict[tuple[bytes, str], tuple[float, bytes]] = {}

    # ---- streams ----------------------------------------------------------------------------
    def stream(self, sub: dict[str, Any], sock: Any = None, framed: bool = False) -> Stream:
        """A stream of ``sub`` (a ``sub_get`` answer)."""
        stream = Stream(self, STREAM_BUFFER, sock, framed,
                        expires=time.monotonic() + max(0.0, (sub["expires_at_ns"] - time.time_ns()) / 1e9))
        stream.id, stream.collection, stream.entity_id = sub["id"], sub["collection"], sub["entity_id"]
        stream.topic, stream.key, stream.interval = sub["topic"], sub["key"], sub["interval"]
        stream.kind = sub.get("kind") or "data"
        stream.target = sub.get("target") or {}
        stream.next_check = 0.0
        return stream

    def added(self, stream: Stream) -> None:
        renderer = self.kinds.get(stream.kind)
        if renderer is not None and renderer.opening is not None:
            renderer.opening(stream)
        self.index(stream)
        cached = self._last_payload.get((stream.key, stream.entity_id))
        if cached is not None and time.monotonic() - cached[0] < events.INTERVALS[stream.interval] * 2:
            stream.push(cached[1])  # the latest value at once, not one interval later

    def removed(self, stream: Stream) -> None:
        if self.unindex(stream):
            self._forget_payload(stream.key)

    def _forget_payload(self, key: bytes) -> None:
        """Nobody here watches ``key`` any more: its latest frames are not kept."""
        self._last_payload = {k: v for k, v in self._last_payload.items() if k[0] != key}

    def last(self, stream: Stream) -> bytes | None:
        return self.error_frame(stream, SHUTDOWN)

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
            if meta.get("last"):  # a goal that finished: its last frame ends its streams
                stream.end()

    def _chunk(self, stream: Stream, stamp: int, meta: dict[str, Any], data: bytes) -> bytes:
        if "error" in meta:
            return self.error_frame(stream, IpcError.from_wire(meta["error"]), stamp)
        return frame(stamp, payload=self.kinds[stream.kind].payload(stream, meta, data))

    def error_frame(self, stream: Stream, exc: IpcError, stamp_ns: int | None = None) -> bytes:
        """The ``error`` frame of ``stream``: the error body a GET of its resource would answer."""
        return frame(time.time_ns() if stamp_ns is None else stamp_ns, error=self.kinds[stream.kind].error(stream, exc))

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
            if self.unwatch(self.by_key, stream.key, stream, stream.key):
                self._forget_payload(stream.key)
            stream.key = key
            self.watch(self.by_key, key, stream, key)
        stream.interval = interval
        stream.expires = time.monotonic() + expires_in
        stream.wake.set()

    # ---- the ticker -------------------------------------------------------------------------
    def tick(self, now: float) -> None:
        if self.by_id and not self.worker_up:
            for stream in list(self.streams):
                if now - stream.last_frame >= events.INTERVALS[stream.interval]:
                    stream.push(self.error_frame(stream, UNAVAILABLE))
        elif self.by_id and now >= self._next_scan:
            self._next_scan = now + SILENT_SCAN
            self._check_silent(now)

    def _check_silent(self, now: float) -> None:
        """Streams that get no frames while the ROS worker is there: is their subscription gone,
        or was it changed by an ``updated`` event this process never got?

        (A ROS worker killed before it saved a new subscription comes back without it; a PUB
        socket drops what it sends while a SUB is reconnecting, see ``ipc/PROTOCOL.md``.)
        """
        for stream in list(self.streams):
            period = events.INTERVALS[stream.interval]
            if now - stream.last_frame >= max(SILENT_CHECK, 5 * period) and now >= stream.next_check:
                stream.next_check = now + SILENT_CHECK
                gevent.spawn(self._verify, stream)

    def _verify(self, stream: Stream) -> None:
        """Apply what the ROS worker says of a silent stream's subscription: it is gone (the
        stream ends), or its key, interval or expiry moved (the stream follows)."""
        try:
            sub = self._lookup(stream)
        except IpcError as exc:
            if exc.code == "no-such-subscription":
                stream.end(self.error_frame(stream, exc))
            return
        expires_in = max(0.0, (sub["expires_at_ns"] - time.time_ns()) / 1e9)
        if sub["key"] != stream.key or sub["interval"] != stream.interval \
                or abs(stream.expires - time.monotonic() - expires_in) > EXPIRY_SLACK:
            log.info("stream of %s: applying the subscription's current interval %s (an update was "
                     "not received on the events channel)", stream.id, sub["interval"])
            self._apply(stream, sub["key"], sub["interval"], expires_in)


# ---- this app's hub ---------------------------------------------------------------------------------------
def setup(app: Flask) -> None:
    cfg = app.config["SOVD"]
    ros = app.extensions[rosclient.EXTENSION]

    def make(app_: Flask) -> StreamHub:
        def lookup(stream: Stream) -> dict[str, Any]:
            return ros.call("sub_get", {"collection": stream.collection, "entity_id": stream.entity_id,
                                        "id": stream.id}, timeout=LOOKUP_TIMEOUT)

        return StreamHub(cfg.runtime_dir, lookup, sse.worker_stopping, cfg.stream_send_timeout, stream_kinds(app_))

    sse.register(app, NAME, make)


def body(sub: dict[str, Any], environ: dict[str, Any]) -> Iterator[bytes]:
    """The body of one ``.../events`` response for ``sub`` (a ``sub_get`` answer); nothing happens
    until the server iterates it (a HEAD, whose body is never iterated, opens no stream)."""
    return sse.response_body(NAME, lambda hub, sock, framed: hub.stream(sub, sock, framed).body(), environ)
