"""``GET /api/v1/faults/stream``: medkit's real-time fault stream, as Server-Sent Events.

One :class:`FaultHub` per HTTP worker process, made when its first stream
opens (never before the fork): a ZeroMQ SUB socket on the ROS worker's events
channel (``ipc/events.py``) subscribed to the fault events only (``f|``), and
a reader greenlet that formats each event once and hands it to every open
stream of the process.

An event is medkit's: ``id: <n>``, ``event: fault_confirmed | fault_updated |
fault_cleared`` and ``data: {"event_type", "fault", "timestamp"}``.  Event ids
never go backwards, across restarts too (``rosworker/faults/manager.py``), so a client
that reconnects with ``Last-Event-ID`` gets what it missed, replayed from the
ROS worker (the last ``MAX_EVENTS``), then the live events.  A restarted ROS
worker publishes before this process's subscription has reached it (the
channel loses what it sends meanwhile, ``ipc/PROTOCOL.md``): once the
subscription is confirmed again, the hub asks it for the events after the
oldest an open stream has, and hands them on before the live ones.

Bounds: ``max_fault_streams`` open streams per HTTP worker (503 past it, as
medkit's client limit); ``STREAM_BUFFER`` events held for a slow client (the
oldest go first; it may reconnect with ``Last-Event-ID``); a client that takes
no frame for ``stream_send_timeout`` seconds is disconnected; a ``:`` keep-alive
after ``KEEPALIVE`` seconds of silence.
"""

from __future__ import annotations

import collections
import logging
import socket
import time
from collections.abc import Callable, Iterator
from typing import Any

import gevent
import gevent.event
import orjson

from common.process import PerProcess
from ipc import events, protocol
from ipc.errors import IpcError

from ..sse import channel
from ..subscriptions.hub import KEEPALIVE, SendStalled, _worker_stopping

log = logging.getLogger("sovd.http.faultstream")

STREAM_BUFFER = 256       # events held for a slow client
STOP_CHECK = 1.0          # seconds between two looks at whether this HTTP worker is stopping
REPLAY_TIMEOUT = 2.0      # seconds the replay of missed events may take to fetch


def chunk(event_id: int, event: dict[str, Any]) -> bytes:
    """One SSE event as medkit formats it."""
    kind = str(event.get("event_type", "")).replace("\r", "").replace("\n", "")
    data = {"event_type": kind, "fault": event.get("fault"), "timestamp": event.get("timestamp")}
    return b"id: %d\nevent: %s\ndata: %s\n\n" % (event_id, kind.encode(), orjson.dumps(data))


class FaultStream:
    def __init__(self, hub: FaultHub, last_id: int):
        self.hub = hub
        self.last_id = last_id          # the newest id this client has (or is sent in the replay)
        self.frames: collections.deque[tuple[int, bytes]] = collections.deque()
        self.wake = gevent.event.Event()
        self.dropped = 0

    def push(self, event_id: int, frame: bytes) -> None:
        self.frames.append((event_id, frame))
        while len(self.frames) > STREAM_BUFFER:
            self.frames.popleft()
            self.dropped += 1
        self.wake.set()

    def body(self, replay, sock: Any = None) -> Iterator[bytes]:
        """The response body; ``sock`` (gunicorn's connection) is looked at for a client that left."""
        hub = self.hub
        hub.replay = replay
        stalled = gevent.Timeout(hub.send_timeout, SendStalled(hub.send_timeout))
        hub.streams.add(self)
        try:
            pending: list[tuple[int, bytes]] = []
            if self.last_id:
                try:
                    pending = [(e["id"], chunk(e["id"], e)) for e in replay(self.last_id)
                               if isinstance(e, dict) and isinstance(e.get("id"), int)]
                except IpcError as exc:
                    log.info("fault stream: no replay after event %d: %s", self.last_id, exc.message)
            # The head goes out once the ROS worker has this process's subscription (app/sse/channel.py),
            # then at once (the client knows the stream is open), with a comment.
            hub.confirmations.wait(events.FAULT_KEY)
            yield b": fault stream open\n\n"
            quiet_since = time.monotonic()
            while True:
                event_id = None
                if pending:
                    event_id, frame = pending.pop(0)
                elif self.frames:
                    event_id, frame = self.frames.popleft()
                    if event_id <= self.last_id:
                        continue  # replayed already
                if event_id is not None:
                    self.last_id = max(self.last_id, event_id)
                    stalled.start()
                    try:
                        yield frame
                    finally:
                        stalled.cancel()
                    quiet_since = time.monotonic()
                    continue
                if _worker_stopping() or _gone(sock):
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
                if not self.frames:
                    self.wake.wait(min(STOP_CHECK, KEEPALIVE - (now - quiet_since)))
        finally:
            hub.streams.discard(self)


def _gone(sock: Any) -> bool:
    """True when the client closed its connection (a peek at the real socket, never waiting)."""
    real = getattr(sock, "_sock", sock)
    if real is None:
        return False
    try:
        return real.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
    except (BlockingIOError, InterruptedError):
        return False
    except OSError:
        return True


class FaultHub(channel.Subscriber):
    KEYS = (events.FAULT_KEY,)
    NAME = "fault events"

    def __init__(self, runtime_dir: str, send_timeout: float):
        super().__init__(runtime_dir)
        self.send_timeout = send_timeout
        self.streams: set[FaultStream] = set()
        self.replay: Callable[[int], list[dict[str, Any]]] | None = None  # fault_events, set by a stream
        self._caught_up = 0   # the reconnects whose missed events were fetched

    def dispatch(self, frames: list[bytes]) -> None:
        if len(frames) == 1:  # a confirmation: after a reconnect, what the ROS worker sent before it
            if frames[0] == events.FAULT_KEY and self._caught_up != self.reconnects:
                self._caught_up = self.reconnects
                self._catch_up()
            return
        if frames[0] != events.FAULT_KEY:
            return
        event = protocol.unpack(frames[1], protocol.MAX_REPLY_FRAME)
        event_id = event.get("id")
        if not isinstance(event_id, int):
            return
        frame = chunk(event_id, event)
        for stream in list(self.streams):
            stream.push(event_id, frame)


    def _catch_up(self) -> None:
        """The events after the oldest an open stream has, handed on before the live ones that follow (the
        reader waits for them: the live events queue in the socket meanwhile)."""
        streams = list(self.streams)
        if not streams or self.replay is None:
            return
        try:
            missed = self.replay(min(stream.last_id for stream in streams))
        except IpcError as exc:
            log.info("fault stream: no catch-up after the ROS worker came back: %s", exc.message)
            return
        for event in missed:
            if isinstance(event, dict) and isinstance(event.get("id"), int):
                frame = chunk(event["id"], event)
                for stream in streams:
                    if event["id"] > stream.last_id:
                        stream.push(event["id"], frame)


def _started(runtime_dir: str, send_timeout: float) -> FaultHub:
    made = FaultHub(runtime_dir, send_timeout)
    made.start()
    return made


_HUBS: dict[str, PerProcess[FaultHub]] = {}


def hub(runtime_dir: str, send_timeout: float) -> FaultHub:
    per_process = _HUBS.get(runtime_dir)
    if per_process is None:
        per_process = _HUBS[runtime_dir] = PerProcess(lambda: _started(runtime_dir, send_timeout), FaultHub.stop)
    return per_process.get()
