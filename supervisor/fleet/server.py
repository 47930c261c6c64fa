"""The link's IPC: the HTTP workers' commands on ``fleetlink.sock``, ``ping``/``stats`` on ``fleetlink-ctl.sock``.

The wire is the ROS worker's (``ipc/PROTOCOL.md``: msgpack, one request → one reply, an id and a
deadline each; errors from ``ipc/errors.py``'s table), so the HTTP workers and the supervisor use
the same :class:`~ipc.client.RosWorkerClient`.  The commands are the link's own
(``supervisor/fleet/PROTOCOL.md``): ``ipc/fleet.py``'s :data:`~ipc.fleet.COMMANDS`.

The main thread owns the ROUTER: it reads requests (``ipc/server.py``'s :func:`read_requests`) and
hands each to a pool of ``THREADS`` threads, since a fan-out waits up to ``fleet_timeout`` for its
robots; past ``MAX_QUEUED`` requests in hand the answer is ``backpressure`` at once.  A pool thread
puts its reply on a queue and wakes the main thread through an eventfd; the main thread sends it.
A request whose budget ran out while it waited is answered ``deadline-exceeded`` without being run.
The control socket is :class:`~ipc.server.ControlServer`'s thread, never behind a fan-out.
"""

from __future__ import annotations

import collections
import logging
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from ipc.errors import IpcError
from ipc.fleet import COMMANDS, SOCKET_NAME
from ipc.server import Request, _send, bind_router, read_requests, reply_frame

log = logging.getLogger("sovd.fleet.server")

THREADS = 16
MAX_QUEUED = 256


class Server:
    def __init__(self, zctx, runtime_dir: str, stats, handlers: dict[str, Callable[[dict, float], dict]]):
        self.zctx = zctx
        self.runtime_dir = runtime_dir
        self.stats = stats
        self.handlers = handlers
        self.pool = ThreadPoolExecutor(max_workers=THREADS, thread_name_prefix="fleet-ipc")
        self._replies: collections.deque[tuple[bytes, bytes]] = collections.deque()
        self._wake = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._in_hand = 0
        self._lock = threading.Lock()

    def serve(self, stopping: Callable[[], bool], wake_fd: int | None = None, idle_wait: float = 0.5) -> None:
        """Serve until ``stopping()``; ``wake_fd`` (the signal wake-up pipe) ends a wait early."""
        import zmq

        router = bind_router(self.zctx, self.runtime_dir, SOCKET_NAME)
        poller = zmq.Poller()
        poller.register(router, zmq.POLLIN)
        poller.register(self._wake, zmq.POLLIN)
        if wake_fd is not None:
            poller.register(wake_fd, zmq.POLLIN)
        try:
            while not stopping():
                ready = dict(poller.poll(int(idle_wait * 1000)))
                if router in ready:
                    read_requests(router, self.stats, self._accept, COMMANDS)
                if self._wake in ready:
                    try:
                        os.eventfd_read(self._wake)
                    except BlockingIOError:
                        pass
                if wake_fd is not None and wake_fd in ready:
                    try:
                        while os.read(wake_fd, 512):
                            pass
                    except BlockingIOError:
                        pass
                while self._replies:
                    identity, frame = self._replies.popleft()
                    _send(router, identity, frame)
        finally:
            self.pool.shutdown(wait=False, cancel_futures=True)
            router.close(linger=0)
            try:
                os.unlink(os.path.join(self.runtime_dir, SOCKET_NAME))
            except OSError:
                pass
            os.close(self._wake)

    def _accept(self, request: Request) -> None:
        with self._lock:
            if self._in_hand >= MAX_QUEUED:
                raise IpcError("backpressure", f"the fleet link has {MAX_QUEUED} requests in hand")
            self._in_hand += 1
        deadline = time.monotonic() + request.budget_ms / 1000.0
        self.pool.submit(self._run, request, deadline)

    def _run(self, request: Request, deadline: float) -> None:
        try:
            if time.monotonic() >= deadline:
                raise IpcError("deadline-exceeded", f"{request.cmd}: the caller's deadline passed in the queue")
            frame = reply_frame(request.rid, self.handlers[request.cmd](request.args, deadline))
        except IpcError as exc:
            frame = reply_frame(request.rid, error=exc)
        except Exception:
            log.exception("fleet: %s failed", request.cmd)
            frame = reply_frame(request.rid, error=IpcError("internal", f"the fleet link failed on {request.cmd} "
                                                                        "(logged)"))
        finally:
            with self._lock:
                self._in_hand -= 1
        self._replies.append((request.identity, frame))
        try:
            os.eventfd_write(self._wake, 1)
        except OSError:
            pass  # closed: the server is stopping


_MISSING = object()


def arg(args: dict[str, Any], name: str, kind: type | tuple[type, ...], default: Any = _MISSING) -> Any:
    """One argument of a command, checked (``bad-request`` names it); ``default`` when it may be absent."""
    if name not in args or args[name] is None:
        if default is _MISSING:
            raise IpcError("bad-request", f"{name}: required")
        return default
    value = args[name]
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        raise IpcError("bad-request", f"{name}: not the expected type")
    return value
