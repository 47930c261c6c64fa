"""The fork-safe client of the ROS worker, used by HTTP workers, the supervisor and the probe.

Before fork / after fork: constructing a :class:`RosWorkerClient` touches no
ZeroMQ state.  The context and the channel pools are made lazily in the
process that first calls :meth:`~RosWorkerClient.call` (``common/process.py``'s
:class:`~common.process.PerProcess`); a forked child makes its own and never
touches the parent's.

Channels.  A channel is one DEALER socket connected to an endpoint, a monitor
of that connection's disconnections, and how to wait for both.  A call borrows
a channel from its endpoint's pool for the duration of one request and its
reply, then gives it back.  A pool holds at most ``pool_size`` channels, made
on demand and reused most recently returned first, so a process with many
concurrent callers (an HTTP worker holds up to ``worker_connections``
greenlets) holds a bounded number of sockets, and a caller beyond them waits
for a free channel within its own deadline.  Pools are kept per endpoint.

Green or plain.  The sockets are plain pyzmq everywhere; what differs is how
a call waits for them.  In a process that gevent has patched (an HTTP
worker; see ``app/http_worker.py``) a call waits on the event loop
(``ipc/greenwaits.py``) for its socket and for a free channel, so it
suspends only its own greenlet.  Everywhere else (the supervisor, the probe,
the tests) it waits in ``zmq_poll`` and the pool is shared by threads.  This
module does not import gevent: it asks whether the process was patched.
(``zmq.green`` does the same job; ``ipc/greenwaits.py`` says why it is not
used.)

Every call has a deadline.  DEALER sockets do not get stuck after a timeout
the way REQ sockets do; a late reply is recognised by its id and dropped by
whichever call uses the channel next.  A connection that drops while a call
waits (the ROS worker died with the request) ends the call at once.

Never reached, or answer lost.  A request that could not be sent (no ROS
worker connected) is ``unavailable``: nothing happened, a retry is safe.  One
that was sent, when the connection then drops, may have been carried out:
for a write (:data:`ipc.protocol.WRITES`: a service call, a goal, a cancel, a
parameter set or reset, a publish, a fault clear ...) that is
``outcome-unknown`` (HTTP 504, no Retry-After); a read is ``unavailable``.
"""

from __future__ import annotations

import contextlib
import itertools
import sys
import threading
import time
from typing import Any

import zmq

from common.process import PerProcess

from . import protocol
from .errors import IpcError

# How long a send waits for the connection to the ROS worker's socket to exist.
CONNECT_WAIT = 0.25
# Channels (DEALER sockets) per endpoint and process.  Requests of one HTTP worker that are in
# flight at the same moment are bounded by it; the ROS worker answers them one at a time anyway,
# and a cold read that waits holds its channel (at most ``cold_wait_cap`` such reads).
POOL_SIZE = 32
_EVENTS, _POLLIN, _POLLOUT = int(zmq.EVENTS), int(zmq.POLLIN), int(zmq.POLLOUT)  # plain ints: no enum cost


class _MalformedReply(IpcError):
    """``internal``: a reply that is not a msgpack map; its channel is closed, not reused."""


def green() -> bool:
    """True in a process whose sockets gevent has patched (an HTTP worker)."""
    monkey = sys.modules.get("gevent.monkey")
    return monkey is not None and monkey.is_module_patched("socket")


class _PollWait:
    """Waits in ``zmq_poll`` (a process without gevent): the :class:`~ipc.greenwaits.LoopWait` API."""

    __slots__ = ("_pollers",)

    def __init__(self):
        self._pollers: dict[tuple, zmq.Poller] = {}

    def wait(self, wanted, timeout: float) -> list[zmq.Socket]:
        poller = self._pollers.get(wanted)
        if poller is None:
            poller = self._pollers[wanted] = zmq.Poller()
            for sock, flag in wanted:
                poller.register(sock, flag)
        return [sock for sock, _ in poller.poll(max(0, int(timeout * 1000)))]

    def close(self) -> None:
        pass


class _Channel:
    """One DEALER socket, a monitor of its disconnections, and how to wait for them."""

    __slots__ = ("sock", "mon", "waits", "replies")

    def __init__(self, ctx: zmq.Context, endpoint: str, green_waits: bool):
        sock = ctx.socket(zmq.DEALER)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.IMMEDIATE, 1)       # no queueing while the worker is down
        sock.setsockopt(zmq.SNDHWM, 64)
        sock.setsockopt(zmq.RCVHWM, 256)
        sock.setsockopt(zmq.MAXMSGSIZE, protocol.MAX_REPLY_FRAME)
        sock.setsockopt(zmq.RECONNECT_IVL, 50)
        sock.setsockopt(zmq.RECONNECT_IVL_MAX, 500)
        self.mon = sock.get_monitor_socket(zmq.EVENT_DISCONNECTED)
        sock.connect(endpoint)
        self.sock = sock
        self.replies = ((sock, _POLLIN), (self.mon, _POLLIN))  # a reply, or a disconnection
        if green_waits:
            from .greenwaits import LoopWait

            self.waits = LoopWait(sock, self.mon)
        else:
            self.waits = _PollWait()

    def forget_disconnects(self) -> None:
        """Drop disconnection events of earlier connections (a restarted worker)."""
        while self.mon.getsockopt(_EVENTS) & _POLLIN:
            self.mon.recv_multipart(zmq.NOBLOCK)

    def close(self) -> None:
        self.waits.close()
        self.mon.close(linger=0)
        self.sock.close(linger=0)


class _ChannelPool:
    """At most ``size`` channels to one endpoint; each is used by one caller at a time.

    With greenlets (one thread) the idle list needs no lock: nothing between
    looking at it and changing it can switch to another greenlet.
    """

    def __init__(self, ctx: zmq.Context, endpoint: str, size: int, green_waits: bool):
        self._ctx, self.endpoint, self._green = ctx, endpoint, green_waits
        if green_waits:
            from .greenwaits import semaphore

            self._slots = semaphore(size)
            self._lock = contextlib.nullcontext()
        else:
            self._slots = threading.BoundedSemaphore(size)
            self._lock = threading.Lock()
        self._idle: list[_Channel] = []
        self._open: list[_Channel] = []

    def acquire(self, timeout: float) -> _Channel | None:
        """A free channel, made if none is idle; None when all stay busy for ``timeout`` s."""
        if not self._slots.acquire(timeout=max(0.0, timeout)):
            return None
        try:
            with self._lock:
                if self._idle:
                    return self._idle.pop()
            channel = _Channel(self._ctx, self.endpoint, self._green)
            with self._lock:
                self._open.append(channel)
            return channel
        except BaseException:
            self._slots.release()
            raise

    def release(self, channel: _Channel, broken: bool = False) -> None:
        with self._lock:
            if broken:
                self._open.remove(channel)
            else:
                self._idle.append(channel)
        if broken:
            channel.close()
        self._slots.release()

    @property
    def open_count(self) -> int:
        return len(self._open)

    def close(self) -> None:
        with self._lock:
            channels, self._open, self._idle = self._open, [], []
        for channel in channels:
            channel.close()


class _Transport:
    """One process's ZeroMQ context and channel pools (made on first use, see the module docstring)."""

    def __init__(self) -> None:
        self.green = green()
        self.ctx = zmq.Context()
        self.pools: dict[str, _ChannelPool] = {}

    def close(self) -> None:
        pools, self.pools = self.pools, {}
        for pool in pools.values():
            pool.close()
        self.ctx.term()


class RosWorkerClient:
    def __init__(self, endpoint: str, pool_size: int = POOL_SIZE):
        self.endpoint = endpoint
        self.control_endpoint = protocol.control_endpoint(endpoint)
        self.pool_size = pool_size
        self._transport: PerProcess[_Transport] = PerProcess(_Transport, _Transport.close)
        self._lock = threading.Lock()
        self._ids = itertools.count(1)

    @classmethod
    def for_runtime_dir(cls, runtime_dir: str) -> RosWorkerClient:
        return cls(protocol.endpoint(runtime_dir))

    @property
    def channel_count(self) -> int:
        """Channels (DEALER sockets) this process holds open, over every endpoint."""
        return sum(pool.open_count for pool in list(self._pools.values()))

    @property
    def _pools(self) -> dict[str, _ChannelPool]:
        """This process's channel pools by endpoint (none before its first call)."""
        transport = self._transport.peek()
        return {} if transport is None else transport.pools

    def _endpoint_for(self, cmd: str) -> str:
        """``ping`` and ``stats`` go to the worker's control socket, every other command to its work socket."""
        return self.control_endpoint if cmd in protocol.IMMEDIATE else self.endpoint

    def _pool(self, endpoint: str) -> _ChannelPool:
        transport = self._transport.get()
        pool = transport.pools.get(endpoint)
        if pool is None:
            with self._lock:
                pool = transport.pools.get(endpoint)
                if pool is None:
                    pool = transport.pools[endpoint] = _ChannelPool(transport.ctx, endpoint, self.pool_size,
                                                                    transport.green)
        return pool

    def call(self, cmd: str, args: dict[str, Any] | None = None, timeout: float = 2.0,
             connect_wait: float = CONNECT_WAIT, request_id: str | None = None) -> dict[str, Any]:
        """Send one command and wait up to ``timeout`` seconds for its reply.

        ``request_id`` (the HTTP request's ``X-Request-Id``, already valid) goes
        into the envelope; the ROS worker tags that command's log lines with it.

        Returns the ``result`` map; raises :class:`IpcError` with code
        ``unavailable`` (no ROS worker connected, or it went away while we
        waited for a read), ``outcome-unknown`` (it went away while we waited
        for a write it was sent), ``deadline-exceeded`` (no answer in time, or
        no free channel in time) or whatever the ROS worker answered.
        """
        deadline = time.monotonic() + timeout
        pool = self._pool(self._endpoint_for(cmd))
        channel = pool.acquire(timeout)
        if channel is None:
            raise IpcError("deadline-exceeded",
                           f"No free channel to the ROS worker for {cmd!r} within {timeout:g} s "
                           f"({self.pool_size} requests of this process are in flight)",
                           {"command": cmd, "timeout_s": timeout})
        broken = True  # unless the exchange ends as the protocol says: anything else closes the channel
        try:
            result = self._exchange(channel, cmd, args, timeout, deadline, connect_wait, request_id)
            broken = False
            return result
        except _MalformedReply:
            raise  # start again on a new socket
        except IpcError:
            broken = False
            raise
        finally:
            pool.release(channel, broken)

    def _exchange(self, channel: _Channel, cmd: str, args: dict[str, Any] | None, timeout: float,
                  deadline: float, connect_wait: float, request_id: str | None) -> dict[str, Any]:
        sock = channel.sock
        channel.forget_disconnects()
        rid = next(self._ids)
        envelope = {"v": protocol.VERSION, "id": rid, "cmd": cmd, "args": args or {},
                    "deadline_ms": max(1, int(timeout * 1000))}
        if request_id is not None:
            envelope["request_id"] = request_id
        frame = protocol.pack(envelope)
        try:
            sock.send(frame, zmq.NOBLOCK)
        except zmq.Again:
            wait = min(connect_wait, max(0.0, deadline - time.monotonic()))
            if not channel.waits.wait(((sock, _POLLOUT),), wait):
                raise IpcError("unavailable", "The ROS worker is not running; retry shortly") from None
            try:
                sock.send(frame, zmq.NOBLOCK)
            except zmq.Again:
                raise IpcError("unavailable", "The ROS worker is not running; retry shortly") from None
        while True:
            remaining = deadline - time.monotonic()
            ready = channel.waits.wait(channel.replies, remaining) if remaining > 0 else ()
            if not ready:
                raise IpcError(
                    "deadline-exceeded",
                    f"The ROS worker did not answer {cmd!r} within {timeout:g} s",
                    {"command": cmd, "timeout_s": timeout},
                )
            if sock not in ready:
                # The connection dropped while we waited: the worker died with our request.
                channel.forget_disconnects()
                if cmd in protocol.WRITES:
                    raise IpcError("outcome-unknown", f"The ROS worker went away while handling {cmd!r}: it may "
                                   "or may not have been carried out; check before you retry", {"command": cmd})
                raise IpcError("unavailable", f"The ROS worker went away while handling {cmd!r}; "
                                              "retry shortly", {"command": cmd})
            try:
                # Not copied out of libzmq's message: unpacking copies what it keeps (a sample's
                # JSON), and a large sample (an image) is then one transient buffer, not two.
                reply = protocol.unpack(sock.recv(zmq.NOBLOCK, copy=False).buffer, protocol.MAX_REPLY_FRAME)
            except zmq.Again:
                continue
            except ValueError:
                raise _MalformedReply("internal", "Malformed reply from the ROS worker") from None
            if reply.get("id") != rid:
                continue  # a late reply to an earlier, timed-out call
            if reply.get("ok") is True:
                result = reply.get("result")
                return result if isinstance(result, dict) else {}
            raise IpcError.from_wire(reply.get("error"))

    def close(self) -> None:
        """Close every channel and the context (call when no thread uses the client).

        A context whose sockets are all closed terminates at once; left to the
        garbage collector with a socket still open, ``term`` would block.
        """
        self._transport.reset()  # never a context inherited across fork(): the child forgot it

