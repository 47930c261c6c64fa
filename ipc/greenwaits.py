"""How the ROS-worker client waits in a gevent-patched process (an HTTP worker).

``ipc/client.py`` uses this module in a process that gevent has patched
(``app/http_worker.py``), where a blocking ``zmq_poll`` would stop every
greenlet of the worker; the greenlet that waits is suspended, the others
run.  Only such a process imports it.  Two waits:

- :class:`LoopWait`: for ZeroMQ sockets (a reply, a disconnection, room to send);
- :func:`semaphore`: for a free channel of a pool (gevent's own semaphore:
  ``threading.BoundedSemaphore`` works when patched, but its ``release`` goes
  once around the event loop each time, through ``Condition.notify``).

libzmq gives each socket a file descriptor (``ZMQ_FD``) that turns readable
when the socket's state may have changed.  It is edge-triggered and says
nothing by itself, so the state is read from ``ZMQ_EVENTS`` before every wait
and after every wake-up; a wait is never longer than ``RECHECK_S`` without
reading it again.  Each socket gets one io watcher, made once and started
only while a greenlet waits on it; the greenlet sleeps on a gevent
``Waiter`` until a watcher or its deadline fires.

This is what ``zmq.green`` does inside a blocking call, without its
per-socket machinery (a Python callback on every event of every socket's
descriptor, an ``AsyncResult`` per wait, ``select`` watchers made per poll).
One request/reply through ``RosWorkerClient.call`` to a process that answers
at once, back to back, 5,000 times, three alternating runs on the 2-vCPU
development VM (median round trip / CPU per call in the caller):

==========================================  ==============  ==============
zmq.green sockets and Poller, patched        178–225 µs      162–187 µs
plain sockets waited on here, patched        128–154 µs       96–99 µs
plain pyzmq, zmq_poll, no gevent (threads)    83–110 µs       47–67 µs
==========================================  ==============  ==============
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import zmq
from gevent import get_hub
from gevent.hub import Waiter
from gevent.lock import BoundedSemaphore

RECHECK_S = 0.5  # the edge-triggered descriptor is trusted, but never for longer than this
_READ = 1        # libev's EV_READ: the descriptor is readable
_EVENTS = int(zmq.EVENTS)


def semaphore(size: int) -> BoundedSemaphore:
    return BoundedSemaphore(size)


class LoopWait:
    """Waits, on the event loop of the thread that made it, for conditions on a fixed set of sockets."""

    __slots__ = ("_loop", "_watchers")

    def __init__(self, *socks: zmq.Socket):
        self._loop = get_hub().loop
        self._watchers = {id(s): self._loop.io(s.getsockopt(zmq.FD), _READ) for s in socks}

    def wait(self, wanted: Sequence[tuple[zmq.Socket, int]], timeout: float) -> list[zmq.Socket]:
        """The sockets of ``wanted`` whose ``ZMQ_EVENTS`` has its flag (``POLLIN``/``POLLOUT`` as ints).

        Waits up to ``timeout`` seconds for at least one; an empty list when none.
        """
        deadline = time.monotonic() + timeout
        watchers = [self._watchers[id(s)] for s, _ in wanted]
        while True:
            ready = [s for s, flag in wanted if s.getsockopt(_EVENTS) & flag]
            if ready:
                return ready
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return []
            self._sleep(watchers, min(remaining, RECHECK_S))

    def _sleep(self, watchers: list, seconds: float) -> None:
        waiter = Waiter()
        timer = self._loop.timer(seconds)
        for watcher in watchers:
            watcher.start(waiter.switch, None)
        timer.start(waiter.switch, None)
        try:
            waiter.get()
        finally:
            for watcher in watchers:
                watcher.stop()
            timer.close()

    def close(self) -> None:
        for watcher in self._watchers.values():
            watcher.close()
        self._watchers = {}
