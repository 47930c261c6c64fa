"""``GET /api/v1/faults/stream``: medkit's real-time fault stream, as Server-Sent Events.

One :class:`FaultHub` per HTTP worker process (``app/sse/hub.py``), subscribed
to the fault events only (``f|``): its reader formats each event once and hands
it to every open stream of the process (``app/sse/stream.py``).

An event is medkit's: ``id: <n>``, ``event: fault_confirmed | fault_updated |
fault_cleared`` and ``data: {"event_type", "fault", "timestamp"}``.  Event ids
never go backwards, across restarts too (``rosworker/faults/manager.py``), so a
client that reconnects with ``Last-Event-ID`` gets what it missed, replayed from
the ROS worker (the last ``MAX_EVENTS``), then the live events (an event is sent
once: its id is the stream's sequence number).  A restarted ROS worker publishes
before this process's subscription has reached it (the channel loses what it
sends meanwhile, ``ipc/PROTOCOL.md``): once the subscription is confirmed again,
the hub asks it for the events after the oldest an open stream has, and hands
them on before the live ones.

Bounds: ``max_fault_streams`` open streams per HTTP worker (503 past it, as
medkit's client limit); ``STREAM_BUFFER`` events held for a slow client (the
oldest go first; it may reconnect with ``Last-Event-ID``); the rest is every
stream's (the stall cut, the keep-alive, the counters).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import orjson
from flask import Flask, request

from ipc import events, protocol
from ipc.errors import IpcError

from ..core import rosclient
from ..core.errors import ApiError
from ..sse import hub as sse
from ..sse.hub import Hub
from ..sse.stream import Stream

log = logging.getLogger("sovd.http.faultstream")

NAME = "faults"
STREAM_BUFFER = 256       # events held for a slow client
REPLAY_TIMEOUT = 2.0      # seconds the replay of missed events may take to fetch
OPEN = b": fault stream open\n\n"


def chunk(event_id: int, event: dict[str, Any]) -> bytes:
    """One SSE event as medkit formats it."""
    kind = str(event.get("event_type", "")).replace("\r", "").replace("\n", "")
    data = {"event_type": kind, "fault": event.get("fault"), "timestamp": event.get("timestamp")}
    return b"id: %d\nevent: %s\ndata: %s\n\n" % (event_id, kind.encode(), orjson.dumps(data))


class FaultHub(Hub):
    KEYS = (events.FAULT_KEY,)
    NAME = "fault events"

    def __init__(self, runtime_dir: str, replay: Callable[[int], list[dict[str, Any]]],
                 stopping: Callable[[], bool] = lambda: False, send_timeout: float = 30.0,
                 endpoint: str = "", name: str = ""):
        self._endpoint = endpoint  # another channel than the ROS worker's (the fleet link's)
        self.NAME = name or self.NAME
        super().__init__(runtime_dir, send_timeout, stopping)
        self.replay = replay      # fault_events: the events after an id (IpcError)
        self._caught_up = 0       # the reconnects whose missed events were fetched

    def endpoint(self) -> str:
        return self._endpoint or super().endpoint()

    def stream(self, last_id: int, sock: Any = None, framed: bool = False) -> Stream:
        stream = Stream(self, STREAM_BUFFER, sock, framed)
        stream.last_seq = last_id   # the newest event this client has
        return stream

    def opening(self, stream: Stream) -> None:
        """Before the response head: what the client missed (``Last-Event-ID``), then the live events
        (held meanwhile) once the ROS worker has this process's subscription (app/sse/channel.py)."""
        stream.hold()
        if stream.last_seq:
            try:
                missed = self.replay(stream.last_seq)
            except IpcError as exc:
                log.info("fault stream: no replay after event %d: %s", stream.last_seq, exc.message)
                missed = []
            held, stream.held = stream.held, None   # the replay first, then what was held (each once)
            for event in missed:
                if isinstance(event, dict) and isinstance(event.get("id"), int):
                    stream.push(chunk(event["id"], event), seq=event["id"])
            stream.held = held
        self.confirmations.wait(events.FAULT_KEY)
        stream.release()

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
            stream.push(frame, seq=event_id)

    def _catch_up(self) -> None:
        """The events after the oldest an open stream has, handed on before the live ones that follow (the
        reader waits for them: the live events queue in the socket meanwhile)."""
        streams = list(self.streams)
        if not streams:
            return
        try:
            missed = self.replay(min(stream.last_seq for stream in streams))
        except IpcError as exc:
            log.info("fault stream: no catch-up after the ROS worker came back: %s", exc.message)
            return
        for event in missed:
            if isinstance(event, dict) and isinstance(event.get("id"), int):
                frame = chunk(event["id"], event)
                for stream in streams:
                    stream.push(frame, seq=event["id"])


# ---- the hubs ---------------------------------------------------------------------------------------------
def register(app: Flask, name: str, client: str = rosclient.EXTENSION, command: str = "fault_events",
             endpoint: Callable[[str], str] | None = None, label: str = "") -> None:
    """Register the hub ``name``: the fault events of the channel at ``endpoint(runtime_dir)`` (the ROS
    worker's by default), the missed ones replayed by ``command`` of the client ``app.extensions[client]``.

    This app's (``setup``), and the fleet gateway's: the robots' events on its link's channel
    (``core/resources.py``'s :class:`~app.core.resources.Relayed` of faults, ``app/fleet/``)."""
    cfg = app.config["SOVD"]

    def make(_app: Flask) -> FaultHub:
        source = _app.extensions[client]

        def replay(after: int) -> list[dict[str, Any]]:
            return source.call(command, {"after": after}, REPLAY_TIMEOUT).get("events") or []

        return FaultHub(cfg.runtime_dir, replay, sse.worker_stopping, cfg.stream_send_timeout,
                        endpoint(cfg.runtime_dir) if endpoint else "", label)

    sse.register(app, name, make)


def setup(app: Flask) -> None:
    register(app, NAME)


def response(name: str, max_streams: int):
    """The answer to ``GET .../faults/stream`` from the hub registered as ``name`` (a :class:`FaultHub`):
    503 past ``max_streams`` open streams of this process, else the stream, after a ``Last-Event-ID``.

    Also the fleet gateway's (``app/fleet/``, through :class:`~app.core.resources.Relayed`), with its own hub."""
    if len(sse.hub_of(name).streams) >= max_streams:
        raise ApiError(503, "service-unavailable", "Maximum number of SSE clients reached. Please try again later.",
                       {"max_fault_streams": max_streams}, headers={"Retry-After": "5"})
    raw = request.headers.get("Last-Event-ID", "").strip()
    last_id = int(raw) if raw.isdigit() and len(raw) <= 18 else 0
    return sse.response(sse.response_body(name, lambda hub, sock, framed: hub.stream(last_id, sock, framed).body(
        hub.opening, OPEN), request.environ))
