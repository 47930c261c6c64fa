"""SOVD operations on the ROS worker: which services and actions a node offers, and the commands
that call them (``op_list``, ``op_call``, ``op_goal``, ``op_goals``, ``op_exec``, ``op_cancel``).

Discovery (``op_list``): a node's services as the graph lists them.  Parameter
services, ``get_type_description`` and the hidden ``/_action/`` services are
not operations; an action is found through its ``<action>/_action/send_goal``
service (type ``pkg/action/Name_SendGoal``).  Each carries ``type_info``: the
JSON schemas (and default values) of the request and response, or of the goal,
result and feedback, built by ``schema.py`` as the data items' are.

Types: ``pkg/srv/Name`` and ``pkg/action/Name`` only, imported only from a
rosidl-generated package (the file system is looked at first, as
``msgtypes.load_type`` does for messages).

Restart record: the running goals (id, action, type, entity) are written to
``operations.json`` in the runtime dir by a small writer thread (never on the
ROS thread), whenever a goal starts or finishes.  A restarted worker reads it:
those goals are kept as failed, ``ros2_status: "unknown"``, with a message
(rclpy cannot re-attach to a goal it did not send, so they cannot be cancelled).
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import json
import logging
import os
import re
import threading
import time
from collections.abc import Callable
from typing import Any

from common.process import write_atomic
from ipc.errors import IpcError

from ..core.executor import RosExecutor, Task
from ..core.stats import Stats
from ..ros.msgtypes import ConversionError, _is_message_class
from ..ros.schema import default_value, schema
from .actions import ActionClients, Goal
from .services import ServiceClients

log = logging.getLogger("sovd.rosworker.operations")

STATE_FILE = "operations.json"
INTERFACE = re.compile(r"^([A-Za-z][A-Za-z0-9_]{0,100})/(srv|action)/([A-Z][A-Za-z0-9]{0,100})$")
PARAMETER_SERVICES = frozenset({"describe_parameters", "get_parameter_types", "get_parameters",
                                "list_parameters", "set_parameters", "set_parameters_atomically"})
SEND_GOAL = "/_action/send_goal"
MAX_NODES = 4096
RESTART_MESSAGE = ("The ROS worker restarted while this goal was running; the gateway cannot follow it "
                   "any more (rclpy cannot re-attach to a goal it did not send). The goal may still be "
                   "running on the action server, which was not asked to cancel it.")


def _package_has(pkg: str, kind: str) -> bool:
    """True if ``pkg`` is a rosidl-generated package with ``kind`` interfaces, WITHOUT importing it."""
    try:
        spec = importlib.util.find_spec(pkg)
    except Exception:  # noqa: BLE001 - anything odd means "not a ROS package"
        return False
    for loc in (spec.submodule_search_locations or []) if spec else []:
        if os.path.isfile(os.path.join(loc, kind, "__init__.py")) and any(
                f.startswith(f"{pkg}_s__rosidl_typesupport_c") for f in os.listdir(loc)):
            return True
    return False


@functools.lru_cache(maxsize=512)
def _load(name: str, kind: str) -> type:
    match = INTERFACE.fullmatch(name)
    if match is None or match.group(2) != kind:
        example = "std_srvs/srv/Trigger" if kind == "srv" else "test_msgs/action/Fibonacci"
        raise ConversionError("invalid-type", f"Invalid {'service' if kind == 'srv' else 'action'} type "
                                              f"{name[:80]!r}: expected 'package/{kind}/Name', e.g. '{example}'")
    pkg, _, cls_name = match.groups()
    missing = ConversionError("type-not-installed", f"Type '{name}' is not installed on the gateway")
    if not _package_has(pkg, kind):
        raise missing
    try:
        cls = getattr(importlib.import_module(f"{pkg}.{kind}"), cls_name, None)
    except Exception:  # noqa: BLE001 - a broken package is as good as a missing one
        raise missing from None
    parts = ("Request", "Response") if kind == "srv" else ("Goal", "Result", "Feedback")
    if cls is None or not all(_is_message_class(getattr(cls, p, None)) for p in parts):
        raise missing
    return cls


def load_interface(name: Any, kind: str) -> type:
    """The service (``kind`` "srv") or action class of ``name``; raises IpcError (400) on trouble."""
    if not isinstance(name, str):
        raise IpcError("type-introspection-failed", "type: expected a string")
    try:
        return _load(name, kind)
    except ConversionError as exc:
        raise IpcError("type-introspection-failed", exc.message, {"type": name[:300]}) from None


@functools.lru_cache(maxsize=512)
def _type_info(name: str, kind: str) -> str:
    cls = load_interface(name, kind)
    parts = ("request", "response") if kind == "srv" else ("goal", "result", "feedback")
    info: dict[str, Any] = {p: schema(getattr(cls, p.capitalize())) for p in parts}
    info["default_value"] = {p: default_value(getattr(cls, p.capitalize())) for p in parts}
    return json.dumps(info)


def type_info(name: str, kind: str) -> dict[str, Any] | None:
    """The schemas and default values of a service or action type, or None when it cannot be loaded."""
    try:
        return json.loads(_type_info(name, kind))
    except IpcError:
        return None


def node_operations(services: list[tuple[str, list[str]]]) -> list[dict[str, Any]]:
    """A node's operations from its ``(service name, types)`` list, services first, then actions."""
    out_services, out_actions = [], []
    for path, types in sorted(services):
        if not types:
            continue
        type_name = types[0]
        short = path.rsplit("/", 1)[-1]
        if path.endswith(SEND_GOAL) and type_name.endswith("_SendGoal") and "/action/" in type_name:
            action_path = path[:-len(SEND_GOAL)]
            if action_path:
                out_actions.append({"kind": "action", "path": action_path,
                                    "name": action_path.rsplit("/", 1)[-1],
                                    "type": type_name[:-len("_SendGoal")]})
            continue
        if "/_action/" in path or short == "get_type_description" or \
                (short in PARAMETER_SERVICES and type_name.startswith("rcl_interfaces/srv/")):
            continue
        out_services.append({"kind": "service", "path": path, "name": short, "type": type_name})
    return out_services + out_actions


class _Saver(threading.Thread):
    """Writes the running goals to ``operations.json`` (latest wins), off the ROS thread.

    ``then`` (a goal's 202) is handed to ``post`` (the executor's: it runs on the ROS thread)
    once the text submitted with it, or a later one, is on disk: a goal a client was told about
    is in the record, so a ROS worker killed right after still knows it.
    """

    def __init__(self, path: str, post: Callable[[Callable[[], None]], None]):
        super().__init__(name="operations-state", daemon=True)
        self.path = path
        self.post = post
        self._lock = threading.Lock()
        self._pending: str | None = None
        self._then: list[Callable[[], None]] = []
        self._wake = threading.Event()
        self._closing = False

    def submit(self, text: str, then: Callable[[], None] | None = None) -> None:
        with self._lock:
            self._pending = text
            if then is not None:
                self._then.append(then)
        self._wake.set()

    def run(self) -> None:
        while True:
            self._wake.wait()
            self._wake.clear()
            with self._lock:
                text, self._pending = self._pending, None
                then, self._then = self._then, []
            if text is not None:
                self._write(text)
            for fn in then:
                self.post(fn)
            if self._closing:
                return

    def _write(self, text: str) -> None:
        try:
            write_atomic(self.path, text.encode())  # 0600, as every file of the runtime dir
        except OSError as exc:
            log.warning("could not write %s: %s", self.path, exc)

    def close(self, wait: float) -> None:
        self._closing = True
        self._wake.set()
        self.join(wait)


def load_restart(runtime_dir: str) -> list[Goal]:
    """The goals a previous ROS worker had running, as failed ``unknown`` goals."""
    path = os.path.join(runtime_dir, STATE_FILE)
    try:
        with open(path) as fh:
            records = json.load(fh)
    except FileNotFoundError:
        return []
    except (OSError, ValueError) as exc:
        log.warning("ignoring %s: %s", path, exc)
        return []
    goals = []
    for record in records if isinstance(records, list) else []:
        try:
            goal = Goal(bytes.fromhex(record["id"]), str(record["action"]), str(record["type"]),
                        str(record.get("entity_id", "")))
            goal.created = float(record.get("created", time.time()))
        except (KeyError, TypeError, ValueError):
            continue
        message = record.get("message")
        goal.finish("unknown", message if isinstance(message, str) and message else RESTART_MESSAGE)
        goals.append(goal)
    return goals[:MAX_NODES]


def _str(args: dict, name: str, limit: int = 1024) -> str:
    value = args.get(name)
    if not isinstance(value, str) or not value or len(value) > limit:
        raise IpcError("bad-request", f"{name}: expected a string of 1 to {limit} characters")
    return value


class Operations:
    """The operation commands (``handlers``, given to the executor by ``main.py``)."""

    def __init__(self, node, executor: RosExecutor, stats: Stats, *, max_clients: int, idle: float,
                 call_timeout: float, max_goals: int, retention: float, restore: bool = True):
        self.node = node
        self.executor = executor
        self.call_timeout = call_timeout
        self.services = ServiceClients(node, executor, stats, max_clients, idle)
        self.actions = ActionClients(node, executor, stats, max_clients, idle, max_goals, retention)
        if restore:  # a worker that died: what its running goals became (a clean start knows none)
            self.actions.restore(load_restart(executor.runtime_dir))
        self._saver = _Saver(os.path.join(executor.runtime_dir, STATE_FILE), executor.post)
        self._saver.start()
        self.actions.on_change = self.save
        self.save()
        self.handlers = {"op_list": self.op_list, "op_call": self.op_call, "op_goal": self.op_goal,
                         "op_goals": self.op_goals, "op_exec": self.op_exec, "op_cancel": self.op_cancel}

    def save(self, then: Callable[[], None] | None = None) -> None:
        # Running goals, and those already known as lost (a previous restart): both read
        # "unknown" after the next one.
        records = [{"id": g.id, "action": g.path, "type": g.type_name, "entity_id": g.entity_id,
                    "created": g.created, "message": g.message if g.done else None}
                   for g in self.actions.goals.values() if not g.done or g.ros2_status == "unknown"]
        self._saver.submit(json.dumps(records), then)

    def _timeout(self, task: Task) -> float:
        # The HTTP side waits call_timeout plus a margin; answer before it gives up.
        return max(0.05, min(self.call_timeout, task.deadline - time.monotonic() - 0.2))

    def op_list(self, task: Task) -> None:
        nodes = task.args.get("nodes")
        if not isinstance(nodes, list) or len(nodes) > MAX_NODES or not all(isinstance(n, str) for n in nodes):
            raise IpcError("bad-request", "nodes: expected a list of node names")
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
        path, type_name = _str(task.args, "service"), _str(task.args, "type", 300)
        srv = load_interface(type_name, "srv")
        data = task.args.get("parameters", {})
        self.services.call(task, path, type_name, srv, data, self._timeout(task))

    def op_goal(self, task: Task) -> None:
        path, type_name = _str(task.args, "action"), _str(task.args, "type", 300)
        action = load_interface(type_name, "action")
        entity = task.args.get("entity_id")
        self.actions.send_goal(task, path, type_name, action, task.args.get("parameters", {}),
                               self._timeout(task), entity if isinstance(entity, str) else "")

    def op_goals(self, task: Task) -> None:
        task.reply({"items": self.actions.listing(_str(task.args, "action"))})

    def op_exec(self, task: Task) -> None:
        task.reply(self.actions.get(_str(task.args, "id", 64)).wire())

    def op_cancel(self, task: Task) -> None:
        self.actions.cancel(task, _str(task.args, "id", 64), self._timeout(task))

    def repeat(self, seconds: float) -> None:
        """Every ``seconds``: drop clients whose server left, idle clients and expired goals."""
        def tick() -> None:
            self.executor.call_later(seconds, tick)
            self.services.check_graph()
            self.services.sweep_idle()
            self.actions.sweep()
        self.executor.call_later(seconds, tick)

    def shutdown(self) -> None:
        self.services.shutdown()
        self.actions.shutdown()   # the running goals stay in operations.json for the next worker
        self._saver.close(1.0)
