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

import gevent.event
import zmq.green as zmq

from ipc import events, protocol

log = logging.getLogger("sovd.http.channel")

CONFIRM_WAIT = 3.0  # seconds a stream waits for its subscription's confirmation before it opens anyway


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
