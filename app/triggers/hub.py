"""The HTTP worker's side of triggers: their event streams (``.../triggers/{id}/events``).

One :class:`TriggerHub` per HTTP worker process, made on first use after the
fork, with its own ZeroMQ SUB socket on the ROS worker's events channel
(``ipc/events.py``): it subscribes to the triggers' control frames, to the
heartbeat, and to the events of the triggers its open streams watch, so a
process receives a trigger's event once however many of its streams watch
it, and nothing of the triggers it does not stream.

A trigger's events come only when it fires.  Each stream holds at most
``EVENT_BUFFER`` events and ``STREAM_BUFFER_BYTES`` (``app/subscriptions/hub.py``'s
bound): past them the oldest go first (the newest event wins) and each one
dropped is counted in ``frames_dropped`` (``/health``, ``/metrics``); a client
that takes no event for ``stream_send_timeout`` seconds is disconnected.  A
``:`` keep-alive comment goes after ``KEEPALIVE`` (15) seconds of silence.

A stream ends at once when its trigger is deleted or expires (a control
frame), after a one-shot trigger's event, and when the HTTP worker stops.
Its first frame may be an event that fired before it opened (``trig_open``
hands the newest one no stream was opened for: a one-shot trigger may fire
before its client has connected); events carry a sequence number, so one is
never sent twice.  While the ROS worker is gone a stream gets one ``error``
frame and stays open; a silent stream's trigger is looked up every
``VERIFY_EVERY`` seconds, so a trigger lost with a control frame (a ROS
worker killed) does not leave the stream open for ever.
"""

from __future__ import annotations

import collections
import logging
import socket
import time
import weakref
from collections.abc import Callable, Iterator
from typing import Any

import gevent
import gevent.event
import orjson
from flask import Flask, current_app

from common.process import PerProcess
from ipc import events, protocol
from ipc.errors import IpcError

from ..core import metrics, rosclient
from ..sse import channel
from ..subscriptions.hub import (
    KEEPALIVE,
    STREAM_BUFFER_BYTES,
    STREAM_SNDBUF,
    SendStalled,
    frame,
)

log = logging.getLogger("sovd.http.triggers")

TICK = 0.25           # seconds between the ticker's rounds
# Events a stream holds for a slow client (and STREAM_BUFFER_BYTES): a trigger's events are discrete
# (a burst of changes is several events, each worth sending), so more than a cyclic stream's frames.
EVENT_BUFFER = 64
VERIFY_EVERY = 10.0   # seconds between two look-ups of a silent stream's trigger
LOOKUP_TIMEOUT = 1.0
EXTENSION = "sovd_trigger_streams"


def _error_frame(stamp: int, message: str) -> bytes:
    return frame(stamp, error=orjson.dumps(message))


class TriggerStream:
    """One open ``.../triggers/{id}/events`` response."""

    def __init__(self, hub: TriggerHub, trigger: dict[str, Any]):
        self.hub = hub
        self.id: str = trigger["id"]
        self.collection: str = trigger["collection"]
        self.entity_id: str = trigger["entity_id"]
        self.key = events.trigger_event_key(self.id)
        self.frames: collections.deque[bytes] = collections.deque()
        self.buffered = 0
        self.seq = 0                  # the newest event's sequence number pushed
        self.wake = gevent.event.Event()
        self.ended = False
        self.finish = False           # end once the buffer is written (a one-shot's event)
        self.last_frame = time.monotonic()
        self.next_check = time.monotonic() + VERIFY_EVERY
        self.told_down = False

    def event(self, meta: dict[str, Any], payload: bytes) -> None:
        seq = meta.get("seq")
        if isinstance(seq, int):
            if seq <= self.seq:
                return  # already sent (a replayed event that also came on the channel)
            self.seq = seq
        stamp = meta["ts"] if isinstance(meta.get("ts"), int) else time.time_ns()
        if isinstance(meta.get("error"), str):
            self.push(_error_frame(stamp, meta["error"]))
        else:
            self.push(frame(stamp, payload=payload or b"{}"))
        if meta.get("last"):
            self.finish = True
            self.wake.set()

    def push(self, chunk: bytes) -> None:
        if self.ended:
            return
        self.frames.append(chunk)
        self.buffered += len(chunk)
        while len(self.frames) > EVENT_BUFFER or (self.buffered > STREAM_BUFFER_BYTES and len(self.frames) > 1):
            self.buffered -= len(self.frames.popleft())
            self.hub.dropped += 1
            self.hub.prom.frames_dropped.inc()
        self.last_frame = time.monotonic()
        self.wake.set()

    def end(self, last: bytes | None = None) -> None:
        if last is not None:
            self.push(last)
        self.finish = True
        self.wake.set()

    def body(self) -> Iterator[bytes]:
        hub = self.hub
        stalled = gevent.Timeout(hub.send_timeout, SendStalled(hub.send_timeout))
        try:
            hub.register(self)  # first: events from now on reach this stream ...
            # ... once the ROS worker has the subscription (app/sse/channel.py): before that, an event
            # would be dropped at its end while the client already counts on it
            hub.confirmations.wait(self.key, events.TRIGGER_CONTROL_PREFIX)
            hub.replay(self)    # then: what fired before it opened
            yield b""           # the response's head goes now, not with the first event
            quiet_since = time.monotonic()
            while True:
                if self.frames:
                    chunk = self.frames.popleft()
                    self.buffered -= len(chunk)
                    hub.prom.frames_sent.inc()
                    stalled.start()
                    try:
                        yield chunk
                    finally:
                        stalled.cancel()
                    quiet_since = time.monotonic()
                    continue
                if self.finish or self.ended:
                    return
                now = time.monotonic()
                if now - quiet_since >= KEEPALIVE:
                    stalled.start()
                    try:
                        yield b": keep-alive\n\n"
                    finally:
                        stalled.cancel()
                    quiet_since = now
                    continue
                self.wake.clear()
                if not self.frames and not self.finish:
                    self.wake.wait(KEEPALIVE - (now - quiet_since))
        finally:
            hub.close(self)


class TriggerHub(channel.Subscriber):
    KEYS = (events.TRIGGER_CONTROL_PREFIX, events.HEARTBEAT_KEY)
    NAME = "events channel (triggers)"

    def __init__(self, runtime_dir: str, lookup: Callable[[TriggerStream, bool], dict[str, Any]],
                 stopping: Callable[[], bool] = lambda: False, send_timeout: float = 30.0):
        super().__init__(runtime_dir)
        self.send_timeout = send_timeout
        self._lookup = lookup           # (stream, open) -> trig_get / trig_open answer (IpcError)
        self._stopping = stopping
        self.by_id: dict[str, set[TriggerStream]] = {}
        self.dropped = 0
        self.prom = metrics.http()

    def loops(self) -> list:
        return [self._tick]

    # ---- streams --------------------------------------------------------------------------------
    def register(self, stream: TriggerStream) -> None:
        streams = self.by_id.get(stream.id)
        if streams is None:
            streams = self.by_id[stream.id] = set()
            self.subscribe(stream.key)
        streams.add(stream)
        self.prom.streams_open.inc()

    def replay(self, stream: TriggerStream) -> None:
        try:
            trigger = self._lookup(stream, True)
        except IpcError as exc:
            if exc.code == "no-such-trigger":
                stream.ended = True
            return
        replay = trigger.get("replay")
        if isinstance(replay, dict):
            stream.event(replay, replay.get("payload") or b"")
        if trigger.get("status") != "active":
            stream.end()

    def close(self, stream: TriggerStream) -> None:
        stream.ended = True
        streams = self.by_id.get(stream.id)
        if streams is None or stream not in streams:
            return
        streams.discard(stream)
        self.prom.streams_open.dec()
        if not streams:
            del self.by_id[stream.id]
            self.unsubscribe(stream.key)

    # ---- the reader (channel.Subscriber's greenlet) ---------------------------------------------
    def dispatch(self, frames: list[bytes]) -> None:
        key = frames[0]
        if key == events.HEARTBEAT_KEY:
            self.heartbeat = time.monotonic()
            return
        if len(frames) < 2 or not key.startswith(b"t|"):
            return
        trigger_id = key[4:-1].decode(errors="replace")
        streams = self.by_id.get(trigger_id)
        if not streams:
            return
        meta = protocol.unpack(frames[1])
        if key.startswith(events.TRIGGER_CONTROL_PREFIX):
            if meta.get("event") in ("deleted", "expired"):
                for stream in list(streams):
                    stream.end()
            return
        payload = frames[2] if len(frames) > 2 else b""
        for stream in list(streams):
            stream.event(meta, payload)

    # ---- the ticker ------------------------------------------------------------------------------
    def _tick(self) -> None:
        while True:
            try:
                gevent.sleep(TICK)
                if self._stopping():
                    for streams in list(self.by_id.values()):
                        for stream in list(streams):
                            stream.end(_error_frame(time.time_ns(), "The gateway is shutting down; "
                                                                    "this stream ends"))
                    return
                now = time.monotonic()
                up = self.worker_up
                for streams in list(self.by_id.values()):
                    for stream in list(streams):
                        if not up and not stream.told_down:
                            stream.told_down = True
                            stream.push(_error_frame(time.time_ns(), "The ROS worker is not running; "
                                                                     "events resume when it is back"))
                        elif up:
                            stream.told_down = False
                            if now >= stream.next_check and now - stream.last_frame >= VERIFY_EVERY:
                                stream.next_check = now + VERIFY_EVERY
                                gevent.spawn(self._verify, stream)
            except gevent.GreenletExit:
                raise
            except Exception:
                log.exception("trigger stream ticker failed a round")

    def _verify(self, stream: TriggerStream) -> None:
        try:
            trigger = self._lookup(stream, False)
        except IpcError as exc:
            if exc.code == "no-such-trigger":
                stream.end()
            return
        if trigger.get("status") != "active":
            stream.end()


class _PerProcess:
    def __init__(self, runtime_dir: str, ros: rosclient.RosClient, send_timeout: float):
        self.runtime_dir = runtime_dir
        self.ros = ros
        self.send_timeout = send_timeout
        make = weakref.WeakMethod(self._make_hub)
        self._hub: PerProcess[TriggerHub] = PerProcess(lambda: make()(), TriggerHub.stop)

    def get(self) -> TriggerHub:
        return self._hub.get()

    def _make_hub(self) -> TriggerHub:
        hub = TriggerHub(self.runtime_dir, self._lookup, _worker_stopping, self.send_timeout)
        hub.start()
        return hub

    def _lookup(self, stream: TriggerStream, opening: bool) -> dict[str, Any]:
        return self.ros.call("trig_open" if opening else "trig_get",
                             {"collection": stream.collection, "entity_id": stream.entity_id, "id": stream.id},
                             timeout=LOOKUP_TIMEOUT)

    def close(self) -> None:
        self._hub.reset()


def _worker_stopping() -> bool:
    from ..http_worker import stopping

    return stopping().is_set()


def init_app(app: Flask) -> None:
    cfg = app.config["SOVD"]
    app.extensions[EXTENSION] = _PerProcess(cfg.runtime_dir, app.extensions[rosclient.EXTENSION],
                                            cfg.stream_send_timeout)


def body(trigger: dict[str, Any], environ: dict[str, Any]) -> Iterator[bytes]:
    """The body of one ``.../triggers/{id}/events`` response (nothing happens until it is iterated)."""
    return _serve(current_app.extensions[EXTENSION], trigger, environ.get("gunicorn.socket"))


def _serve(per_process: _PerProcess, trigger: dict[str, Any], sock: Any) -> Iterator[bytes]:
    if sock is not None:
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, STREAM_SNDBUF)
        except OSError as exc:
            log.warning("could not bound a stream's send buffer: %s", exc)
    yield from TriggerStream(per_process.get(), trigger).body()
