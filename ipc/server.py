"""The ROS worker's IPC thread: the ROUTER socket, the lock, and the stand-in front.

This thread never touches rclpy.  It

- holds an exclusive ``flock`` on ``<runtime_dir>/rosworker.lock`` before it
  binds, so a second worker on the same directory cannot steal the socket;
- binds the ROUTER and shares it with the ROS thread: whoever holds the
  executor's ``front_lock`` serves it (see ``rosworker/executor.py``).  The
  ROS thread normally does, so that a warm sample is read, answered and
  sent back by one thread.  This thread serves it (``front``) from start-up
  until the ROS thread claims it (``back`` on the reply pair), when the ROS
  thread hands it over (``take``: someone waits on a cold topic), and when a
  task has run longer than ``TAKEOVER_AFTER_MS`` (it takes the lock, which the
  ROS thread never holds while it works), so that ``ping``/``stats`` never wait
  behind ROS work;
- as the front, decodes requests (:meth:`IpcServer._receive`, the same code
  the ROS thread runs when it is the front): drops frames that are not
  requests (counted), answers malformed ones with an error, answers
  ``ping``/``stats`` at once, queues everything else for the ROS thread
  (``backpressure`` when full), and forwards the ROS thread's replies (which
  then arrive on the inproc pair) to the clients;
- checks the watchdog every ``WATCH_TICK`` (not the front) or
  ``WATCHDOG_CHECK`` (the front) seconds.
"""

from __future__ import annotations

import fcntl
import logging
import os
import threading
import time
from typing import Any

import zmq

from . import protocol
from .errors import IpcError

# One-frame signals from the ROS thread on the reply pair (replies have two frames).
TAKE = b"take"   # serve the ROUTER: the ROS thread stops polling it (cold waiters, shutdown)
BACK = b"back"   # hand it back, after forwarding the replies that came before

log = logging.getLogger("sovd.rosworker.ipc")

WATCHDOG_CHECK = 0.05
WATCH_TICK = 0.02          # seconds between looks at the ROS thread while it is the front
TAKEOVER_AFTER_MS = 20     # a task running this long hands the socket to this thread
HANDOVER_WAIT = 1.0        # seconds to wait for the lock the ROS thread gave away
CLOSE_GRACE = 0.25         # seconds the socket stays open after the last replies (see _linger)


class LockHeld(RuntimeError):
    """Another ROS worker owns this runtime directory."""


class RuntimeLock:
    def __init__(self, runtime_dir: str):
        self.path = os.path.join(runtime_dir, protocol.LOCK_NAME)
        self._fh = None

    def acquire(self) -> None:
        fh = open(self.path, "a+")
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.seek(0)
            holder = fh.read().strip() or "another process"
            fh.close()
            raise LockHeld(f"another ROS worker (pid {holder}) already serves {os.path.dirname(self.path)}; "
                           "refusing to take its socket") from None
        fh.seek(0)
        fh.truncate()
        fh.write(str(os.getpid()))
        fh.flush()
        os.chmod(self.path, 0o600)
        self._fh = fh

    def release(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


class IpcServer:
    """Runs on its own thread; see the module docstring."""

    def __init__(self, zctx: zmq.Context, runtime_dir: str, executor, stats, info: dict[str, Any]):
        self.zctx = zctx
        self.runtime_dir = runtime_dir
        self.executor = executor
        self.stats = stats
        self.info = info
        self.started = time.monotonic()
        self._closing = threading.Event()   # stop accepting work; answer "shutdown"
        self._finished = threading.Event()  # the ROS thread is done: flush and exit
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._front = False                 # this thread serves the ROUTER (see the docstring)
        self._thread = threading.Thread(target=self._run, name="ipc", daemon=True)

    def start(self, timeout: float = 5.0) -> None:
        self._thread.start()
        if not self._ready.wait(timeout):
            raise RuntimeError("the IPC thread did not start in time")
        if self._error is not None:
            raise self._error

    def close_for_work(self) -> None:
        self._closing.set()

    def finish(self, timeout: float = 3.0) -> None:
        self._closing.set()
        self._finished.set()
        self._thread.join(timeout)

    # ---- the thread ---------------------------------------------------------------------
    def _bind(self) -> tuple[zmq.Socket, zmq.Socket]:
        pair = self.executor.bind_replies()
        router = self.zctx.socket(zmq.ROUTER)
        router.setsockopt(zmq.LINGER, 500)
        router.setsockopt(zmq.MAXMSGSIZE, protocol.MAX_FRAME)
        # Per peer: a client has one request in flight per thread, so 1000 is far above
        # need, and it bounds what a hostile peer makes the worker buffer.
        router.setsockopt(zmq.RCVHWM, 1000)
        router.setsockopt(zmq.SNDHWM, 1000)
        path = os.path.join(self.runtime_dir, protocol.SOCKET_NAME)
        if os.path.exists(path):
            os.unlink(path)  # stale: we hold the lock, so nobody else serves it
        old_umask = os.umask(0o177)
        try:
            router.bind(protocol.endpoint(self.runtime_dir))
        finally:
            os.umask(old_umask)
        os.chmod(path, 0o600)
        return router, pair

    def _run(self) -> None:
        lock = self.executor.front_lock
        lock.acquire()  # the front until the ROS thread claims the socket
        try:
            router, pair = self._bind()
        except BaseException as exc:
            self._error = exc
            lock.release()
            self._ready.set()
            return
        self.executor.attach_front(router, self._receive)
        self._ready.set()
        self._front = True
        front_poller = zmq.Poller()
        front_poller.register(router, zmq.POLLIN)
        front_poller.register(pair, zmq.POLLIN)
        watch_poller = zmq.Poller()
        watch_poller.register(pair, zmq.POLLIN)
        try:
            while True:
                if self._front:
                    events = dict(front_poller.poll(int(WATCHDOG_CHECK * 1000)))
                    if pair in events:
                        self._from_ros(pair, router)
                    if self._front and router in events:
                        self._receive(router)
                else:
                    if watch_poller.poll(int(WATCH_TICK * 1000)):
                        self._from_ros(pair, router)
                    elif self.stats.current_task_age_ms() >= TAKEOVER_AFTER_MS and lock.acquire(blocking=False):
                        self._front = True  # the ROS thread is stuck in a task: stand in for it
                self.stats.check_watchdog()
                if self._finished.is_set():
                    # The ROS thread is done and has handed the socket over: flush and exit.
                    if self._front or lock.acquire(timeout=HANDOVER_WAIT):
                        self._front = True
                        self._from_ros(pair, router)
                        self._linger(router, pair)
                    break
        finally:
            if self._front:
                lock.release()
            router.close(linger=500)
            pair.close(linger=0)
            path = os.path.join(self.runtime_dir, protocol.SOCKET_NAME)
            try:
                os.unlink(path)
            except OSError:
                pass

    def _linger(self, router: zmq.Socket, pair: zmq.Socket) -> None:
        """Keep the socket open for ``CLOSE_GRACE`` after the last replies (answering "shutdown").

        Clients connect with ``ZMQ_IMMEDIATE`` (a request sent while the worker is down must
        fail, not wait for its successor), and libzmq then drops what a client has received
        but not yet read when the connection goes: without this pause, the answers to woken
        waiters and drained commands could be lost at the very end.
        """
        until = time.monotonic() + CLOSE_GRACE
        poller = zmq.Poller()
        poller.register(router, zmq.POLLIN)
        poller.register(pair, zmq.POLLIN)
        while (left := until - time.monotonic()) > 0:
            events = dict(poller.poll(max(1, int(left * 1000))))
            if pair in events:
                self._from_ros(pair, router)
            if router in events:
                self._receive(router)

    def _from_ros(self, pair: zmq.Socket, router: zmq.Socket) -> None:
        """Handle what the ROS thread sent, in order: replies to forward, ``take``, ``back``."""
        lock = self.executor.front_lock
        for _ in range(10000):
            if not pair.get(zmq.EVENTS) & zmq.POLLIN:
                return
            try:
                frames = pair.recv_multipart(zmq.NOBLOCK, copy=False)
            except zmq.Again:
                return
            if len(frames) == 1:
                signal = frames[0].bytes
                if signal == TAKE and not self._front:
                    if not lock.acquire(timeout=HANDOVER_WAIT):
                        log.error("the ROS thread handed the IPC socket over but kept its lock")
                        continue
                    self._front = True
                elif signal == BACK and self._front and not self._finished.is_set():
                    self._front = False
                    lock.release()
                continue  # a stale take/back: the state it asks for is already there
            if len(frames) != 2:
                continue
            if not self._front:
                # A reply sent while we were not the front: the ROS thread lost the lock to
                # a take-over that has not happened yet here; take the socket now.
                if not lock.acquire(timeout=HANDOVER_WAIT):
                    log.error("could not take the IPC socket to forward a reply")
                    continue
                self._front = True
            try:
                router.send_multipart(frames, zmq.NOBLOCK, copy=False)
            except zmq.ZMQError:
                pass  # the client went away; its reply has no one to go to

    def _receive(self, router: zmq.Socket) -> None:
        """Read the requests waiting on the ROUTER (run by whichever thread is the front)."""
        for _ in range(1000):
            if not router.get(zmq.EVENTS) & zmq.POLLIN:
                return
            try:
                frames = router.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            if len(frames) != 2:
                self.stats.ipc_dropped_frames += 1
                continue
            identity, frame = frames
            try:
                request = protocol.unpack(frame)
            except ValueError as exc:
                self.stats.ipc_dropped_frames += 1
                log.debug("dropped a frame: %s", exc)
                continue
            rid = request.get("id")
            if isinstance(rid, bool) or not isinstance(rid, int):
                self.stats.ipc_dropped_frames += 1
                continue
            try:
                self._dispatch(router, identity, rid, request)
            except IpcError as exc:
                self._reply(router, identity, rid, error=exc)

    def _dispatch(self, router: zmq.Socket, identity: bytes, rid: int, request: dict) -> None:
        if request.get("v") != protocol.VERSION:
            raise IpcError("unsupported-version",
                           f"protocol version {request.get('v')!r} is not supported (this worker speaks "
                           f"{protocol.VERSION})", {"supported": protocol.VERSION})
        cmd = request.get("cmd")
        args = request.get("args", {})
        budget = request.get("deadline_ms", 5000)
        if not isinstance(cmd, str) or cmd not in protocol.COMMANDS:
            raise IpcError("unknown-command", f"unknown command {str(cmd)[:64]!r}")
        if not isinstance(args, dict):
            raise IpcError("bad-request", "args: expected a map")
        if isinstance(budget, bool) or not isinstance(budget, int) or not (0 < budget <= 600000):
            raise IpcError("bad-request", "deadline_ms: expected an integer from 1 to 600000")
        if cmd == "ping":
            self._reply(router, identity, rid, result={
                **self.info, "pid": os.getpid(), "uptime_s": round(time.monotonic() - self.started, 3),
                "protocol": protocol.VERSION})
            return
        if cmd == "stats":
            self._reply(router, identity, rid, result={**self.stats.snapshot(), "pid": os.getpid()})
            return
        if self._closing.is_set():
            raise IpcError("shutdown", "The gateway is shutting down")
        if not self.executor.submit(cmd, args, identity, rid, time.monotonic() + budget / 1000):
            raise IpcError("backpressure",
                           f"The ROS worker's queue is full ({self.executor.max_queue_depth} pending); "
                           "retry shortly", {"max_queue_depth": self.executor.max_queue_depth})

    def _reply(self, router: zmq.Socket, identity: bytes, rid: int, result: dict | None = None,
               error: IpcError | None = None) -> None:
        if error is not None:
            message = {"v": protocol.VERSION, "id": rid, "ok": False, "error": error.to_wire()}
        else:
            message = {"v": protocol.VERSION, "id": rid, "ok": True, "result": result}
        try:
            router.send_multipart([identity, protocol.pack(message)], zmq.NOBLOCK)
        except zmq.ZMQError:
            pass
