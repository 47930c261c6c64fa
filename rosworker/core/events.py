"""The events channel, the ROS worker's side: one PUB socket to every HTTP worker, owned by no family.

A ZeroMQ XPUB bound beside the command ROUTER (``ipc/events.py`` has the keys,
``ipc/PROTOCOL.md`` the wire): the cyclic subscriptions' frames and control
events, the fault events, the trigger events all go out here, from the ROS
thread, never blocking (a subscriber past its high-water mark misses a frame;
nothing waits for it).

Besides what the families send, the channel itself sends a heartbeat every
``HEARTBEAT_EVERY`` s (HTTP workers tell a ROS worker that is gone by it), a
``c|shutdown`` control frame when it closes, and answers each subscription an
HTTP worker makes with a one-frame message of its prefix (the XPUB is
verbose): the XPUB applied the subscription before it handed it over, so
whoever receives that confirmation receives everything of the prefix sent
after it (``app/sse/channel.py`` opens an event stream only then).
"""

from __future__ import annotations

import os
import time
from typing import Any

import zmq

from ipc import events, protocol
from ipc.server import bind_publisher, send_frames

from .executor import RosExecutor
from .stats import Stats

HEARTBEAT_EVERY = 1.0
CONFIRM_BATCH = 1000  # subscription messages confirmed per round of the loop at most


class EventsChannel:
    def __init__(self, zctx: zmq.Context, runtime_dir: str, executor: RosExecutor, stats: Stats):
        self.zctx = zctx
        self.runtime_dir = runtime_dir
        self.executor = executor
        self.stats = stats
        self._pub: zmq.Socket | None = None

    def bind(self) -> None:
        """Bind the socket and start the heartbeat (ROS thread, before the loop)."""
        self._pub = bind_publisher(self.zctx, self.runtime_dir)
        self.executor.add_reader("the events channel's subscriptions", self._pub, self._confirm)
        self.executor.call_later(0, self._heartbeat)

    def send(self, frames: list[bytes]) -> None:
        """Publish ``frames`` (a key, then its parts; ROS thread; never blocks; dropped when closed)."""
        if self._pub is None:
            return
        try:
            send_frames(self._pub, frames)
        except zmq.ZMQError:
            pass  # PUB never blocks: a subscriber past its high-water mark misses this frame

    def publish(self, key: bytes, meta: dict[str, Any], data: bytes = b"{}") -> None:
        """One stream frame: ``key``, msgpack ``meta``, ``data`` (counted in ``frames_published``)."""
        self.send([key, protocol.pack(meta), data])
        self.stats.frames_published += 1

    def close(self) -> None:
        if self._pub is not None:
            self.send([events.CONTROL_KEY + b"shutdown", protocol.pack({"event": "shutdown"})])
            self.executor.remove_reader(self._pub)
            self._pub.close(linger=200)
            self._pub = None

    def _heartbeat(self) -> None:
        self.executor.call_later(HEARTBEAT_EVERY, self._heartbeat)
        self.send([events.HEARTBEAT_KEY, protocol.pack({"pid": os.getpid(), "t": time.time_ns()})])

    def _confirm(self) -> None:
        """Each subscription an HTTP worker made is answered with a one-frame message of its prefix
        (``ipc/events.py``), so that message, and every frame of the prefix after it, reaches it."""
        for _ in range(CONFIRM_BATCH):
            try:
                message = self._pub.recv(zmq.NOBLOCK)
            except zmq.Again:
                return
            if len(message) > 1 and message[0] == 1:
                self.stats.subscriptions_confirmed += 1
                self.send([message[1:]])
