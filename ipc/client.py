"""The fork-safe client of the ROS worker, used by HTTP workers, the supervisor and the probe.

Before fork / after fork: constructing a :class:`RosWorkerClient` touches no
ZeroMQ state.  The context is made lazily in the process that first calls
:meth:`call`, and each thread gets its own DEALER socket.  A process that
finds a context made by another pid (it was forked) makes a new one.

Every call has a deadline.  DEALER sockets do not get stuck after a timeout
the way REQ sockets do; a late reply is recognised by its id and dropped.
"""

from __future__ import annotations

import itertools
import os
import threading
import time
from typing import Any

import zmq

from . import protocol
from .errors import IpcError

# How long a send waits for the connection to the ROS worker's socket to exist.
CONNECT_WAIT = 0.25


class _Channel:
    """One thread's DEALER socket, a monitor of its disconnections, and a poller over both."""

    __slots__ = ("sock", "mon", "poller")

    def __init__(self, ctx: zmq.Context, endpoint: str):
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
        self.poller = zmq.Poller()
        self.poller.register(sock, zmq.POLLIN)
        self.poller.register(self.mon, zmq.POLLIN)

    def forget_disconnects(self) -> None:
        """Drop disconnection events of earlier connections (a restarted worker)."""
        while self.mon.getsockopt(zmq.EVENTS) & zmq.POLLIN:
            self.mon.recv_multipart(zmq.NOBLOCK)

    def close(self) -> None:
        self.mon.close(linger=0)
        self.sock.close(linger=0)


class RosWorkerClient:
    """``ping`` and ``stats`` go to the worker's control socket, every other command to its work socket."""

    def __init__(self, endpoint: str):
        self.endpoint = endpoint
        self.control_endpoint = protocol.control_endpoint(endpoint)
        self._pid: int | None = None
        self._ctx: zmq.Context | None = None
        self._local = threading.local()
        self._lock = threading.Lock()
        self._ids = itertools.count(1)
        self._sockets: list[zmq.Socket] = []  # every thread's socket, so close() can close them all

    @classmethod
    def for_runtime_dir(cls, runtime_dir: str) -> RosWorkerClient:
        return cls(protocol.endpoint(runtime_dir))

    def _channel(self, control: bool = False) -> _Channel:
        pid = os.getpid()
        if self._pid != pid:
            with self._lock:
                if self._pid != pid:
                    # Forked (or first use): never touch the parent's context.
                    self._ctx = zmq.Context()
                    self._local = threading.local()
                    self._sockets = []
                    self._pid = pid
        slot = "control" if control else "channel"
        channel = getattr(self._local, slot, None)
        if channel is None:
            channel = _Channel(self._ctx, self.control_endpoint if control else self.endpoint)
            setattr(self._local, slot, channel)
            with self._lock:
                self._sockets = [s for s in self._sockets if not s.closed] + [channel.sock, channel.mon]
        return channel

    def _reset_channel(self, control: bool = False) -> None:
        slot = "control" if control else "channel"
        channel = getattr(self._local, slot, None)
        if channel is not None:
            channel.close()
            setattr(self._local, slot, None)

    def call(self, cmd: str, args: dict[str, Any] | None = None, timeout: float = 2.0,
             connect_wait: float = CONNECT_WAIT) -> dict[str, Any]:
        """Send one command and wait up to ``timeout`` seconds for its reply.

        Returns the ``result`` map; raises :class:`IpcError` with code
        ``unavailable`` (no ROS worker connected, or it went away while we
        waited), ``deadline-exceeded`` (no answer in time) or whatever the ROS
        worker answered.
        """
        deadline = time.monotonic() + timeout
        control = cmd in protocol.IMMEDIATE
        channel = self._channel(control)
        sock = channel.sock
        channel.forget_disconnects()
        rid = next(self._ids)
        frame = protocol.pack({
            "v": protocol.VERSION, "id": rid, "cmd": cmd, "args": args or {},
            "deadline_ms": max(1, int(timeout * 1000)),
        })
        try:
            sock.send(frame, zmq.NOBLOCK)
        except zmq.Again:
            wait = min(connect_wait, max(0.0, deadline - time.monotonic()))
            if not sock.poll(int(wait * 1000), zmq.POLLOUT):
                raise IpcError("unavailable", "The ROS worker is not running; retry shortly") from None
            try:
                sock.send(frame, zmq.NOBLOCK)
            except zmq.Again:
                raise IpcError("unavailable", "The ROS worker is not running; retry shortly") from None
        while True:
            remaining = deadline - time.monotonic()
            events = channel.poller.poll(max(1, int(remaining * 1000))) if remaining > 0 else ()
            if not events:
                raise IpcError(
                    "deadline-exceeded",
                    f"The ROS worker did not answer {cmd!r} within {timeout:g} s",
                    {"command": cmd, "timeout_s": timeout},
                )
            if not any(s is sock for s, _ in events):
                # The connection dropped while we waited: the worker died with our request.
                channel.forget_disconnects()
                raise IpcError("unavailable", f"The ROS worker went away while handling {cmd!r}; "
                                              "retry shortly", {"command": cmd})
            try:
                reply = protocol.unpack(sock.recv(zmq.NOBLOCK), protocol.MAX_REPLY_FRAME)
            except zmq.Again:
                continue
            except ValueError:
                self._reset_channel(control)
                raise IpcError("internal", "Malformed reply from the ROS worker") from None
            if reply.get("id") != rid:
                continue  # a late reply to an earlier, timed-out call
            if reply.get("ok") is True:
                result = reply.get("result")
                return result if isinstance(result, dict) else {}
            raise IpcError.from_wire(reply.get("error"))

    def close(self) -> None:
        """Close every thread's socket and the context (call when no thread uses the client).

        A context whose sockets are all closed terminates at once; left to the
        garbage collector with a socket still open, ``term`` would block.
        """
        with self._lock:
            sockets, self._sockets = self._sockets, []
            ctx, owner = self._ctx, self._pid
            self._ctx, self._pid = None, None
            self._local = threading.local()
        if ctx is None or owner != os.getpid():
            return  # never touch a context inherited across fork()
        for sock in sockets:
            sock.close(linger=0)
        ctx.term()
