"""The ``param_*`` commands (``ipc/PROTOCOL.md`` "Configurations") and what each does on a node.

One command is one *operation* per node, written as a generator that yields
``(service, request)`` (or a list of them, sent at once) and is sent each
response; :class:`~rosworker.configurations.clients.ParameterClients` drives it
(its deadlines, the line for a client set of ``pool.py``).  The operations of a
multi-node command (a listing, a reset of everything) start at once and the
command is answered when the last one ends.

Defaults: ROS 2 has no "default" service.  The first time an operation reaches a
node, its parameters are read and kept as that node's record (``defaults.py``,
keyed by the node's start); reset sets the recorded value back.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from typing import Any

from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters

from ipc.errors import IpcError

from ..core import args
from ..core.task import Task
from .clients import Operation, ParameterClients, Step
from .defaults import Defaults, Record
from .values import descriptor_json, refused, same_value, to_value, type_name, value_json

T = ParameterType
MAX_NODES_PER_COMMAND = 256  # nodes one listing or reset may name
ANSWER_MARGIN = 0.25         # seconds before the request's deadline by which every operation has ended


def _fqns(a: dict) -> list[str]:
    nodes = a.get("nodes")
    if not isinstance(nodes, list) or len(nodes) > MAX_NODES_PER_COMMAND:
        raise IpcError("bad-request", f"nodes: expected a list of at most {MAX_NODES_PER_COMMAND} node names")
    return list(dict.fromkeys(args.node({"node": n}) for n in nodes))


def _name(a: dict) -> str:
    return args.string(a, "name", limit=512)


def _outcome(result: Any, key: str) -> dict[str, Any]:
    if isinstance(result, IpcError):
        return {"ok": False, "error": result.to_wire()}
    return {"ok": True, key: result}


def _limit(task: Task) -> float:
    """When a command's operations end at the latest: before the HTTP side stops waiting for the answer."""
    return task.deadline - ANSWER_MARGIN


def _answer(task: Task) -> Callable[[Any], None]:
    def done(result: Any) -> None:
        if isinstance(result, IpcError):
            task.fail(result)
        else:
            task.reply(result)
    return done


class ParameterCommands:
    """The ``param_*`` handlers over the pooled parameter clients (ROS thread only)."""

    def __init__(self, clients: ParameterClients, defaults: Defaults):
        self.clients = clients
        self.defaults = defaults
        self.run = clients.run
        self.run_all = clients.run_all

    # ---- the IPC commands (ipc/PROTOCOL.md "param_*") ------------------------------------------
    def handlers(self) -> dict[str, Callable[[Task], None]]:
        return {"param_list": self.cmd_list, "param_get": self.cmd_get, "param_set": self.cmd_set,
                "param_reset": self.cmd_reset, "param_reset_all": self.cmd_reset_all}

    def cmd_list(self, task: Task) -> None:
        self.run_all(_fqns(task.args), self.op_list,
                     lambda results: task.reply({"nodes": {f: _outcome(r, "parameters") for f, r in results.items()}}),
                     _limit(task))

    def cmd_get(self, task: Task) -> None:
        fqn = args.node(task.args)
        self.run(fqn, self.op_get(fqn, _name(task.args)), _answer(task), _limit(task))

    def cmd_set(self, task: Task) -> None:
        fqn = args.node(task.args)
        if "value" not in task.args:
            raise IpcError("bad-request", "value: missing")
        self.run(fqn, self.op_set(fqn, _name(task.args), task.args["value"]), _answer(task), _limit(task))

    def cmd_reset(self, task: Task) -> None:
        fqn = args.node(task.args)
        self.run(fqn, self.op_reset(fqn, _name(task.args)), _answer(task), _limit(task))

    def cmd_reset_all(self, task: Task) -> None:
        self.run_all(_fqns(task.args), self.op_reset_all,
                     lambda results: task.reply({"nodes": {f: _outcome(r, "result") for f, r in results.items()}}),
                     _limit(task))

    # ---- the operations (generators: yield (service, request), get the response) -------------
    def op_list(self, fqn: str) -> Operation:
        names, values = yield from self._read_all(fqn)
        record = yield from self._record(fqn, (names, values))
        for name, value in zip(names, values, strict=True):
            record.values.setdefault(name, value)
        return [{"name": n, "value": value_json(v), "type": type_name(v)} for n, v in zip(names, values, strict=True)]

    def op_get(self, fqn: str, name: str) -> Operation:
        yield from self._record(fqn)
        got, described = yield [("get", GetParameters.Request(names=[name])),
                                ("describe", DescribeParameters.Request(names=[name]))]
        value = self._found(fqn, name, got)
        body = {"name": name, "value": value_json(value), "type": type_name(value)}
        if described.descriptors:
            body.update(descriptor_json(described.descriptors[0]))
        return body

    def op_set(self, fqn: str, name: str, data: Any) -> Operation:
        current = yield from self._current(fqn, name)
        value = to_value(data, current.type)
        yield from self._set(name, value)
        after = yield "get", GetParameters.Request(names=[name])
        now = after.values[0] if after.values else value
        return {"name": name, "value": value_json(now), "type": type_name(now)}

    def op_reset(self, fqn: str, name: str) -> Operation:
        record = yield from self._record(fqn)
        default = record.values.get(name)
        if default is None:
            raise IpcError("no-default", f"No default value for parameter: {name} (the gateway first saw it "
                           "after it was set, or never)", {"name": name})
        current = yield from self._current(fqn, name)
        if not same_value(current, default):
            yield from self._set(name, default)
        return {}

    def op_reset_all(self, fqn: str) -> Operation:
        names, values = yield from self._read_all(fqn)
        record = yield from self._record(fqn, (names, values))
        changed = [(n, record.values[n]) for n, v in zip(names, values, strict=True)
                   if n in record.values and not same_value(v, record.values[n])]
        reset, failed = [], []
        if changed:
            request = SetParameters.Request(parameters=[Parameter(name=n, value=v) for n, v in changed])
            response = yield "set", request
            results = list(response.results)
            for i, (n, _) in enumerate(changed):
                result = results[i] if i < len(results) else None
                if result is not None and result.successful:
                    reset.append(n)
                else:
                    failed.append({"name": n, "reason": (result.reason if result is not None else "")
                                   or "the node gave no result for it"})
        return {"reset": reset, "failed": failed}

    # ---- steps shared by the operations ---------------------------------------------------
    def _read_all(self, fqn: str) -> Generator[Step, Any, tuple[list[str], list[ParameterValue]]]:
        for _ in range(2):  # a parameter undeclared between the two calls: once more
            listed = yield "list", ListParameters.Request()
            names = list(listed.result.names)
            if not names:
                return [], []
            got = yield "get", GetParameters.Request(names=names)
            values = list(got.values)
            if len(values) == len(names):
                return names, values
        raise IpcError("parameter-failed", f"The parameters of {fqn} changed while they were read; retry",
                       {"node": fqn})

    def _current(self, fqn: str, name: str) -> Generator[Step, Any, ParameterValue]:
        yield from self._record(fqn)
        got = yield "get", GetParameters.Request(names=[name])
        return self._found(fqn, name, got)

    def _found(self, fqn: str, name: str, got: Any) -> ParameterValue:
        """The value of a get_parameters answer for one name (first seen: recorded), or 404."""
        if not got.values or got.values[0].type == T.PARAMETER_NOT_SET:
            raise IpcError("no-such-parameter", f"Parameter not found: {name}", {"name": name})
        record = self.defaults.records.get(fqn)
        if record is not None:
            record.values.setdefault(name, got.values[0])
        return got.values[0]

    def _set(self, name: str, value: ParameterValue) -> Generator[Step, Any, None]:
        response = yield "set", SetParameters.Request(parameters=[Parameter(name=name, value=value)])
        if not response.results:
            raise IpcError("parameter-failed", f"Set parameter returned no result for: {name}", {"name": name})
        if not response.results[0].successful:
            raise refused(response.results[0].reason, name)

    def _record(self, fqn: str, read: tuple[list[str], list[ParameterValue]] | None = None
                ) -> Generator[Step, Any, Record]:
        """The node's record of this start; made from ``read`` or from a read of every parameter."""
        key = self.defaults.start_keys(fqn)
        record = self.defaults.records.get(fqn)
        if record is not None and key <= record.key:  # no start of the node since the record was made
            self.defaults.records.move_to_end(fqn)
            return record
        if read is None:
            read = yield from self._read_all(fqn)
        return self.defaults.keep(fqn, key, read)
