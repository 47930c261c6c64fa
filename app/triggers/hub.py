"""The HTTP worker's side of triggers: their event streams (``.../triggers/{id}/events``).

One :class:`TriggerHub` per HTTP worker process (``app/sse/hub.py``), subscribed
to the triggers' control frames, to the heartbeat, and to the group key
(``events.trigger_group_key``: a source, a target, a bytes mode) of each trigger
its open streams watch.  The ROS worker sends a change once per group key
however many of its triggers fired on it, with their ids and sequence numbers
(``ipc/PROTOCOL.md``): a process receives it once, builds its SSE frame once
(and its HTTP chunk once), and pushes that one buffer into the streams of each
trigger that fired.  A process receives nothing of a group none of its streams
watches; a change of a group it watches that fired none of its triggers costs
it a look-up per trigger that fired.

A trigger's events come only when it fires.  Each stream (``app/sse/stream.py``)
holds at most ``EVENT_BUFFER`` events and ``STREAM_BUFFER_BYTES``: past them the
oldest go first (the newest event wins), each counted in ``frames_dropped``.

A stream opens once the ROS worker has confirmed its subscription
(``app/sse/channel.py``: an event sent before would be lost while the client
already counts on it); its first frame may be an event that fired before it
opened (``trig_open`` hands the newest one no stream was opened for: a one-shot
trigger may fire before its client has connected); events carry a sequence
number, so one is never sent twice.  It ends at once when its trigger is deleted
or expires (a control frame), after a one-shot trigger's event, and when the HTTP
worker stops.  While the ROS worker is gone a stream gets one ``error`` frame and
stays open; a silent stream's trigger is looked up every ``VERIFY_EVERY``
seconds, so a trigger lost with a control frame (a ROS worker killed) does not
leave the stream open for ever.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from typing import Any

import gevent
import orjson
from flask import Flask

from ipc import events, protocol
from ipc.errors import IpcError

from ..core import rosclient
from ..sse import hub as sse
from ..sse.hub import Hub
from ..sse.stream import Stream, chunked, frame

log = logging.getLogger("sovd.http.triggers")

NAME = "triggers"
# Events a stream holds for a slow client (and STREAM_BUFFER_BYTES): a trigger's events are discrete
# (a burst of changes is several events, each worth sending), so more than a cyclic stream's frames.
EVENT_BUFFER = 64
VERIFY_EVERY = 10.0   # seconds between two look-ups of a silent stream's trigger
LOOKUP_TIMEOUT = 1.0
DOWN = "The ROS worker is not running; events resume when it is back"
STOPPING = "The gateway is shutting down; this stream ends"


def error_frame(stamp: int, message: str) -> bytes:
    return frame(stamp, error=orjson.dumps(message))


class TriggerHub(Hub):
    KEYS = (events.TRIGGER_CONTROL_PREFIX, events.HEARTBEAT_KEY)
    NAME = "events channel (triggers)"

    def __init__(self, runtime_dir: str, lookup: Callable[[Stream, bool], dict[str, Any]],
                 stopping: Callable[[], bool] = lambda: False, send_timeout: float = 30.0):
        super().__init__(runtime_dir, send_timeout, stopping)
        self._lookup = lookup           # (stream, open) -> trig_get / trig_open answer (IpcError)
        # by_id: trigger id -> its open streams; by_key: group key -> the open streams of its triggers

    # ---- streams --------------------------------------------------------------------------------
    def stream(self, trigger: dict[str, Any], sock: Any = None, framed: bool = False) -> Stream:
        stream = Stream(self, EVENT_BUFFER, sock, framed)
        stream.id, stream.collection, stream.entity_id = trigger["id"], trigger["collection"], trigger["entity_id"]
        stream.key = events.trigger_group_key(trigger["source"], trigger["bytes"], trigger["target"])
        stream.next_check = time.monotonic() + VERIFY_EVERY
        stream.told_down = False
        return stream

    def added(self, stream: Stream) -> None:
        self.index(stream)

    def removed(self, stream: Stream) -> None:
        self.unindex(stream)

    def opening(self, stream: Stream) -> None:
        """Before the response head: the subscription confirmed, then what fired before it opened."""
        # Events from now on reach this stream (held meanwhile), once the ROS worker has the
        # subscription (app/sse/channel.py): before that, an event would be lost at its end.
        stream.hold()
        self.confirmations.wait(stream.key, events.TRIGGER_CONTROL_PREFIX)
        try:
            trigger = self._lookup(stream, True)
        except IpcError as exc:
            if exc.code == "no-such-trigger":
                stream.ended = True
            trigger = {}
        replay = trigger.get("replay")
        if isinstance(replay, dict):
            event(stream, replay, replay.get("payload") or b"")
        if trigger and trigger.get("status") != "active":
            stream.end()
        stream.release()

    def last(self, stream: Stream) -> bytes | None:
        return error_frame(time.time_ns(), STOPPING)

    # ---- the reader ----------------------------------------------------------------------------------
    def dispatch(self, frames: list[bytes]) -> None:
        key = frames[0]
        if key == events.HEARTBEAT_KEY:
            self.heartbeat = time.monotonic()
            return
        if len(frames) < 2:
            return
        if key.startswith(events.TRIGGER_GROUP_PREFIX):
            self._fired(protocol.unpack(frames[1], protocol.MAX_REPLY_FRAME), frames[2] if len(frames) > 2 else b"")
        elif key.startswith(events.TRIGGER_CONTROL_PREFIX):
            streams = self.by_id.get(key[4:-1].decode(errors="replace"))
            if streams and protocol.unpack(frames[1]).get("event") in ("deleted", "expired"):
                for stream in list(streams):
                    stream.end()

    def _fired(self, meta: dict[str, Any], payload: bytes) -> None:
        """One change, and the triggers it fired: its frame made once, pushed into each one's streams."""
        fired = meta.get("fired") if isinstance(meta, dict) else None
        if not isinstance(fired, list):
            return
        made: list[bytes] = []   # the frame, then the frame as an HTTP chunk (each made when first needed)
        for entry in fired:
            if not isinstance(entry, list) or len(entry) != 3:
                continue
            trigger_id, seq, last = entry
            streams = self.by_id.get(trigger_id) if isinstance(trigger_id, str) else None
            if not streams:
                continue
            if not made:
                made.append(event_frame(meta, payload))
            for stream in list(streams):
                if stream.framed and len(made) == 1:
                    made.append(chunked(made[0]))
                stream.push(made[0], made[1] if stream.framed else None, seq=seq if isinstance(seq, int) else None)
                if last:
                    stream.end()

    # ---- the ticker ----------------------------------------------------------------------------------
    def tick(self, now: float) -> None:
        up = self.worker_up
        for stream in list(self.streams):
            if not up and not stream.told_down:
                stream.told_down = True
                stream.push(error_frame(time.time_ns(), DOWN))
            elif up:
                stream.told_down = False
                if now >= stream.next_check and now - stream.last_frame >= VERIFY_EVERY:
                    stream.next_check = now + VERIFY_EVERY
                    gevent.spawn(self._verify, stream)

    def _verify(self, stream: Stream) -> None:
        try:
            trigger = self._lookup(stream, False)
        except IpcError as exc:
            if exc.code == "no-such-trigger":
                stream.end()
            return
        if trigger.get("status") != "active":
            stream.end()


def event_frame(meta: dict[str, Any], payload: bytes) -> bytes:
    """The SSE frame of one trigger event (``meta``: its ``ts`` and ``error``?), the same for every trigger
    the change fired: neither the trigger nor its ``seq`` is in it."""
    stamp = meta["ts"] if isinstance(meta.get("ts"), int) else time.time_ns()
    if isinstance(meta.get("error"), str):
        return error_frame(stamp, meta["error"])
    return frame(stamp, payload=payload or b"{}")


def event(stream: Stream, meta: dict[str, Any], payload: bytes) -> None:
    """One trigger event into ``stream`` (a replay: sent once, by its ``seq``); a one-shot's (``last``) ends it."""
    seq = meta.get("seq") if isinstance(meta.get("seq"), int) else None
    stream.push(event_frame(meta, payload), seq=seq)
    if meta.get("last"):
        stream.end()


# ---- this app's hub ---------------------------------------------------------------------------------------
def setup(app: Flask) -> None:
    cfg = app.config["SOVD"]
    ros = app.extensions[rosclient.EXTENSION]

    def make(_app: Flask) -> TriggerHub:
        def lookup(stream: Stream, opening: bool) -> dict[str, Any]:
            return ros.call("trig_open" if opening else "trig_get",
                            {"collection": stream.collection, "entity_id": stream.entity_id, "id": stream.id},
                            timeout=LOOKUP_TIMEOUT)

        return TriggerHub(cfg.runtime_dir, lookup, sse.worker_stopping, cfg.stream_send_timeout)

    sse.register(app, NAME, make)


def body(trigger: dict[str, Any], environ: dict[str, Any]) -> Iterator[bytes]:
    """The body of one ``.../triggers/{id}/events`` response (nothing happens until it is iterated)."""
    return sse.response_body(NAME, lambda hub, sock, framed: hub.stream(trigger, sock, framed).body(hub.opening),
                             environ)
