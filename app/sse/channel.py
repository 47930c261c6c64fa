"""An HTTP worker's side of the events channel (``ipc/events.py``): its SUB sockets, and knowing when a
subscription has taken effect.

A ZeroMQ subscription travels to the ROS worker's XPUB on its own, after the
``setsockopt`` that made it; until it has arrived, what the ROS worker sends
on that key is dropped at the XPUB.  A stream of frames every tick does not
mind (the next tick comes), but a trigger's or a fault's event is sent once:
one that fired in that window was lost (a review reproduced it under load).
So the ROS worker answers each subscription with a one-frame message of the
subscribed key, and a stream of events does not tell its client it is open
before that confirmation came (:meth:`Confirmations.wait`).
"""

from __future__ import annotations

import logging
import time

import gevent
import gevent.event
import zmq.green as zmq

from ipc import events, protocol

log = logging.getLogger("sovd.http.channel")

CONFIRM_WAIT = 3.0     # seconds a stream waits for its subscription's confirmation before it opens anyway
HEARTBEAT_LOST = 3.0   # seconds without a heartbeat before the ROS worker counts as gone
READ_BATCH = 1000      # messages read in one go before the reader yields to the other greenlets


def subscriber(ctx: zmq.Context, *keys: bytes) -> zmq.Socket:
    """A SUB socket for the ROS worker's events channel, subscribed to ``keys`` (prefixes); the caller
    connects it (``events.endpoint``), once it has attached a monitor if it wants one."""
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVHWM, events.HIGH_WATER)
    sock.setsockopt(zmq.RECONNECT_IVL, 100)
    sock.setsockopt(zmq.RECONNECT_IVL_MAX, 1000)
    sock.setsockopt(zmq.MAXMSGSIZE, protocol.MAX_REPLY_FRAME)
    for key in keys:
        sock.setsockopt(zmq.SUBSCRIBE, key)
    return sock


class Confirmations:
    """Which subscriptions of one SUB socket the ROS worker has confirmed (greenlets of one process)."""

    def __init__(self):
        self._keys: dict[bytes, gevent.event.Event] = {}
        self.late = 0  # streams that opened without their confirmation (CONFIRM_WAIT passed)

    def expect(self, key: bytes) -> None:
        """``key`` was just subscribed (call it with the SUBSCRIBE)."""
        self._keys.setdefault(key, gevent.event.Event())

    def forget(self, key: bytes) -> None:
        """``key`` was unsubscribed."""
        self._keys.pop(key, None)

    def seen(self, key: bytes) -> None:
        """A message of ``key`` arrived: the confirmation, or any frame sent after it."""
        confirmed = self._keys.get(key)
        if confirmed is not None:
            confirmed.set()

    def lost(self) -> None:
        """The connection to the ROS worker dropped: every subscription is made again on the next one."""
        for confirmed in self._keys.values():
            confirmed.clear()

    def wait(self, *keys: bytes, timeout: float = CONFIRM_WAIT) -> bool:
        """Until every one of ``keys`` is confirmed (True), or ``timeout`` passed (False, logged)."""
        deadline = time.monotonic() + timeout
        for key in keys:
            confirmed = self._keys.get(key)
            if confirmed is None or confirmed.is_set():
                continue
            if not confirmed.wait(max(0.0, deadline - time.monotonic())):
                self.late += 1
                log.warning("the ROS worker did not confirm the subscription %r within %g s; the stream "
                            "opens anyway, and an event sent before it arrives is lost", key, timeout)
                return False
        return True


class Subscriber:
    """The events channel as one HTTP worker's hub reads it: a SUB socket subscribed to ``KEYS`` (whose
    confirmations a stream may wait for), its connection monitor, the ROS worker's heartbeat, and a
    greenlet that hands every message to :meth:`dispatch` (after noting a confirmation).  A hub adds
    its own greenlets with :meth:`loops`."""

    KEYS: tuple[bytes, ...] = ()
    NAME = "events channel"

    def __init__(self, runtime_dir: str):
        self.runtime_dir = runtime_dir
        self.connected = False
        self.reconnects = 0       # connections to the ROS worker lost so far (a restarted worker)
        self.heartbeat = 0.0
        self.confirmations = Confirmations()
        self._ctx: zmq.Context | None = None
        self._sock = None
        self._monitor = None
        self._greenlets: list[gevent.Greenlet] = []

    def start(self) -> None:
        self._ctx = zmq.Context()
        sock = subscriber(self._ctx, *self.KEYS)
        for key in self.KEYS:
            self.confirmations.expect(key)
        self._monitor = sock.get_monitor_socket(zmq.EVENT_CONNECTED | zmq.EVENT_DISCONNECTED)
        sock.connect(self.endpoint())
        self._sock = sock
        self.heartbeat = time.monotonic()  # a grace period for the first heartbeat
        self._greenlets = [gevent.spawn(self._read), *(gevent.spawn(loop) for loop in self.loops())]

    def endpoint(self) -> str:
        """The XPUB this hub reads: the ROS worker's (the fleet link's for the fleet gateway, app/fleet/)."""
        return events.endpoint(self.runtime_dir)

    def loops(self) -> list:
        return []

    def stop(self) -> None:
        gevent.killall(self._greenlets, timeout=1)
        for s in (self._monitor, self._sock):
            if s is not None:
                s.close(linger=0)
        if self._ctx is not None:
            self._ctx.term()
        self._sock = self._monitor = self._ctx = None

    @property
    def worker_up(self) -> bool:
        return self.connected and time.monotonic() - self.heartbeat <= HEARTBEAT_LOST

    def subscribe(self, key: bytes) -> None:
        self.confirmations.expect(key)
        self._sock.setsockopt(zmq.SUBSCRIBE, key)

    def unsubscribe(self, key: bytes) -> None:
        self.confirmations.forget(key)
        if self._sock is not None:
            self._sock.setsockopt(zmq.UNSUBSCRIBE, key)

    def dispatch(self, frames: list[bytes]) -> None:
        raise NotImplementedError

    def _read(self) -> None:
        poller = zmq.Poller()
        poller.register(self._sock, zmq.POLLIN)
        poller.register(self._monitor, zmq.POLLIN)
        seen = self.confirmations.seen
        while True:
            try:
                ready = dict(poller.poll(1000))
                if self._monitor in ready:
                    self._monitor_event()
                if self._sock in ready:
                    for _ in range(READ_BATCH):
                        try:
                            frames = self._sock.recv_multipart(zmq.NOBLOCK, copy=True)
                        except zmq.Again:
                            break
                        seen(frames[0])
                        self.dispatch(frames)
            except gevent.GreenletExit:
                raise
            except Exception:  # a malformed frame must not end the reader
                log.exception("%s: could not handle a frame", self.NAME)

    def _monitor_event(self) -> None:
        from zmq.utils.monitor import parse_monitor_message

        event = parse_monitor_message(self._monitor.recv_multipart())["event"]
        if event == zmq.EVENT_CONNECTED:
            self.connected = True
        elif event == zmq.EVENT_DISCONNECTED:
            self.connected = False
            self.reconnects += 1
            self.confirmations.lost()
