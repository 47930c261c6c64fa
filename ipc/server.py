"""The ROS worker's side of the wire: the runtime lock, binding, request decoding, the control thread.

The ROS worker serves two ROUTER sockets in its runtime directory:

- ``rosworker.sock`` (work): served by the ROS thread itself
  (``rosworker/core/executor.py``), which reads, queues, runs and answers every
  command there;
- ``rosworker-ctl.sock`` (control): served by :class:`ControlServer`, a thread
  that never touches rclpy.  It answers ``ping`` and ``stats`` from counters,
  at once, whatever the ROS thread is doing, and checks the watchdog every
  ``WATCHDOG_CHECK`` seconds.  So ``/health`` and the supervisor's health
  check never wait behind ROS work.  Nothing but :meth:`ControlServer.finish`
  ends that thread: an exception while answering answers that request
  ``internal``, and one anywhere else in its loop is logged and the loop goes
  on (at most one traceback per ``ERROR_LOG_EVERY``).  A dead control thread
  would leave a healthy worker silent, and the supervisor would kill it.

Both sockets decode requests with :func:`read_requests`: frames that are not
requests are dropped (counted in ``ipc_dropped_frames``), malformed requests
that carry an id get an error reply.  Before anything is bound, the worker
holds an exclusive ``flock`` on ``<runtime_dir>/rosworker.lock``
(:class:`RuntimeLock`), so a second worker on the same directory cannot steal
the sockets.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zmq

from common.process import PidfileHeld, lock_pidfile

from . import events, protocol
from .errors import IpcError

log = logging.getLogger("sovd.rosworker.ipc")

WATCHDOG_CHECK = 0.05      # seconds between looks at the ROS thread's current task
READ_BATCH = 1000          # requests read in one go before the reader returns
ERROR_LOG_EVERY = 10.0     # seconds: one traceback per period from the control thread, the rest counted


class LockHeld(RuntimeError):
    """Another ROS worker owns this runtime directory."""


class RuntimeLock:
    def __init__(self, runtime_dir: str):
        self.path = os.path.join(runtime_dir, protocol.LOCK_NAME)
        self._fh = None

    def acquire(self, wait: float = 0.0, poll: float = 0.05,
                waiting: Callable[[LockHeld], None] | None = None) -> float:
        """Take the lock, waiting up to ``wait`` s for its holder to go (``waiting(exc)`` once when it
        starts to wait); the seconds waited, or :class:`LockHeld` (saying how long) past ``wait``."""
        started = time.monotonic()
        told = False
        while True:
            try:
                self._fh = lock_pidfile(self.path)
                return time.monotonic() - started
            except PidfileHeld as held:
                exc = LockHeld(f"another ROS worker (pid {held.holder or 'another process'}) already serves "
                               f"{os.path.dirname(self.path)}; refusing to take its socket")
            waited = time.monotonic() - started
            if waited >= wait:
                raise LockHeld(f"{exc} (waited {waited:.1f} s)" if wait else str(exc))
            if waiting is not None and not told:
                told = True
                waiting(exc)
            time.sleep(min(poll, wait - waited))

    def release(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


_MORE = int(zmq.SNDMORE | zmq.NOBLOCK)  # plain ints: pyzmq's flag enums cost more than the send itself
_LAST = int(zmq.NOBLOCK)
ZERO_COPY_FROM = 64 * 1024  # a part this large is handed to ZeroMQ without a copy; a smaller one is copied


def send_frames(sock: zmq.Socket, frames: list[bytes]) -> None:
    """``sock.send_multipart(frames, zmq.NOBLOCK)`` at a third of its cost (about 3 µs against 10 for a
    small three-part frame, measured here): one ``send`` per part with int flags, and a copy of each
    small part, which is cheaper than pyzmq's zero-copy bookkeeping.  Raises ``zmq.ZMQError`` as that
    does; the ROUTER and XPUB it serves drop rather than refuse a frame, so none is sent in part."""
    send = sock.send
    last = len(frames) - 1
    for i, part in enumerate(frames):
        send(part, _MORE if i < last else _LAST, copy=len(part) < ZERO_COPY_FROM)


def bind_router(zctx: zmq.Context, runtime_dir: str, name: str) -> zmq.Socket:
    """A ROUTER bound to ``ipc://<runtime_dir>/<name>``, private to the service user (0600)."""
    router = zctx.socket(zmq.ROUTER)
    router.setsockopt(zmq.LINGER, 500)
    router.setsockopt(zmq.MAXMSGSIZE, protocol.MAX_FRAME)
    # Per peer: a client has one request in flight per socket, so 1000 is far above
    # need, and it bounds what a hostile peer makes the worker buffer.
    router.setsockopt(zmq.RCVHWM, 1000)
    router.setsockopt(zmq.SNDHWM, 1000)
    return bind_private(router, runtime_dir, name)


def bind_publisher(zctx: zmq.Context, runtime_dir: str) -> zmq.Socket:
    """The events socket (``ipc/events.py``), private to the service user (0600): an XPUB that hands
    the ROS worker every subscription message (verbose), so that it can confirm each one."""
    pub = zctx.socket(zmq.XPUB)
    pub.setsockopt(zmq.LINGER, 0)
    pub.setsockopt(zmq.SNDHWM, events.HIGH_WATER)
    pub.setsockopt(zmq.XPUB_VERBOSE, 1)
    pub.setsockopt(zmq.MAXMSGSIZE, 4096)  # subscription messages are all it ever receives
    return bind_private(pub, runtime_dir, events.EVENTS_SOCKET_NAME)


def bind_private(sock: zmq.Socket, runtime_dir: str, name: str) -> zmq.Socket:
    path = os.path.join(runtime_dir, name)
    if os.path.exists(path):
        os.unlink(path)  # stale: we hold the lock, so nobody else serves it
    old_umask = os.umask(0o177)
    try:
        sock.bind("ipc://" + path)
    finally:
        os.umask(old_umask)
    os.chmod(path, 0o600)
    return sock


@dataclass(slots=True)
class Request:
    identity: bytes
    rid: int
    cmd: str
    args: dict
    budget_ms: int
    request_id: str | None = None  # the HTTP request's X-Request-Id, for log lines


def reply_frame(rid: int, result: dict[str, Any] | None = None, error: IpcError | None = None) -> bytes:
    if error is not None:
        return protocol.pack({"v": protocol.VERSION, "id": rid, "ok": False, "error": error.to_wire()})
    return protocol.pack({"v": protocol.VERSION, "id": rid, "ok": True, "result": result})


def read_requests(router: zmq.Socket, stats, accept: Callable[[Request], None],
                  commands: tuple[str, ...] = protocol.COMMANDS) -> None:
    """Read the requests waiting on ``router`` and hand each valid one to ``accept``.

    ``accept`` may raise :class:`IpcError`, which is answered to that request.  ``commands``: those
    this socket serves (the fleet link's are its own, ``supervisor/fleet/server.py``).
    """
    for _ in range(READ_BATCH):
        if not router.get(zmq.EVENTS) & zmq.POLLIN:
            return
        try:
            frames = router.recv_multipart(zmq.NOBLOCK)
        except zmq.Again:
            return
        if len(frames) != 2:
            stats.ipc_dropped_frames += 1
            continue
        identity, frame = frames
        try:
            message = protocol.unpack(frame)
        except ValueError as exc:
            stats.ipc_dropped_frames += 1
            log.debug("dropped a frame: %s", exc)
            continue
        rid = message.get("id")
        if isinstance(rid, bool) or not isinstance(rid, int):
            stats.ipc_dropped_frames += 1
            continue
        try:
            accept(_decode(identity, rid, message, commands))
        except IpcError as exc:
            _send(router, identity, reply_frame(rid, error=exc))


def _decode(identity: bytes, rid: int, message: dict, commands: tuple[str, ...] = protocol.COMMANDS) -> Request:
    if message.get("v") != protocol.VERSION:
        raise IpcError("unsupported-version",
                       f"protocol version {message.get('v')!r} is not supported (this worker speaks "
                       f"{protocol.VERSION})", {"supported": protocol.VERSION})
    cmd = message.get("cmd")
    args = message.get("args", {})
    budget = message.get("deadline_ms", 5000)
    if not isinstance(cmd, str) or cmd not in commands:
        raise IpcError("unknown-command", f"unknown command {str(cmd)[:64]!r}")
    if not isinstance(args, dict):
        raise IpcError("bad-request", "args: expected a map")
    if isinstance(budget, bool) or not isinstance(budget, int) or not (0 < budget <= 600000):
        raise IpcError("bad-request", "deadline_ms: expected an integer from 1 to 600000")
    request_id = message.get("request_id")
    if request_id is not None and not protocol.valid_request_id(request_id):
        raise IpcError("bad-request", "request_id: expected 1 to 128 characters of A-Z a-z 0-9 . _ -")
    return Request(identity, rid, cmd, args, budget, request_id)


def _send(router: zmq.Socket, identity: bytes, frame: bytes) -> None:
    try:
        router.send_multipart([identity, frame], zmq.NOBLOCK)
    except zmq.ZMQError:
        pass  # the client went away; its reply has no one to go to


class ControlServer:
    """The control thread: ``ping`` and ``stats`` on ``rosworker-ctl.sock``, and the watchdog."""

    def __init__(self, zctx: zmq.Context, runtime_dir: str, stats, info: dict[str, Any],
                 socket_name: str = protocol.CONTROL_SOCKET_NAME, check_every: float = WATCHDOG_CHECK):
        self.socket_name = socket_name  # the fleet link serves its own (fleetlink-ctl.sock)
        self.check_every = check_every  # the fleet link has no executor to watch: it looks up seldom
        self.zctx = zctx
        self.runtime_dir = runtime_dir
        self.stats = stats
        self.info = info
        self.started = time.monotonic()
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._error_logged = -ERROR_LOG_EVERY
        self.errors = 0  # exceptions contained on the control thread
        self._thread = threading.Thread(target=self._run, name="ipc-control", daemon=True)

    def answer(self, cmd: str) -> dict[str, Any]:
        """The result of ``ping`` or ``stats`` (also used by the ROS thread on the work socket)."""
        if cmd == "ping":
            return {**self.info, "pid": os.getpid(), "uptime_s": round(time.monotonic() - self.started, 3),
                    "protocol": protocol.VERSION}
        return {**self.stats.snapshot(), "pid": os.getpid()}

    def start(self, timeout: float = 5.0) -> None:
        self._thread.start()
        if not self._ready.wait(timeout):
            raise RuntimeError("the IPC control thread did not start in time")
        if self._error is not None:
            raise self._error

    def finish(self, timeout: float = 3.0) -> None:
        self._stop.set()
        self._thread.join(timeout)

    def _accept(self, router: zmq.Socket, request: Request) -> None:
        if request.cmd not in protocol.IMMEDIATE:
            raise IpcError("bad-request", f"the control socket answers {', '.join(protocol.IMMEDIATE)} only; "
                                          f"send {request.cmd!r} to {protocol.SOCKET_NAME}")
        try:
            result = self.answer(request.cmd)
        except Exception:
            self._contained(f"answering {request.cmd}")
            raise IpcError("internal", f"the ROS worker failed to answer {request.cmd} (logged)") from None
        _send(router, request.identity, reply_frame(request.rid, result))

    def _contained(self, where: str) -> None:
        """Count the exception being handled; log its traceback at most once per ``ERROR_LOG_EVERY``."""
        self.errors += 1
        now = time.monotonic()
        if now - self._error_logged >= ERROR_LOG_EVERY:
            self._error_logged = now
            log.exception("control thread: %s failed (contained; %d so far, further tracebacks at most "
                          "every %g s)", where, self.errors, ERROR_LOG_EVERY)

    def _run(self) -> None:
        try:
            router = bind_router(self.zctx, self.runtime_dir, self.socket_name)
        except BaseException as exc:
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        try:
            while not self._stop.is_set():
                try:
                    if router.poll(int(self.check_every * 1000), zmq.POLLIN):
                        read_requests(router, self.stats, lambda request: self._accept(router, request))
                    self.stats.check_watchdog()
                except zmq.ContextTerminated:
                    break
                except Exception:
                    self._contained("the control loop")
                    self._stop.wait(self.check_every)  # never a hot loop of the same failure
        finally:
            router.close(linger=0)
            try:
                os.unlink(os.path.join(self.runtime_dir, self.socket_name))
            except OSError:
                pass
