"""Pooled ROS 2 action clients and the goals they sent (ROS thread only).

One ``rclpy.action.ActionClient`` per action path, made on the first goal,
kept in LRU order with the service clients' cap, dropped after ``idle``
seconds without goals, or when the path is used with another type.  rclpy's
futures are never used: goals, cancels and result requests go out on the
client's rcl handle (``send_goal_request`` ...), and :meth:`ActionClients.poll`
(an executor poller) takes goal, cancel and result responses, feedback and
status from it when a client with something open has one ready (the waiter wakes
the ROS thread), at the requests' deadlines, and every ``SERVER_CHECK`` s while
goals run.

Goals: each accepted goal is a :class:`Goal` keyed by its UUID as 32 hex
digits (medkit's execution id).  Its status follows the action's status
topic and its result request; the latest feedback and the result are kept.
At most ``max_goals`` per action are kept (the oldest finished one is dropped
first; when none has finished a new goal is refused), and a finished goal is
dropped ``retention`` seconds after it finished.

Cancel: medkit's issue-576 rule.  When the cancel answer does not come in
time but the status already shows the goal cancelling (or cancelled), the
cancel counts as accepted; otherwise the outcome is unknown (``not-responding``).

Restart: :attr:`ActionClients.on_change` is called (ROS thread) after a goal
starts or finishes; ``rosworker/operations/commands.py`` saves the running goals off
this thread so that a restarted worker can say what became of them.
"""

from __future__ import annotations

import collections
import functools
import logging
import time
import uuid
from collections.abc import Callable, Iterator
from typing import Any

from ipc.errors import IpcError

from ..core.executor import RosExecutor
from ..core.stats import Stats
from ..core.task import Task
from ..ros.decode import from_plain
from ..ros.encode import to_plain
from ..ros.msgtypes import ConversionError
from . import lru

log = logging.getLogger("sovd.rosworker.actions")

# A new client whose server shows up waits this long more before its first request: the server's
# reply writer may not have matched the client's reader yet (rclpy only tells about the request
# side), and a reply sent before that is lost.
SETTLE = 0.25
# Goal requests one client has out at once; more wait in line.  A server's request reader keeps
# the services' default history (10): a burst beyond it is dropped at the server, unanswered.
MAX_IN_FLIGHT = 8
MATCH_WAIT = 1.0      # seconds a goal waits for a new client to match its server before it is 503
SERVER_GONE = 2.0     # seconds a running goal's server may be missing before the goal is failed
SERVER_CHECK = 0.5    # seconds between looks at the server of running goals
MATCH_POLL = 0.002    # seconds between looks at a new client's match while a goal waits for it
# action_msgs/msg/GoalStatus codes -> medkit's ros2_status words
ROS_STATUS = {0: "unknown", 1: "accepted", 2: "executing", 3: "canceling", 4: "succeeded", 5: "canceled",
              6: "aborted"}
TERMINAL = frozenset({"succeeded", "canceled", "aborted", "unknown-final"})
SOVD_STATUS = {"accepted": "running", "executing": "running", "canceling": "running",
               "succeeded": "completed", "canceled": "failed", "aborted": "failed"}


def answers(pending: dict[int, Any], take: Callable[[], tuple[int | None, Any]]) -> Iterator[tuple[Any, Any]]:
    """``(what was kept for the request, its response)`` for each answer ``take()`` has for a request in
    ``pending`` (by sequence number; popped), until none is left.  An answer to a request no longer
    pending (timed out) is dropped: every answer that came is taken, so the waiter does not wake for it
    again."""
    while True:
        seq, response = take()
        if seq is None:
            return
        kept = pending.pop(seq, None)
        if kept is not None:
            yield kept, response


class Goal:
    __slots__ = ("id", "uuid", "path", "type_name", "ros2_status", "feedback", "result", "message",
                 "finished", "created", "server_missing_since", "entity_id")

    def __init__(self, goal_uuid: bytes, path: str, type_name: str, entity_id: str = ""):
        self.id = goal_uuid.hex()
        self.uuid = goal_uuid
        self.path = path
        self.type_name = type_name
        self.ros2_status = "accepted"
        self.feedback: dict | None = None
        self.result: dict | None = None
        self.message: str | None = None
        self.finished: float | None = None   # monotonic, once terminal
        self.created = time.time()
        self.server_missing_since: float | None = None
        self.entity_id = entity_id

    @property
    def done(self) -> bool:
        return self.finished is not None

    def finish(self, ros2_status: str, message: str | None = None) -> None:
        if self.finished is None:
            self.ros2_status = ros2_status
            self.finished = time.monotonic()
            if message:
                self.message = message

    def wire(self) -> dict[str, Any]:
        status = SOVD_STATUS.get(self.ros2_status, "failed" if self.done else "running")
        out: dict[str, Any] = {"id": self.id, "status": status, "ros2_status": self.ros2_status,
                               "action": self.path, "type": self.type_name, "created": self.created}
        if self.result is not None:
            out["result"] = self.result
        if self.feedback is not None:
            out["feedback"] = self.feedback
        if self.message:
            out["message"] = self.message
        return out


class Pooled:
    __slots__ = ("path", "type_name", "action", "client", "last_used", "ready_since", "goals", "sends", "cancels",
                 "results", "waiting")

    def __init__(self, path: str, type_name: str, action: type, client):
        self.path = path
        self.type_name = type_name
        self.action = action
        self.client = client
        self.last_used = time.monotonic()
        self.ready_since: float | None = None   # when the server was first seen matched
        self.goals: collections.OrderedDict[str, Goal] = collections.OrderedDict()
        self.sends: dict[int, tuple[Task, Goal, float]] = {}
        self.cancels: dict[int, tuple[Task, Goal, float]] = {}
        self.results: dict[int, Goal] = {}
        self.waiting: list[tuple[Task, Any, Goal, float, float]] = []

    def ready(self, now: float) -> bool:
        """The server is there and the client has been matched to it for SETTLE seconds."""
        if self.ready_since is None:
            if not self.client.server_is_ready():
                return False
            self.ready_since = now
        return now - self.ready_since >= SETTLE

    @property
    def handle(self):
        return self.client._client_handle

    @property
    def busy(self) -> bool:
        return bool(self.sends or self.cancels or self.waiting or any(not g.done for g in self.goals.values()))


class ActionClients:
    def __init__(self, node, executor: RosExecutor, stats: Stats, max_clients: int, idle: float,
                 max_goals: int, retention: float):
        self.node = node
        self.executor = executor
        self.stats = stats
        self.max_clients = max_clients
        self.idle = idle
        self.max_goals = max_goals
        self.retention = retention
        self.entries: collections.OrderedDict[str, Pooled] = collections.OrderedDict()
        self.goals: dict[str, Goal] = {}       # every kept goal, by id (restored ones too)
        self.open = 0                          # sends, cancels and goals not finished
        self.polled = 0.0                      # when poll() last ran: what due() counts from
        # Called after a goal starts or finishes (ROS thread) with what to run once that is saved.
        self.on_change: Callable[[Callable[[], None] | None], None] = lambda then=None: then and then()
        executor.add_poller("action clients", self.waitables, self.poll, self.due)

    # ---- clients --------------------------------------------------------------------------
    def _client(self, path: str, type_name: str, action: type) -> Pooled:
        from rclpy.action import ActionClient

        pooled = lru.reuse(self.entries, path, type_name)
        if pooled is not None:
            return pooled
        pooled = self.entries.get(path)
        if pooled is not None:
            if pooled.busy:
                raise IpcError("action-unavailable", f"{path} has goals of type {pooled.type_name} running; "
                                                     f"a {type_name} goal cannot be sent until they finish",
                               {"action": path})
            self._destroy(path)
        try:
            client = ActionClient(self.node, action, path)
        except Exception as exc:
            raise IpcError("action-unavailable", f"Could not create a client for {path}: {exc}",
                           {"action": path}) from None
        lru.make_room(self.entries, self.max_clients, lambda e: e.busy, self._destroy)
        pooled = self.entries[path] = Pooled(path, type_name, action, client)
        self._count()
        return pooled

    def _destroy(self, path: str) -> None:
        pooled = self.entries.pop(path)
        for goal in pooled.goals.values():
            goal.finish("unknown", "The gateway dropped its client of the action before the goal finished")
        self._count()
        try:
            self.node.destroy_action_client(pooled.client)
        except Exception:
            log.exception("destroying the action client of %s failed", path)

    def _count(self) -> None:
        self.stats.operation_action_clients = len(self.entries)
        self.stats.operation_goals_tracked = len(self.goals)
        open_ = 0
        for p in self.entries.values():
            open_ += len(p.sends) + len(p.cancels) + len(p.waiting) + sum(not g.done for g in p.goals.values())
        self.open = open_

    # ---- goals ----------------------------------------------------------------------------
    def send_goal(self, task: Task, path: str, type_name: str, action: type, data: Any, timeout: float,
                  entity_id: str = "") -> None:
        try:
            goal_msg = from_plain(action.Goal, data, path="parameters")
        except ConversionError as exc:
            raise IpcError("invalid-operation-data", exc.message, {"action": path}) from None
        pooled = self._client(path, type_name, action)
        self._make_room(pooled)
        request = action.Impl.SendGoalService.Request()
        goal_uuid = uuid.uuid4().bytes
        request.goal_id.uuid = list(goal_uuid)
        request.goal = goal_msg
        goal = Goal(goal_uuid, path, type_name, entity_id)
        now = time.monotonic()
        pooled.last_used = now
        if pooled.ready(now) and not pooled.waiting and len(pooled.sends) < MAX_IN_FLIGHT:
            self._send_goal(pooled, task, request, goal, now + timeout)
        else:
            pooled.waiting.append((task, request, goal, now + timeout, now + min(MATCH_WAIT, timeout)))
        self._count()

    def _make_room(self, pooled: Pooled) -> None:
        pending = len(pooled.sends) + len(pooled.waiting)
        while len(pooled.goals) + pending >= self.max_goals:
            oldest = next((g for g in pooled.goals.values() if g.done), None)
            if oldest is None:
                raise IpcError("goals-full", f"{pooled.path} has {self.max_goals} goals running "
                                             "(max_goals_per_action); retry when one has finished",
                               {"action": pooled.path, "max_goals_per_action": self.max_goals})
            self._forget(pooled, oldest)

    def _forget(self, pooled: Pooled | None, goal: Goal) -> None:
        if pooled is not None:
            pooled.goals.pop(goal.id, None)
        self.goals.pop(goal.id, None)

    def _send_goal(self, pooled: Pooled, task: Task, request: Any, goal: Goal, deadline: float) -> None:
        try:
            seq = pooled.handle.send_goal_request(request)
        except Exception as exc:  # noqa: BLE001 - rcl refused it
            task.fail(IpcError("action-unavailable", f"Sending the goal to {pooled.path} failed: {exc}",
                               {"action": pooled.path}))
            return
        pooled.sends[seq] = (task, goal, deadline)
        self.stats.operation_goals_total += 1

    def cancel(self, task: Task, goal_id: str, timeout: float) -> None:
        goal = self.get(goal_id)
        pooled = self.entries.get(goal.path)
        if goal.done or pooled is None or pooled.goals.get(goal.id) is not goal:
            if goal.ros2_status == "unknown":
                raise IpcError("action-unavailable", "The goal cannot be cancelled through the gateway any "
                                                     f"more: {goal.message or 'its client is gone'}",
                               {"action": goal.path, "return_code": 3})
            raise IpcError("action-rejected", "Execution already terminated",
                           {"action": goal.path, "return_code": 3})
        if not pooled.client.server_is_ready():
            raise IpcError("action-unavailable", f"The action server of {goal.path} is not available",
                           {"action": goal.path})
        request = pooled.action.Impl.CancelGoalService.Request()
        request.goal_info.goal_id.uuid = list(goal.uuid)
        try:
            seq = pooled.handle.send_cancel_request(request)
        except Exception as exc:  # noqa: BLE001
            raise IpcError("action-unavailable", f"Sending the cancel request to {goal.path} failed: {exc}",
                           {"action": goal.path}) from None
        pooled.cancels[seq] = (task, goal, time.monotonic() + timeout)
        self._count()

    def get(self, goal_id: str) -> Goal:
        goal = self.goals.get(goal_id)
        if goal is None:
            raise IpcError("no-such-execution", "Execution not found", {"execution_id": goal_id[:64]})
        return goal

    def listing(self, path: str) -> list[dict[str, Any]]:
        """The goals of ``path``, newest first."""
        goals = [g for g in self.goals.values() if g.path == path]
        goals.sort(key=lambda g: g.created, reverse=True)
        return [g.wire() for g in goals]

    def restore(self, goals: list[Goal]) -> None:
        """Goals a previous ROS worker had running (already finished as "unknown")."""
        for goal in goals:
            self.goals[goal.id] = goal
        self._count()

    # ---- the poller -----------------------------------------------------------------------
    def waitables(self) -> list:
        """The clients with requests, results or goals open (their responses, feedback and status wake
        the ROS thread)."""
        if not self.open:
            return []
        return [p.client for p in self.entries.values() if p.busy or p.results]

    def due(self) -> float | None:
        """When :meth:`poll` must run without an event: a request's deadline; soon while a goal waits
        for its client to match; every ``SERVER_CHECK`` s while goals run (is their server still there?)."""
        if not self.open:
            return None
        due = None
        for pooled in self.entries.values():
            if pooled.waiting:
                return self.polled + MATCH_POLL
            for _task, _goal, deadline in (*pooled.sends.values(), *pooled.cancels.values()):
                if due is None or deadline < due:
                    due = deadline
            if any(not g.done for g in pooled.goals.values()):
                check = self.polled + SERVER_CHECK
                due = min(due, check) if due is not None else check
        return due

    def poll(self) -> None:
        now = self.polled = time.monotonic()
        changed = False
        for pooled in list(self.entries.values()):
            changed |= self._poll_one(pooled, now)
        self._count()
        if changed:
            self.on_change()

    def _poll_one(self, pooled: Pooled, now: float) -> bool:
        changed = False
        impl = pooled.action.Impl
        handle = pooled.handle
        if pooled.waiting:
            ready = pooled.ready(now)
            still = []
            for task, request, goal, deadline, ready_by in pooled.waiting:
                if ready and len(pooled.sends) < MAX_IN_FLIGHT and now < deadline:
                    self._send_goal(pooled, task, request, goal, deadline)
                elif now >= deadline:
                    self.stats.operation_timeouts += 1
                    task.fail(IpcError("not-responding", f"The goal for {pooled.path} waited in line for the "
                                                         "whole service call timeout; it was not sent",
                                       {"action": pooled.path}))
                elif now >= ready_by and pooled.ready_since is None:
                    task.fail(IpcError("action-unavailable", f"No server of {pooled.path} is available",
                                       {"action": pooled.path}))
                else:
                    still.append((task, request, goal, deadline, ready_by))
            pooled.waiting = still
        for (task, goal, _), response in answers(
                pooled.sends, lambda: handle.take_goal_response(impl.SendGoalService.Response)):
            if response.accepted:
                pooled.goals[goal.id] = goal
                self.goals[goal.id] = goal
                request = impl.GetResultService.Request()
                request.goal_id.uuid = list(goal.uuid)
                pooled.results[handle.send_result_request(request)] = goal
                # Answered once the goal is in the restart record (operations.py).
                self.on_change(functools.partial(task.reply, {"id": goal.id, "status": "running"}))
            else:
                self.stats.operation_goals_rejected += 1
                task.fail(IpcError("action-rejected", "Goal rejected",
                                   {"action": pooled.path, "details": "The action server rejected the goal"}))
        for (task, goal, _), response in answers(
                pooled.cancels, lambda: handle.take_cancel_response(impl.CancelGoalService.Response)):
            code = int(response.return_code)
            if code == 0:
                if goal.ros2_status in ("accepted", "executing"):
                    goal.ros2_status = "canceling"
                task.reply({"id": goal.id, "status": "running" if not goal.done else
                            SOVD_STATUS.get(goal.ros2_status, "failed")})
            else:
                message = {1: "Cancel request rejected", 2: "Unknown execution ID",
                           3: "Execution already terminated"}.get(code, f"Cancel refused (return code {code})")
                task.fail(IpcError("action-rejected", message, {"action": pooled.path, "return_code": code}))
        # Feedback and status are taken even with no goal of ours yet: what is ready is taken, or the
        # waiter wakes the ROS thread again at once.
        while True:
            feedback = handle.take_feedback(impl.FeedbackMessage)
            if feedback is None:
                break
            goal = pooled.goals.get(bytes(feedback.goal_id.uuid).hex())
            if goal is not None and not goal.done:
                goal.feedback = to_plain(feedback.feedback)
        while True:
            status = handle.take_status(impl.GoalStatusMessage)
            if status is None:
                break
            for item in status.status_list:
                goal = pooled.goals.get(bytes(item.goal_info.goal_id.uuid).hex())
                word = ROS_STATUS.get(int(item.status), "unknown")
                if goal is not None and not goal.done and word in ("accepted", "executing", "canceling"):
                    goal.ros2_status = word
        for goal, response in answers(
                pooled.results, lambda: handle.take_result_response(impl.GetResultService.Response)):
            goal.result = to_plain(response.result)
            goal.finish(ROS_STATUS.get(int(response.status), "unknown"),
                        None if int(response.status) in (4, 5, 6) else "The action server answered the result "
                                                                       "request without a final status")
            changed = True
        for seq, (task, _goal, deadline) in list(pooled.sends.items()):
            if now >= deadline:
                del pooled.sends[seq]
                self.stats.operation_timeouts += 1
                task.fail(IpcError("not-responding", f"The action server of {pooled.path} did not answer the "
                                                     "goal request in time; the goal may or may not have been "
                                                     "accepted", {"action": pooled.path}))
        for seq, (task, goal, deadline) in list(pooled.cancels.items()):
            if now >= deadline:
                del pooled.cancels[seq]
                self.stats.operation_timeouts += 1
                if goal.ros2_status in ("canceling", "canceled"):   # medkit's issue 576
                    task.reply({"id": goal.id, "status": SOVD_STATUS.get(goal.ros2_status, "running")})
                else:
                    task.fail(IpcError("not-responding", "outcome unknown: the action server did not answer in "
                                                         "time. Poll the execution status resource and read "
                                                         "x-medkit.ros2_status to learn the goal's outcome.",
                                       {"action": pooled.path}))
        running = [g for g in pooled.goals.values() if not g.done]
        if running:
            available = pooled.client.server_is_ready()
            for goal in running:
                if available:
                    goal.server_missing_since = None
                elif goal.server_missing_since is None:
                    goal.server_missing_since = now
                elif now - goal.server_missing_since >= SERVER_GONE:
                    goal.finish("unknown", "The action server left the ROS graph before the goal finished")
                    pooled.results = {s: g for s, g in pooled.results.items() if g is not goal}
                    changed = True
        return changed

    # ---- upkeep ---------------------------------------------------------------------------
    def sweep(self) -> None:
        """Drop finished goals past ``retention``, and clients idle for ``idle`` seconds."""
        now = time.monotonic()
        for goal in [g for g in self.goals.values() if g.done and now - g.finished >= self.retention]:
            self._forget(self.entries.get(goal.path), goal)
        if self.idle:
            for path in [p for p, e in self.entries.items() if not e.busy and now - e.last_used >= self.idle]:
                self._destroy(path)
        self._count()

    def running(self) -> list[Goal]:
        return [g for g in self.goals.values() if not g.done]

    def shutdown(self) -> None:
        for pooled in self.entries.values():
            for task, *_ in [*pooled.sends.values(), *pooled.cancels.values(), *pooled.waiting]:
                task.fail(IpcError("shutdown", "The gateway shut down before the action server answered"))
            pooled.sends.clear()
            pooled.cancels.clear()
            pooled.waiting.clear()
        for path in list(self.entries):
            pooled = self.entries.pop(path)
            try:
                self.node.destroy_action_client(pooled.client)
            except Exception:
                log.exception("destroying the action client of %s failed", path)
        self._count()
