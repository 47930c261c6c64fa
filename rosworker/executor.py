"""The single ROS thread: every rclpy call of the gateway runs here.

Who reads the IPC socket (the ROUTER that ``ipc/server.py`` binds) is the
*front*, and it moves between two threads; ``front_lock`` says who may touch
the socket right now:

- normally the ROS thread is the front: between its own work it polls the
  ROUTER, reads the requests (``ping``/``stats`` are answered at once, the
  rest go into the bounded deque, ``backpressure`` beyond it), runs them and
  sends each reply straight back on the ROUTER.  A warm sample costs no
  hand-off between threads at all;
- the IPC thread is the front while the ROS thread cannot poll: from start-up
  until the ROS thread claims the socket, while somebody waits on a cold
  topic (the ROS thread then sleeps in an rcl wait set), and when a task has
  run longer than the IPC thread's take-over limit (so ``ping``/``stats``
  never wait behind ROS work).  It then queues work with :meth:`submit` and
  forwards the replies the ROS thread sends over an inproc PAIR.

Hand-over: the ROS thread holds ``front_lock`` only while it polls, reads or
sends; it gives the front away by sending ``take`` on the PAIR and asks for
it back by sending ``back`` (the IPC thread forwards the replies that came
before it, then releases the lock).  A take-over by the IPC thread is noticed
by the ROS thread when it cannot get the lock to send a reply.

While the IPC thread is the front, the ROS thread sleeps in one of two ways:

- nobody waits on a cold topic: on a plain lock used as a wake-up flag
  (``_wakeup``, held while no wake-up is pending), with the next timer as
  its timeout; :meth:`submit` releases it only while the thread sleeps there;
- somebody waits on a cold topic: in an rcl wait set holding those
  subscriptions and a guard condition that :meth:`submit` triggers, so the
  first message and new work both wake it at once.

Each sleeping mode sets its flag *before* the thread looks at the queue one
last time, and ``submit`` reads the flags *after* appending under the same
lock, so a task is never left in the queue while the thread sleeps.  A
pooled topic costs nothing either way.

Timers (graph polling, idle sweep, cold-wait deadlines) run on the same
thread from a heap.
"""

from __future__ import annotations

import collections
import heapq
import itertools
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import zmq
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

from ipc import protocol
from ipc.errors import IpcError
from ipc.server import BACK, TAKE

from .stats import Stats

log = logging.getLogger("sovd.rosworker.executor")

REPLIES_ENDPOINT = "inproc://rosworker-replies"
IDLE_WAIT_CAP = 1.0  # seconds: the loop wakes at least this often
CLAIM_WAIT = 1.0     # seconds the ROS thread waits for the IPC thread to hand the socket back


class Task:
    """One queued command; ``reply``/``fail`` may be called once, on the ROS thread."""

    __slots__ = ("cmd", "args", "identity", "rid", "deadline", "answered", "_executor")

    def __init__(self, cmd: str, args: dict, identity: bytes, rid: int, deadline: float):
        self.cmd = cmd
        self.args = args
        self.identity = identity
        self.rid = rid
        self.deadline = deadline
        self.answered = False
        self._executor: RosExecutor | None = None

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
    """Owns the ROS thread, its task queue, its timers and its wake-up paths."""

    def __init__(self, context, zctx: zmq.Context, stats: Stats, max_queue_depth: int):
        self._context = context
        self._zctx = zctx
        self.stats = stats
        self.max_queue_depth = max_queue_depth
        self._queue: collections.deque[Task] = collections.deque()
        self._lock = threading.Lock()
        self._guard = _rclpy.GuardCondition(context.handle)
        self._timers: list[tuple[float, int, Timer]] = []
        self._seq = itertools.count()
        self._stopping = threading.Event()
        self._sock: zmq.Socket | None = None       # ROS thread's end of the reply pair
        self._replies: zmq.Socket | None = None    # IPC thread's end
        # The front (see the module docstring).
        self.front_lock = threading.Lock()
        self._router: zmq.Socket | None = None
        self._read_requests: Callable[[zmq.Socket], None] | None = None
        self._front = False                         # ROS thread's view: it serves the ROUTER
        self._front_poller: zmq.Poller | None = None
        # Wake-up of the ROS thread while the IPC thread is the front.
        self._wakeup = threading.Lock()
        self._wakeup.acquire()                      # held: no wake-up pending
        self._sleeping_on_lock = False
        self._sleeping_in_rcl = False
        self.handlers: dict[str, Callable[[Task], None]] = {}
        # Set by the pool: subscriptions that callers wait on, and what to do when one is ready.
        self.cold_entries: Callable[[], list] = lambda: []
        self.on_ready: Callable[[Any], None] = lambda entry: None
        self.on_idle: Callable[[], None] = lambda: None
        self.thread_ident: int | None = None

    # ---- called from the IPC thread -------------------------------------------------
    def bind_replies(self) -> zmq.Socket:
        """Create the IPC thread's end of the reply pair (call on the IPC thread, first)."""
        self._replies = self._zctx.socket(zmq.PAIR)
        self._replies.setsockopt(zmq.SNDHWM, 0)
        self._replies.setsockopt(zmq.RCVHWM, 0)
        self._replies.setsockopt(zmq.LINGER, 0)
        self._replies.bind(REPLIES_ENDPOINT)
        return self._replies

    def attach_front(self, router: zmq.Socket, read_requests: Callable[[zmq.Socket], None]) -> None:
        """The ROUTER the ROS thread may serve, and how requests are read from it.

        Called on the IPC thread while it holds ``front_lock`` (it is the front until
        the ROS thread claims the socket).
        """
        self._router = router
        self._read_requests = read_requests

    def submit(self, cmd: str, args: dict, identity: bytes, rid: int, deadline: float) -> bool:
        """Queue a command; False when the queue is full (the caller answers backpressure)."""
        task = Task(cmd, args, identity, rid, deadline)
        with self._lock:
            if len(self._queue) >= self.max_queue_depth:
                self.stats.queue_dropped += 1
                return False
            task._executor = self
            self._queue.append(task)
            depth = len(self._queue)
            self.stats.queue_depth = depth
            if depth > self.stats.queue_max_depth_observed:
                self.stats.queue_max_depth_observed = depth
        # Read after the append (see the module docstring): a busy thread needs no wake-up.
        if self._sleeping_on_lock:
            self._wake()
        elif self._sleeping_in_rcl:
            self._guard.trigger_guard_condition()
        return True

    def _wake(self) -> None:
        try:
            self._wakeup.release()
        except RuntimeError:
            pass  # a wake-up is already pending

    def stop(self) -> None:
        """Ask the ROS thread to finish: it drains the queue and returns.

        Takes no lock: it may run in a signal handler on the ROS thread itself.
        """
        self._stopping.set()
        self._wake()
        try:
            self._guard.trigger_guard_condition()
        except Exception:  # the context may already be gone
            pass

    @property
    def stopping(self) -> bool:
        return self._stopping.is_set()

    # ---- ROS thread -------------------------------------------------------------------
    def call_later(self, delay: float, fn: Callable[[], None]) -> Timer:
        timer = Timer(time.monotonic() + delay, fn)
        heapq.heappush(self._timers, (timer.when, next(self._seq), timer))
        return timer

    def _send(self, task: Task, message: dict) -> None:
        try:
            frame = protocol.pack(message)
        except Exception:
            log.exception("could not encode the reply to %s", task.cmd)
            frame = protocol.pack({"v": protocol.VERSION, "id": task.rid, "ok": False,
                                   "error": IpcError("internal", "reply could not be encoded").to_wire()})
        if self._front:
            if self.front_lock.acquire(blocking=False):
                try:
                    self._router.send_multipart([task.identity, frame], zmq.NOBLOCK, copy=False)
                except zmq.ZMQError:
                    pass  # the client went away (or its queue is full): nobody to answer
                finally:
                    self.front_lock.release()
                return
            self._front = False  # the IPC thread took the socket over while we worked
        self._sock.send_multipart([task.identity, frame], copy=False)

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
                log.exception("timer task failed")
            finally:
                self.stats.task_finished(started, ok)

    def _pop(self) -> Task | None:
        with self._lock:
            if not self._queue:
                return None
            task = self._queue.popleft()
            self.stats.queue_depth = len(self._queue)
            return task

    def _run_task(self, task: Task) -> None:
        started = self.stats.task_started()
        ok = True
        try:
            if started > task.deadline:
                raise IpcError("deadline-exceeded", "The request's deadline passed while it was queued",
                               {"command": task.cmd})
            handler = self.handlers.get(task.cmd)
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
            self.stats.task_finished(started, ok, task.cmd)

    def drain(self) -> None:
        while True:
            task = self._pop()
            if task is None:
                break
            self._run_task(task)

    # ---- the front ----------------------------------------------------------------------
    def _serve_front(self, timeout: float) -> None:
        """Poll the ROUTER until a request or ``timeout``; read what came (ROS thread, front)."""
        if not self.front_lock.acquire(blocking=False):
            self._front = False  # taken over during the last task; the IPC thread serves now
            return
        try:
            if self._queue or self._stopping.is_set():
                timeout = 0.0
            if self._front_poller.poll(int(timeout * 1000)):
                self._read_requests(self._router)
        finally:
            self.front_lock.release()

    def _leave_front(self) -> None:
        if self._front:
            self._front = False
            self._sock.send(TAKE)

    def _claim_front(self) -> None:
        self._sock.send(BACK)
        if self.front_lock.acquire(timeout=CLAIM_WAIT):
            self._front = True
            self.front_lock.release()
        # else: the IPC thread is slow to answer; it hands the socket back later and the
        # next round claims it again (a second "back" is harmless).

    def _settle_front(self) -> None:
        """Leave the front while cold waiters need the rcl wait set; claim it back when idle."""
        if self._router is None:
            return
        cold = bool(self.cold_entries())
        if self._front:
            if cold:
                self._leave_front()
        elif not cold and not self._queue and not self._stopping.is_set():
            self._claim_front()

    # ---- sleeping while the IPC thread is the front --------------------------------------
    def _wait(self, timeout: float) -> None:
        entries = self.cold_entries()
        # The flag goes up before the last look at the queue; submit() reads it after appending.
        if entries:
            self._sleeping_in_rcl = True
        else:
            self._sleeping_on_lock = True
        try:
            with self._lock:
                busy = bool(self._queue) or self._stopping.is_set()
            if entries:  # looked at even when busy, so that cold waiters are served under load
                self._wait_rcl(entries, 0.0 if busy else timeout)
            elif not busy:
                self._wakeup.acquire(timeout=timeout)
        finally:
            self._sleeping_on_lock = self._sleeping_in_rcl = False

    def _wait_rcl(self, entries: list, timeout: float) -> None:
        ws = _rclpy.WaitSet(len(entries), 1, 0, 0, 0, 0, self._context.handle)
        ws.clear_entities()
        ws.add_guard_condition(self._guard)
        for entry in entries:
            ws.add_subscription(entry.sub.handle)
        ws.wait(int(timeout * 1e9))
        ready = set(ws.get_ready_entities("subscription"))
        for entry in entries:
            if entry.sub is not None and entry.sub.handle.pointer in ready:
                self.on_ready(entry)

    def run(self) -> None:
        """The ROS thread's loop. Returns after :meth:`stop` once the queue is drained."""
        self.thread_ident = threading.get_ident()
        self._sock = self._zctx.socket(zmq.PAIR)
        self._sock.setsockopt(zmq.SNDHWM, 0)
        self._sock.setsockopt(zmq.RCVHWM, 0)
        self._sock.setsockopt(zmq.LINGER, 1000)
        self._sock.connect(REPLIES_ENDPOINT)
        if self._router is not None:
            self._front_poller = zmq.Poller()
            self._front_poller.register(self._router, zmq.POLLIN)
        try:
            self._settle_front()
            while not self._stopping.is_set():
                if self._front:
                    self._serve_front(self._next_timeout())
                else:
                    self._wait(self._next_timeout())
                self._run_timers()
                self.drain()
                if self.stats.degraded and not self._queue:
                    self.stats.degraded = False  # idle again: the episode is over
                self.on_idle()
                self._settle_front()
            self.drain()
        finally:
            # Shutdown replies (woken waiters, the rest of the queue) go through the IPC
            # thread, which also closes the socket.
            self._leave_front()

    def close(self) -> None:
        """Close the ROS thread's socket (call on the ROS thread after :meth:`run`)."""
        if self._sock is not None:
            self._sock.close(linger=1000)
            self._sock = None
