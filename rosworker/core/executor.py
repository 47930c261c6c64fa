"""The single ROS thread: every rclpy call of the gateway runs here.

The ROS thread owns the work socket (``rosworker.sock``, a ROUTER) outright.
Between its own work it polls that socket, reads every request waiting there
(:func:`ipc.server.read_requests`), queues them (``backpressure`` at once
beyond ``max_queue_depth``), runs them and sends each reply straight back.  A
warm sample is read, answered and sent by this one thread: no hand-off
between threads, no lock.

``ping`` and ``stats`` are answered by the control thread on a socket of its
own (``ipc/server.py``), so they never wait behind ROS work, however long the
queue or the task that runs.  Sent to the work socket, they are refused
(``bad-request``) as soon as they are read.

Sleeping: in one ``zmq.Poller.poll`` over the work socket and a wake-up pipe
(written by :meth:`RosExecutor.stop`, which is async-signal-safe, by
:meth:`RosExecutor.post`, and by ``signal.set_wakeup_fd`` when a signal comes:
the worker's handler only records it, and ``stop_when`` tells the loop), with
the next timer as the timeout.  While callers wait for the first message of a
cold topic the timeout is at most ``COLD_POLL`` and each cold subscription is
tried (``take``) on every round; so no rcl wait set and no guard condition
are needed, and a pooled topic costs nothing between reads.

Pieces that wait on rclpy client handles (services, actions, parameters) register
with :meth:`RosExecutor.add_poller`: while one has work open, the loop wakes every
``COLD_POLL`` s and lets it ``take`` what came; no rclpy executor, no spin, nothing
blocks this thread on a future.

Timers (graph polling, idle sweep, cold-wait deadlines, stream ticks,
publishers waiting for their subscribers) run on the same thread from a heap.
Another thread hands work to this one with :meth:`RosExecutor.post` (the
restart state's writer: the replies that waited for a write).

Wiring: the families are built on an executor (they set its timers), so what
the loop runs is given to it after them, before :meth:`RosExecutor.run`: the
command handlers of every family (:meth:`RosExecutor.serve`, by ``main.py``),
and the data family's cold entries (:meth:`RosExecutor.watch_cold`).

Containment: an exception in a task answers that task's caller with an
error; an exception anywhere else on this thread (a timer, a cold-topic
wake-up, the idle hook) is logged, rate-limited per place, and counted in
``loop_errors``.  Nothing but :meth:`RosExecutor.stop` ends the thread.
"""

from __future__ import annotations

import collections
import heapq
import itertools
import logging
import math
import os
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import zmq

from ipc import protocol
from ipc.errors import IpcError
from ipc.server import Request, bind_router, read_requests, send_frames

from .requestlog import bound
from .stats import Stats

log = logging.getLogger("sovd.rosworker.executor")

IDLE_WAIT_CAP = 1.0   # seconds: the loop wakes at least this often
COLD_POLL = 0.002     # seconds between looks at cold subscriptions while somebody waits on one
CLOSE_GRACE = 0.25    # seconds the socket stays open after the last replies (see linger())
ERROR_LOG_EVERY = 10.0  # seconds: one traceback per place and period, the rest are counted
SLOW_COMMAND = 0.5      # seconds from receipt to answer past which a command is logged (info)
SLOW_LOG_PER_S = 20     # at most this many such lines per second; the rest are counted only


class Task:
    """One queued command; ``reply``/``fail`` may be called once, on the ROS thread.

    ``request_id`` is the HTTP request's id when the HTTP side sent one: log
    lines written while the task runs or is answered carry it (``requestlog.py``).
    """

    __slots__ = ("cmd", "args", "identity", "rid", "deadline", "received", "request_id", "answered",
                 "counted", "_executor")

    def __init__(self, executor: RosExecutor, request: Request, deadline: float, received: float):
        self.cmd = request.cmd
        self.args = request.args
        self.identity = request.identity
        self.rid = request.rid
        self.deadline = deadline
        self.received = received
        self.request_id = request.request_id
        self.answered = False
        self.counted = False  # in stats.commands: before its reply goes, so a later ``stats`` sees it
        self._executor = executor

    def reply(self, result: dict[str, Any]) -> None:
        if not self.answered:
            self.answered = True
            self._executor._send(self, {"v": protocol.VERSION, "id": self.rid, "ok": True, "result": result})

    def fail(self, error: IpcError) -> None:
        if not self.answered:
            self.answered = True
            self._executor._send(self, {"v": protocol.VERSION, "id": self.rid, "ok": False,
                                        "error": error.to_wire()})


class Timer:
    __slots__ = ("when", "fn", "cancelled")

    def __init__(self, when: float, fn: Callable[[], None]):
        self.when = when
        self.fn = fn
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class RosExecutor:
    """Owns the ROS thread, the work socket, the task queue and the timers."""

    def __init__(self, zctx: zmq.Context, runtime_dir: str, stats: Stats, max_queue_depth: int,
                 stop_when: Callable[[], bool] = lambda: False):
        self._zctx = zctx
        self.runtime_dir = runtime_dir
        self.stats = stats
        self.max_queue_depth = max_queue_depth
        self._stop_when = stop_when            # looked at every round: True ends the loop (a signal)
        self._queue: collections.deque[Task] = collections.deque()
        self._timers: list[tuple[float, int, Timer]] = []
        self._seq = itertools.count()
        self._stopping = threading.Event()
        self.closing = False                   # after run(): new work is answered "shutdown"
        self._router: zmq.Socket | None = None
        self._poller: zmq.Poller | None = None
        self._wake_r, self._wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self._last_reply = 0.0
        self._error_logged: dict[str, float] = {}
        self._slow_second = 0   # the second (monotonic) whose slow-command lines are counted
        self._slow_logged = 0
        self._handlers: dict[str, Callable[[Task], None]] = {}
        # Entries that callers wait on, and what to do with one (see watch_cold).
        self._cold_entries: Callable[[], list] = lambda: []
        self._on_ready: Callable[[Any], None] = lambda entry: None
        self.on_idle: Callable[[], None] = lambda: None
        # Pieces that wait on rclpy futures or handles (service, action, parameter clients):
        # (name, active, poll), see add_poller.
        self._pollers: list[tuple[str, Callable[[], bool], Callable[[], None]]] = []
        self._posted: collections.deque[Callable[[], None]] = collections.deque()
        # Other sockets the loop waits on: socket -> (name, what reads it), see add_reader.
        self._readers: dict[zmq.Socket, tuple[str, Callable[[], None]]] = {}

    # ---- any thread -------------------------------------------------------------------
    def stop(self) -> None:
        """Ask the ROS thread to finish its loop; safe in a signal handler (no lock, no zmq)."""
        self._stopping.set()
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass  # the pipe is full (a wake-up is pending) or already closed

    def post(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` on the ROS thread soon (any thread; deque.append is atomic)."""
        self._posted.append(fn)
        try:
            os.write(self._wake_w, b"p")
        except OSError:
            pass  # the pipe is full (a wake-up is pending) or closed (run_posted() is called at the end)

    def run_posted(self) -> None:
        """Run what other threads posted (ROS thread)."""
        while self._posted:
            self.guarded("posted work", self._posted.popleft())

    @property
    def stopping(self) -> bool:
        return self._stopping.is_set()

    @property
    def wakeup_fd(self) -> int:
        """The wake-up pipe's write end, for ``signal.set_wakeup_fd`` (non-blocking; valid until close())."""
        return self._wake_w

    # ---- ROS thread: set-up ------------------------------------------------------------
    def serve(self, handlers: Mapping[str, Callable[[Task], None]]) -> None:
        """The queued commands this executor runs, by name (before :meth:`run`)."""
        self._handlers = dict(handlers)

    def watch_cold(self, entries: Callable[[], list], on_ready: Callable[[Any], None]) -> None:
        """While ``entries()`` is not empty, ``on_ready(entry)`` is called for each on every round.

        ``entries`` are what callers wait on (the pool's cold topics); the loop then polls
        at most every ``COLD_POLL`` s (before :meth:`run`).
        """
        self._cold_entries = entries
        self._on_ready = on_ready

    def add_poller(self, name: str, active: Callable[[], bool], poll: Callable[[], None]) -> None:
        """While ``active()`` is true, ``poll()`` runs on every round and the loop wakes every ``COLD_POLL`` s.

        For pieces that wait on something the loop's sockets cannot wake it for: rclpy
        client handles (a service response, an action's goal, feedback and status) are
        read with ``take`` by ``poll``, as the pool reads cold topics.  ``active`` is
        asked every round, so it must be cheap (a length); an idle piece costs nothing.
        ``name`` labels a failure of ``poll`` in the log (contained like a timer's).
        """
        self._pollers.append((f"polling {name}", active, poll))

    def add_reader(self, name: str, sock: zmq.Socket, on_readable: Callable[[], None]) -> None:
        """The loop also waits on ``sock`` and calls ``on_readable()`` when it has something to read
        (the events socket's subscription messages); a failure is contained like a timer's."""
        self._readers[sock] = (f"reading {name}", on_readable)
        if self._poller is not None:
            self._poller.register(sock, zmq.POLLIN)

    def remove_reader(self, sock: zmq.Socket) -> None:
        if self._readers.pop(sock, None) is not None and self._poller is not None:
            self._poller.unregister(sock)

    def _polling(self) -> list[tuple[str, Callable[[], bool], Callable[[], None]]]:
        return [p for p in self._pollers if p[1]()] if self._pollers else []

    def bind(self) -> None:
        """Bind the work socket (call on the ROS thread before :meth:`run`)."""
        self._router = bind_router(self._zctx, self.runtime_dir, protocol.SOCKET_NAME)
        self._poller = zmq.Poller()
        self._poller.register(self._router, zmq.POLLIN)
        self._poller.register(self._wake_r, zmq.POLLIN)
        for sock in self._readers:
            self._poller.register(sock, zmq.POLLIN)

    def call_later(self, delay: float, fn: Callable[[], None]) -> Timer:
        timer = Timer(time.monotonic() + delay, fn)
        heapq.heappush(self._timers, (timer.when, next(self._seq), timer))
        return timer

    # ---- ROS thread: requests and replies ---------------------------------------------
    def _read(self) -> None:
        read_requests(self._router, self.stats, self._accept)

    def _accept(self, request: Request) -> None:
        """One decoded request: answer it now, queue it, or refuse it (raises IpcError)."""
        if request.cmd in protocol.IMMEDIATE:
            raise IpcError("bad-request", f"{request.cmd} is answered on the control socket "
                           f"({protocol.CONTROL_SOCKET_NAME}), not on the work socket")
        if self.closing:
            raise IpcError("shutdown", "The gateway is shutting down")
        if len(self._queue) >= self.max_queue_depth:
            self.stats.queue_dropped += 1
            raise IpcError("backpressure",
                           f"The ROS worker's queue is full ({self.max_queue_depth} pending); retry shortly",
                           {"max_queue_depth": self.max_queue_depth})
        now = time.monotonic()
        self._queue.append(Task(self, request, now + request.budget_ms / 1000, now))
        depth = len(self._queue)
        self.stats.queue_depth = depth
        if depth > self.stats.queue_max_depth_observed:
            self.stats.queue_max_depth_observed = depth

    def _send(self, task: Task, message: dict) -> None:
        if not task.counted:
            task.counted = True
            self.stats.count_command(task.cmd)
        with bound(task.request_id):
            try:
                frame = protocol.pack(message)
            except Exception:
                log.exception("could not encode the reply to %s", task.cmd)
                frame = protocol.pack({"v": protocol.VERSION, "id": task.rid, "ok": False,
                                       "error": IpcError("internal", "reply could not be encoded").to_wire()})
            self._send_frame(task.identity, frame)
            took = self._last_reply - task.received
            if took >= SLOW_COMMAND:
                self._log_slow(task, message, took)

    def _log_slow(self, task: Task, message: dict, took: float) -> None:
        """One info line per command answered after ``SLOW_COMMAND`` s (at most ``SLOW_LOG_PER_S``/s)."""
        second = int(self._last_reply)
        if second != self._slow_second:
            self._slow_second, self._slow_logged = second, 0
        self._slow_logged += 1
        if self._slow_logged > SLOW_LOG_PER_S:
            return
        topic = task.args.get("topic") if isinstance(task.args, dict) else None
        what = f"{task.cmd} {topic}" if isinstance(topic, str) else task.cmd
        if message.get("ok"):
            result = message.get("result") or {}
            outcome = result.get("status", "ok") if isinstance(result, dict) else "ok"
            if isinstance(result, dict) and result.get("reason"):
                outcome += f" ({result['reason']})"
        else:
            outcome = f"error {(message.get('error') or {}).get('code')}"
        log.info("slow command: %s answered after %d ms: %s", what[:300], int(took * 1000), outcome)

    def _send_frame(self, identity: bytes, frame: bytes) -> None:
        self._last_reply = time.monotonic()
        try:
            send_frames(self._router, [identity, frame])
        except zmq.ZMQError:
            pass  # the client went away (or its queue is full): nobody to answer

    # ---- ROS thread: the loop ----------------------------------------------------------
    def guarded(self, where: str, fn: Callable[..., Any], *args: Any) -> Any:
        """Run ``fn``; an exception is logged (once per ``where`` and period) and counted, never raised."""
        try:
            return fn(*args)
        except Exception:
            self._contained(where)
            return None

    def _contained(self, where: str) -> None:
        """Count the exception being handled; log its traceback once per ``where`` and period."""
        self.stats.loop_errors += 1
        now = time.monotonic()
        if now - self._error_logged.get(where, -ERROR_LOG_EVERY) >= ERROR_LOG_EVERY:
            self._error_logged[where] = now
            log.exception("%s failed (contained; further failures here are counted and "
                          "logged at most every %g s)", where, ERROR_LOG_EVERY)

    def _next_timeout(self) -> float:
        while self._timers and self._timers[0][2].cancelled:
            heapq.heappop(self._timers)
        if not self._timers:
            return IDLE_WAIT_CAP
        return min(IDLE_WAIT_CAP, max(0.0, self._timers[0][0] - time.monotonic()))

    def _run_timers(self) -> None:
        now = time.monotonic()
        while self._timers and self._timers[0][0] <= now:
            _, _, timer = heapq.heappop(self._timers)
            if timer.cancelled:
                continue
            started = self.stats.task_started()
            ok = True
            try:
                timer.fn()
            except Exception:
                ok = False
                self._contained("a timer")
            finally:
                self.stats.task_finished(started, ok)

    def _run_task(self, task: Task) -> None:
        with bound(task.request_id):
            self._run_bound(task)

    def _run_bound(self, task: Task) -> None:
        started = self.stats.task_started()
        ok = True
        try:
            if started > task.deadline:
                raise IpcError("deadline-exceeded", "The request's deadline passed while it was queued",
                               {"command": task.cmd})
            handler = self._handlers.get(task.cmd)
            if handler is None:
                raise IpcError("unknown-command", f"Unknown command {task.cmd!r}")
            handler(task)
        except IpcError as exc:
            ok = False
            task.fail(exc)
        except Exception:
            ok = False
            log.exception("command %s failed", task.cmd)
            task.fail(IpcError("internal", f"Internal error in the ROS worker while handling {task.cmd!r}; "
                                           "see its log"))
        finally:
            # Only names of the protocol are queued (ipc/server.py), so the table stays small.
            self.stats.task_finished(started, ok, task.cmd, counted=task.counted)
            task.counted = True

    def drain(self) -> None:
        """Run what is queued now; requests that come meanwhile are read between tasks."""
        for _ in range(len(self._queue)):
            if not self._queue:
                break
            task = self._queue.popleft()
            self.stats.queue_depth = len(self._queue)
            self._run_task(task)
            if self._router is not None and self._router.get(zmq.EVENTS) & zmq.POLLIN:
                self._read()

    def _wake_cold(self) -> None:
        for entry in self._cold_entries():
            self.guarded("a cold-topic wake-up", self._on_ready, entry)

    def run(self) -> None:
        """The ROS thread's loop, until :meth:`stop` or ``stop_when()``; then :meth:`linger`, :meth:`close`."""
        while not self._stopping.is_set():
            if self._stop_when():
                self._stopping.set()
                break
            timeout = 0.0 if self._queue else self._next_timeout()
            cold = bool(self._cold_entries())
            polling = self._polling()
            if cold or polling:
                timeout = min(timeout, COLD_POLL)
            events = dict(self._poller.poll(math.ceil(timeout * 1000)))
            if self._wake_r in events:
                self._drain_pipe()
            if self._posted:
                self.run_posted()
            if self._router in events:
                self.guarded("reading requests", self._read)
            for sock, (where, on_readable) in self._readers.items():
                if sock in events:
                    self.guarded(where, on_readable)
            self._run_timers()
            if cold:
                self._wake_cold()
            for where, _, poll in polling:
                self.guarded(where, poll)
            self.drain()
            if self.stats.degraded and not self._queue:
                self.stats.degraded = False  # idle again: the episode is over
            self.guarded("the idle hook", self.on_idle)

    def _drain_pipe(self) -> None:
        try:
            while os.read(self._wake_r, 512):
                pass
        except OSError:
            pass

    # ---- ROS thread: the end -------------------------------------------------------------
    def linger(self, grace: float = CLOSE_GRACE) -> None:
        """Answer what comes with "shutdown" until ``grace`` s after the last reply.

        Clients connect with ``ZMQ_IMMEDIATE`` (a request sent while the worker is
        down must fail, not wait for its successor), and libzmq then drops what a
        client has received but not yet read when the connection goes: without this
        pause, the answers to woken waiters and drained commands could be lost.
        """
        self.closing = True
        self.drain()
        until = max(time.monotonic(), self._last_reply) + grace
        while (left := until - time.monotonic()) > 0:
            if dict(self._poller.poll(max(1, math.ceil(left * 1000)))).get(self._router):
                self.guarded("reading requests", self._read)
                self.drain()

    def close(self) -> None:
        """Close the work socket and the wake-up pipe (ROS thread, after :meth:`linger`)."""
        if self._router is not None:
            self._router.close(linger=0)
            self._router = None
            try:
                os.unlink(os.path.join(self.runtime_dir, protocol.SOCKET_NAME))
            except OSError:
                pass
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass

