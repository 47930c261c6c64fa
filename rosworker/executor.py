"""The single ROS thread: every rclpy call of the gateway runs here.

Work reaches the thread as :class:`Task` objects that the IPC thread
appends to a bounded deque (:meth:`RosExecutor.submit`, the only method
called from another thread).  The ROS thread sleeps in one of two ways:

- nobody waits on a cold topic: in ``zmq.poll`` on an inproc socket the IPC
  thread pokes for each task (cheap, and a pooled topic costs nothing);
- somebody waits on a cold topic: in an rcl wait set holding those
  subscriptions and a guard condition the IPC thread triggers for each task,
  so the first message and new work both wake it at once.

Timers (graph polling, idle sweep, cold-wait deadlines) run on the same
thread from a heap.  Replies go back to the IPC thread over the inproc socket.
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

from .stats import Stats

log = logging.getLogger("sovd.rosworker.executor")

TASKS_ENDPOINT = "inproc://rosworker-tasks"
IDLE_WAIT_CAP = 1.0  # seconds: the loop wakes at least this often


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
        self._sock: zmq.Socket | None = None       # ROS thread's end of the inproc pair
        self._poke: zmq.Socket | None = None       # IPC thread's end
        self.handlers: dict[str, Callable[[Task], None]] = {}
        # Set by the pool: subscriptions that callers wait on, and what to do when one is ready.
        self.cold_entries: Callable[[], list] = lambda: []
        self.on_ready: Callable[[Any], None] = lambda entry: None
        self.on_idle: Callable[[], None] = lambda: None
        self.thread_ident: int | None = None

    # ---- called from the IPC thread -------------------------------------------------
    def bind_poke(self) -> zmq.Socket:
        """Create the IPC thread's end of the inproc pair (call on the IPC thread, first)."""
        self._poke = self._zctx.socket(zmq.PAIR)
        self._poke.setsockopt(zmq.SNDHWM, 0)
        self._poke.setsockopt(zmq.RCVHWM, 0)
        self._poke.setsockopt(zmq.LINGER, 0)
        self._poke.bind(TASKS_ENDPOINT)
        return self._poke

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
        self._poke.send(b"", zmq.NOBLOCK)
        self._guard.trigger_guard_condition()
        return True

    def stop(self) -> None:
        """Ask the ROS thread to finish: it drains the queue and returns."""
        self._stopping.set()
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
            self.stats.task_finished(started, ok)

    def drain(self) -> None:
        while True:
            task = self._pop()
            if task is None:
                break
            self._run_task(task)

    def _wait(self, timeout: float) -> None:
        entries = self.cold_entries()
        if not entries:
            if self._sock.poll(int(timeout * 1000)):
                while True:  # consume the pokes; the deque holds the tasks
                    try:
                        self._sock.recv(zmq.NOBLOCK)
                    except zmq.Again:
                        break
            return
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
        self._sock.connect(TASKS_ENDPOINT)
        try:
            while not self._stopping.is_set():
                self._wait(self._next_timeout())
                self._run_timers()
                self.drain()
                if self.stats.degraded and not self._queue:
                    self.stats.degraded = False  # idle again: the episode is over
                self.on_idle()
            self.drain()
        finally:
            pass

    def close(self) -> None:
        """Close the ROS thread's socket (call on the ROS thread after :meth:`run`)."""
        if self._sock is not None:
            self._sock.close(linger=1000)
            self._sock = None
