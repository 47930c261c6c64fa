"""The operation commands: ``op_list``, ``op_call``, ``op_goal``, ``op_goals``, ``op_exec``, ``op_cancel``.

SOVD operations on the ROS worker: the services and actions a node offers
(``interfaces.py``), called through pooled service clients (``services.py``)
and action clients (``actions.py``); the running goals are kept in the restart
record (``goals.py``).  The HTTP side has checked what a client sent; these
guard the wire (``core/args.py``).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from ..core import args
from ..core.executor import RosExecutor
from ..core.stats import Stats
from ..core.task import Task
from .actions import ActionClients
from .goals import GoalRecord, load_restart
from .interfaces import load_interface, node_operations, type_info
from .services import ServiceClients

MAX_NODES = 4096


class Operations:
    """The operation commands (``handlers``) and the clients they call."""

    def __init__(self, node, executor: RosExecutor, stats: Stats, *, max_clients: int, idle: float,
                 call_timeout: float, max_goals: int, retention: float, restore: bool = True):
        self.node = node
        self.executor = executor
        self.call_timeout = call_timeout
        self.services = ServiceClients(node, executor, stats, max_clients, idle)
        self.actions = ActionClients(node, executor, stats, max_clients, idle, max_goals, retention)
        if restore:  # a worker that died: what its running goals became (a clean start knows none)
            self.actions.restore(load_restart(executor.runtime_dir))
        self._record = GoalRecord(executor.runtime_dir, executor.post)
        self.actions.on_change = self.save
        self.save()
        self.handlers = {"op_list": self.op_list, "op_call": self.op_call, "op_goal": self.op_goal,
                         "op_goals": self.op_goals, "op_exec": self.op_exec, "op_cancel": self.op_cancel}

    def save(self, then: Callable[[], None] | None = None) -> None:
        self._record.save(list(self.actions.goals.values()), then)

    def _timeout(self, task: Task) -> float:
        # The HTTP side waits call_timeout plus a margin; answer before it gives up.
        return max(0.05, min(self.call_timeout, task.deadline - time.monotonic() - 0.2))

    def op_list(self, task: Task) -> None:
        nodes = args.strings(task.args, "nodes", MAX_NODES, "a list of node names")
        with_info = task.args.get("type_info", True) is not False
        out: dict[str, list] = {}
        for fqn in nodes:
            namespace, _, name = fqn.rpartition("/")
            try:
                services = self.node.get_service_names_and_types_by_node(name, namespace or "/")
            except Exception:  # noqa: BLE001 - the node left, or is half discovered
                services = []
            ops = node_operations(services)
            for op in ops if with_info else ():
                op["type_info"] = type_info(op["type"], "srv" if op["kind"] == "service" else "action")
            out[fqn] = ops
        task.reply({"nodes": out})

    def op_call(self, task: Task) -> None:
        path, type_name = args.string(task.args, "service", limit=1024), args.string(task.args, "type", limit=300)
        srv = load_interface(type_name, "srv")
        data = task.args.get("parameters", {})
        self.services.call(task, path, type_name, srv, data, self._timeout(task))

    def op_goal(self, task: Task) -> None:
        path, type_name = args.string(task.args, "action", limit=1024), args.string(task.args, "type", limit=300)
        action = load_interface(type_name, "action")
        entity = task.args.get("entity_id")
        self.actions.send_goal(task, path, type_name, action, task.args.get("parameters", {}),
                               self._timeout(task), entity if isinstance(entity, str) else "")

    def op_goals(self, task: Task) -> None:
        task.reply({"items": self.actions.listing(args.string(task.args, "action", limit=1024))})

    def op_exec(self, task: Task) -> None:
        task.reply(self.actions.get(args.string(task.args, "id", limit=64)).wire())

    def op_cancel(self, task: Task) -> None:
        self.actions.cancel(task, args.string(task.args, "id", limit=64), self._timeout(task))

    def check(self) -> None:
        """Drop clients whose server left, idle clients and expired goals (every ``CHECK_EVERY``)."""
        self.services.check_graph()
        self.services.sweep_idle()
        self.actions.sweep()

    def shutdown(self) -> None:
        self.services.shutdown()
        self.actions.shutdown()   # the running goals stay in operations.json for the next worker
        self._record.close(1.0)
