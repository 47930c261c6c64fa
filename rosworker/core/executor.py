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

Sleeping: in one ``zmq.Poller.poll`` over the work socket, the readers' sockets
and a wake-up pipe (written by :meth:`RosExecutor.stop`, which is
async-signal-safe, by :meth:`RosExecutor.post`, by ``signal.set_wakeup_fd``
when a signal comes: the worker's handler only records it, and ``stop_when``
tells the loop; and by the waiter), with the next timer, or the next time a
poller asked for, as the timeout.  Nothing wakes it on a clock.

Waking on ROS events: the waiter thread (``waiter.py``: who waits on what, and
why it is race-free) sleeps in an rcl wait set over the entities that have
work open, which this thread names before each sleep (:meth:`RosExecutor._arm`):
the subscriptions of the cold topics callers wait on (:meth:`RosExecutor.watch_cold`)
and the entities of the pollers (:meth:`RosExecutor.add_poller`: trigger
subscriptions; service, action and parameter clients with calls open).  When
one is ready it writes to the wake-up pipe, and this thread runs the cold
topics' ``on_ready`` and every poller's ``poll``, which ``take`` what came.
A pooled topic without a reader is in no wait set: it costs nothing per
message.  ``loop_wakeups`` in the stats counts the rounds of this loop.

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
from typing import Any, NamedTuple

import zmq

from ipc import protocol
from ipc.errors import IpcError
from ipc.server import Request, bind_router, read_requests, send_frames

from .requestlog import SlowCommands, bound
from .stats import Stats
from .task import Task, Timer
from .waiter import Waiter

log = logging.getLogger("sovd.rosworker.executor")

IDLE_WAIT_CAP = 1.0   # seconds: the loop wakes at least this often (its stop checks)
NO_WAITER_POLL = 0.002  # seconds between looks at waited entities when no waiter runs (unit tests)
CLOSE_GRACE = 0.25    # seconds the socket stays open after the last replies (see linger())
ERROR_LOG_EVERY = 10.0  # seconds: one traceback per place and period, the rest are counted


class Poller(NamedTuple):
    where: str
    waitables: Callable[[], list]
    poll: Callable[[], None]
    due: Callable[[], float | None]


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
        self._slow = SlowCommands(log)
        self._handlers: dict[str, Callable[[Task], None]] = {}
        # Entries that callers wait on, what to do with one, their subscriptions (see watch_cold).
        self._cold_entries: Callable[[], list] = lambda: []
        self._on_ready: Callable[[Any], None] = lambda entry: None
        self._cold_waitables: Callable[[], list] = lambda: []
        self.on_idle: Callable[[], None] = lambda: None
        # Pieces that take from rclpy entities (service, action, parameter clients, triggers):
        # (where, waitables, poll, due), see add_poller.
        self._pollers: list[Poller] = []
        self._waiter: Waiter | None = None
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

    def watch_cold(self, entries: Callable[[], list], on_ready: Callable[[Any], None],
                   waitables: Callable[[], list]) -> None:
        """``entries()``: what callers wait on (the pool's cold topics), ``waitables()`` their subscriptions;
        ``on_ready(entry)`` is called for each entry when one of those is ready (before :meth:`run`)."""
        self._cold_entries = entries
        self._on_ready = on_ready
        self._cold_waitables = waitables

    def add_poller(self, name: str, waitables: Callable[[], list], poll: Callable[[], None],
                   due: Callable[[], float | None] = lambda: None) -> None:
        """A piece that takes from rclpy entities: ``poll()`` runs when one of ``waitables()`` is ready
        (the entities with work open: an idle piece returns none and costs nothing), and when the
        time ``due()`` returns (a ``time.monotonic()``, or None) has come: its deadlines, or a
        server it waits to see matched (rclpy has no event for that).  Both are asked every round,
        so they must be cheap.  ``name`` labels a failure of ``poll`` in the log (contained like a
        timer's)."""
        self._pollers.append(Poller(f"polling {name}", waitables, poll, due))

    def use_waiter(self, context) -> None:
        """Wake on ROS events through a waiter thread over ``context`` (ROS thread, before :meth:`run`).
        Without one (unit tests without rclpy), waited entities are looked at every ``NO_WAITER_POLL`` s."""
        self._waiter = Waiter(context, self._wake_from_waiter)
        self._waiter.start()

    def release(self, entity: Any) -> None:
        """Before ``entity`` is destroyed (``node.py``): out of the waiter's wait set."""
        if self._waiter is not None:
            self._waiter.release(entity)

    def _wake_from_waiter(self) -> None:
        try:
            os.write(self._wake_w, b"w")
        except OSError:
            pass  # the pipe is full (a wake-up is pending) or closed

    def add_reader(self, name: str, sock: zmq.Socket, on_readable: Callable[[], None]) -> None:
        """The loop also waits on ``sock`` and calls ``on_readable()`` when it has something to read
        (the events socket's subscription messages); a failure is contained like a timer's."""
        self._readers[sock] = (f"reading {name}", on_readable)
        if self._poller is not None:
            self._poller.register(sock, zmq.POLLIN)

    def remove_reader(self, sock: zmq.Socket) -> None:
        if self._readers.pop(sock, None) is not None and self._poller is not None:
            self._poller.unregister(sock)

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
            self._slow.answered(task.cmd, task.args, message, self._last_reply - task.received, self._last_reply)

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

    def _arm(self) -> tuple[bool, float | None, list[Poller]]:
        """Name what the waiter waits on; whether anything is waited on, the pollers' next due time, and
        the pollers with something open (the others have nothing to take)."""
        waited = list(self._cold_waitables())
        due = None
        active = []
        for poller in self._pollers:
            entities = poller.waitables()
            when = poller.due()
            if entities or when is not None:
                waited += entities
                active.append(poller)
            if when is not None and (due is None or when < due):
                due = when
        if self._waiter is not None:
            self._waiter.arm(waited)
        return bool(waited), due, active

    def _take_ready(self, active: list[Poller]) -> None:
        """Something waited on is ready (or due): the cold topics' and the open pollers' turn."""
        for entry in self._cold_entries():
            self.guarded("a cold-topic wake-up", self._on_ready, entry)
        for poller in active:
            self.guarded(poller.where, poller.poll)

    def run(self) -> None:
        """The ROS thread's loop, until :meth:`stop` or ``stop_when()``; then :meth:`linger`, :meth:`close`."""
        while not self._stopping.is_set():
            if self._stop_when():
                self._stopping.set()
                break
            timeout = 0.0 if self._queue else self._next_timeout()
            waited, due, active = self._arm()
            if due is not None:
                timeout = min(timeout, max(0.0, due - time.monotonic()))
            if waited and self._waiter is None:
                timeout = min(timeout, NO_WAITER_POLL)
            events = dict(self._poller.poll(math.ceil(timeout * 1000)))
            self.stats.loop_wakeups += 1
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
            if ((self._waiter.fired() if self._waiter is not None else waited)
                    or (due is not None and time.monotonic() >= due)):
                self._take_ready(active)
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
        """Stop the waiter; close the work socket and the wake-up pipe (ROS thread, after :meth:`linger`)."""
        if self._waiter is not None:
            self._waiter.stop()
            self._waiter = None
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

