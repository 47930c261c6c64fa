"""The fleet gateway's events channel: fault events from the link to the HTTP workers.

The same channel as the ROS worker's (``ipc/events.py``), so an HTTP worker reads it with the same
hub (``app/fleet/stream.py``: the faults family's hub on this channel): an XPUB bound on
``ipc://<runtime_dir>/fleetlink-events.sock`` (0600), verbose, that confirms every subscription with
a one-frame message of its key, sends ``f|`` + msgpack ``{id, event_type, fault, timestamp}`` per
fault event and ``h|`` + msgpack ``{pid, t}`` every second.

One thread owns the socket.  Other threads (Zenoh's callbacks) hand it messages with :meth:`send`:
a bounded queue (the oldest dropped first past ``QUEUE_MAX``) and an eventfd that wakes the thread,
so an event leaves within the time it takes to be picked up, not a polling period.
"""

from __future__ import annotations

import collections
import logging
import os
import threading
import time

from ipc import events, protocol
from ipc.fleet import EVENTS_SOCKET_NAME as SOCKET_NAME
from ipc.server import bind_private

log = logging.getLogger("sovd.fleet.channel")

QUEUE_MAX = 10000
HEARTBEAT = 1.0


class EventChannel:
    def __init__(self, zctx, runtime_dir: str):
        self.zctx = zctx
        self.runtime_dir = runtime_dir
        self._queue: collections.deque[list[bytes]] = collections.deque(maxlen=QUEUE_MAX)
        self._wake = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self.sent = 0
        self._thread = threading.Thread(target=self._run, name="fleet-channel", daemon=True)

    def start(self) -> None:
        self._thread.start()
        if not self._ready.wait(5.0) or self._error is not None:
            raise RuntimeError(f"the fleet events channel did not start: {self._error}")

    def stop(self) -> None:
        self._stop.set()
        os.eventfd_write(self._wake, 1)
        self._thread.join(2.0)
        os.close(self._wake)

    def send(self, frames: list[bytes]) -> None:
        """From any thread: queue one message for the HTTP workers."""
        self._queue.append(frames)
        os.eventfd_write(self._wake, 1)

    def _run(self) -> None:
        import zmq

        try:
            pub = self.zctx.socket(zmq.XPUB)
            pub.setsockopt(zmq.LINGER, 0)
            pub.setsockopt(zmq.SNDHWM, events.HIGH_WATER)
            pub.setsockopt(zmq.XPUB_VERBOSE, 1)
            pub.setsockopt(zmq.MAXMSGSIZE, 4096)
            bind_private(pub, self.runtime_dir, SOCKET_NAME)
        except BaseException as exc:
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        poller = zmq.Poller()
        poller.register(pub, zmq.POLLIN)
        poller.register(self._wake, zmq.POLLIN)
        beat = 0.0
        try:
            while not self._stop.is_set():
                ready = dict(poller.poll(int(HEARTBEAT * 1000)))
                if pub in ready:
                    self._confirm(pub)
                if self._wake in ready:
                    try:
                        os.eventfd_read(self._wake)
                    except BlockingIOError:
                        pass
                while self._queue:
                    self._send(pub, self._queue.popleft())
                now = time.monotonic()
                if now - beat >= HEARTBEAT:
                    beat = now
                    self._send(pub, [events.HEARTBEAT_KEY, protocol.pack({"pid": os.getpid(), "t": time.time()})])
        finally:
            pub.close(linger=0)
            try:
                os.unlink(os.path.join(self.runtime_dir, SOCKET_NAME))
            except OSError:
                pass

    def _confirm(self, pub) -> None:
        import zmq

        while True:
            try:
                message = pub.recv(zmq.NOBLOCK)
            except zmq.Again:
                return
            if message[:1] == b"\x01" and len(message) > 1:
                self._send(pub, [message[1:]])   # the subscribed key itself: the confirmation

    def _send(self, pub, frames: list[bytes]) -> None:
        import zmq

        try:
            pub.send_multipart(frames, zmq.NOBLOCK)
            self.sent += 1
        except zmq.ZMQError as exc:
            log.debug("fleet: an event was not sent: %s", exc)
