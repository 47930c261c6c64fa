"""ROS 2 parameters of other nodes: the ``param_*`` commands (SOVD configurations).

Every node's parameters are read and changed through its own services
(``rcl_interfaces``: ``list_parameters``, ``describe_parameters``,
``get_parameters``, ``set_parameters``).  The clients are made and called on
the ROS thread only, one set per node, pooled (LRU, at most
``max_parameter_clients`` nodes; a set unused for ``parameter_client_idle_s``
is destroyed by the idle sweep).  A request is sent with the client handle's
``send_request`` and its response is taken with ``take_response`` by
:meth:`ParameterClients.poll`, which the executor runs while calls are open
(``RosExecutor.add_poller``): no future, no spin, nothing ever waits on this
thread.

One command is one *operation* per node, written as a generator that yields
``(service, request)`` and is sent each response (:meth:`ParameterClients._advance`);
the operations of a multi-node command (a listing, a reset of everything) start
at once and the command is answered when the last one ends.  An operation needs
its node's client set; when all ``max_parameter_clients`` sets are held by
operations in flight, it waits in line (first come, first served) for one to
be free, within the request's deadline (``pool-busy`` for a node still in line
when the deadline comes), so a component of 200 nodes lists all of them.  Once
it has its clients, the node's services have ``parameter_service_timeout`` to
be matched, and the node as much again from the operation's first request to
answer (a read unanswered for ``RESEND_AFTER`` s is sent again: a new client's
first reply can be lost before the server has matched it); past either the
node is answered ``node-unavailable`` and remembered for
``parameter_negative_cache_s``, so a hung node costs one request its timeout
and the next ones nothing (medkit's issues 318 and 531).  A node whose services
are not in the graph is answered at once.

Defaults: ROS 2 has no "default" service.  The first time an operation reaches a
node, its parameters are read and kept as that node's record, keyed by the
node's start (the GID of its ``/parameter_events`` publisher: a restarted node
is a new record).  A parameter first seen later (declared later: its
``/parameter_events`` "new" entry, or first read) joins the record with the
value it had then.  Reset sets the recorded value back.

One pooled ``/parameter_events`` subscription (read with ``take`` before each
operation and on every sweep) keeps the records of parameters declared later;
values themselves are never cached, so a change made elsewhere shows on the
next read.

The gateway's own node is answered by its own parameter service's callbacks,
called directly, never through its services (that would wait on itself).
"""

from __future__ import annotations

import collections
import logging
import math
import time
from collections.abc import Callable, Generator
from typing import Any

from rcl_interfaces.msg import Parameter, ParameterEvent, ParameterType, ParameterValue
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
from rclpy.parameter_service import ParameterService
from rclpy.qos import qos_profile_parameter_events, qos_profile_parameters

from ipc.errors import IpcError

from ..core.executor import Task
from ..core.stats import Stats

log = logging.getLogger("sovd.rosworker.parameters")

SERVICES = {"list": ListParameters, "describe": DescribeParameters, "get": GetParameters,
            "set": SetParameters}
SERVICE_NAMES = {"list": "list_parameters", "describe": "describe_parameters", "get": "get_parameters",
                 "set": "set_parameters"}
EVENTS_TOPIC = "/parameter_events"
EVENTS_PER_DRAIN = 1000      # parameter events taken at most per look (the rest wait for the next)
MAX_RECORDS = 4096           # nodes whose defaults are kept (the oldest record goes first)
MAX_NODES_PER_COMMAND = 256  # nodes one listing or reset may name
ANSWER_MARGIN = 0.25         # seconds before the request's deadline by which every operation has ended
# A new client whose server shows up waits this long more before its first request: the server's reply
# writer may not have matched the client's reader yet (rclpy only tells about the request side), and a
# reply sent before that is lost (seen with hundreds of new clients at once).  services.py does the same.
SETTLE = 0.25
READS = ("list", "describe", "get")   # requests that may be sent again: asking twice changes nothing
RESEND_AFTER = 0.5                   # seconds a read waits for its answer before it is sent again
MAX_SENDS = 3                        # times one read is sent at most

T = ParameterType
TYPE_NAMES = {
    T.PARAMETER_BOOL: "bool", T.PARAMETER_INTEGER: "int", T.PARAMETER_DOUBLE: "double",
    T.PARAMETER_STRING: "string", T.PARAMETER_BYTE_ARRAY: "byte_array", T.PARAMETER_BOOL_ARRAY: "bool_array",
    T.PARAMETER_INTEGER_ARRAY: "int_array", T.PARAMETER_DOUBLE_ARRAY: "double_array",
    T.PARAMETER_STRING_ARRAY: "string_array", T.PARAMETER_NOT_SET: "not_set",
}
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1
_NON_FINITE = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}

Step = tuple[str, Any]                          # (service kind, request)
Operation = Generator[Step | list[Step], Any, Any]


# ---- values: ParameterValue <-> JSON ------------------------------------------------------
def _double_out(x: float) -> float | str:
    """A double as JSON: NaN and ±inf as proto3's strings."""
    if math.isnan(x):
        return "NaN"
    if math.isinf(x):
        return "Infinity" if x > 0 else "-Infinity"
    return x


def value_json(v: ParameterValue) -> Any:
    t = v.type
    if t == T.PARAMETER_BOOL:
        return bool(v.bool_value)
    if t == T.PARAMETER_INTEGER:
        return int(v.integer_value)
    if t == T.PARAMETER_DOUBLE:
        return _double_out(float(v.double_value))
    if t == T.PARAMETER_STRING:
        return str(v.string_value)
    if t == T.PARAMETER_BYTE_ARRAY:
        return [b if isinstance(b, int) else b[0] for b in v.byte_array_value]
    if t == T.PARAMETER_BOOL_ARRAY:
        return [bool(b) for b in v.bool_array_value]
    if t == T.PARAMETER_INTEGER_ARRAY:
        return [int(i) for i in v.integer_array_value]
    if t == T.PARAMETER_DOUBLE_ARRAY:
        return [_double_out(float(d)) for d in v.double_array_value]
    if t == T.PARAMETER_STRING_ARRAY:
        return [str(s) for s in v.string_array_value]
    return None


def type_name(v: ParameterValue) -> str:
    return TYPE_NAMES.get(v.type, "not_set")


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and INT64_MIN <= x <= INT64_MAX


def _double_in(x: Any) -> float | None:
    if isinstance(x, bool):
        return None
    if isinstance(x, str):
        return _NON_FINITE.get(x)
    if isinstance(x, (int, float)):
        try:
            return float(x)
        except OverflowError:
            return None
    return None


def _convert(data: Any, t: int) -> ParameterValue | None:
    """``data`` as a value of type ``t``, or None when it is not one."""
    if t == T.PARAMETER_BOOL:
        return ParameterValue(type=t, bool_value=data) if isinstance(data, bool) else None
    if t == T.PARAMETER_INTEGER:
        return ParameterValue(type=t, integer_value=data) if _is_int(data) else None
    if t == T.PARAMETER_DOUBLE:
        d = _double_in(data)
        return None if d is None else ParameterValue(type=t, double_value=d)
    if t == T.PARAMETER_STRING:
        return ParameterValue(type=t, string_value=data) if isinstance(data, str) else None
    if not isinstance(data, list):
        return None
    if t == T.PARAMETER_BYTE_ARRAY:
        if all(_is_int(b) and 0 <= b <= 255 for b in data):
            return ParameterValue(type=t, byte_array_value=[bytes([b]) for b in data])
    elif t == T.PARAMETER_BOOL_ARRAY:
        if all(isinstance(b, bool) for b in data):
            return ParameterValue(type=t, bool_array_value=data)
    elif t == T.PARAMETER_INTEGER_ARRAY:
        if all(_is_int(i) for i in data):
            return ParameterValue(type=t, integer_array_value=data)
    elif t == T.PARAMETER_DOUBLE_ARRAY:
        doubles = [_double_in(d) for d in data]
        if all(d is not None for d in doubles):
            return ParameterValue(type=t, double_array_value=doubles)
    elif t == T.PARAMETER_STRING_ARRAY:
        if all(isinstance(s, str) for s in data):
            return ParameterValue(type=t, string_array_value=data)
    return None


def _inferred(data: Any) -> int | None:
    """The parameter type a JSON value reads as by itself (None: none)."""
    if isinstance(data, bool):
        return T.PARAMETER_BOOL
    if _is_int(data):
        return T.PARAMETER_INTEGER
    if isinstance(data, float):
        return T.PARAMETER_DOUBLE
    if isinstance(data, str):
        return T.PARAMETER_STRING
    if isinstance(data, list) and data:
        for t in (T.PARAMETER_BOOL_ARRAY, T.PARAMETER_INTEGER_ARRAY, T.PARAMETER_DOUBLE_ARRAY,
                  T.PARAMETER_STRING_ARRAY):
            if _convert(data, t) is not None:
                return t
    return None


def to_value(data: Any, current: int) -> ParameterValue:
    """The value to send for ``data``: of the parameter's type when it fits, else of the type the
    JSON reads as (the node then decides, with its own reason); IpcError when it reads as none."""
    value = _convert(data, current)
    if value is None:
        inferred = _inferred(data)
        value = None if inferred is None else _convert(data, inferred)
    if value is None:
        expected = TYPE_NAMES.get(current, "a parameter value")
        raise IpcError("invalid-parameter-value",
                       f"The value is not a ROS 2 parameter value of type {expected}: expected a boolean, an "
                       "integer (64-bit), a number (NaN and infinities as \"NaN\", \"Infinity\", \"-Infinity\"), "
                       "a string, or a non-empty array of one of those (bytes: integers 0-255)",
                       {"expected_type": expected})
    return value


def _same(a: ParameterValue, b: ParameterValue) -> bool:
    return a.type == b.type and value_json(a) == value_json(b)


def descriptor_json(d: Any) -> dict[str, Any]:
    """The describe_parameters answer: description, read-only and, when declared, ranges and constraints."""
    out: dict[str, Any] = {"description": str(d.description), "read_only": bool(d.read_only)}
    if d.additional_constraints:
        out["additional_constraints"] = str(d.additional_constraints)
    if d.dynamic_typing:
        out["dynamic_typing"] = True
    if d.integer_range:
        r = d.integer_range[0]
        out["integer_range"] = {"from_value": int(r.from_value), "to_value": int(r.to_value), "step": int(r.step)}
    if d.floating_point_range:
        r = d.floating_point_range[0]
        out["floating_point_range"] = {"from_value": _double_out(r.from_value), "to_value": _double_out(r.to_value),
                                       "step": _double_out(r.step)}
    return out


def refused(reason: str, name: str) -> IpcError:
    """A set the node refused: read-only (403) or any other reason (400), with the node's reason."""
    text = reason or "the node refused the value without a reason"
    low = text.lower()
    if "read-only" in low or "read only" in low or "read_only" in low:
        return IpcError("parameter-read-only", text, {"name": name})
    return IpcError("invalid-parameter-value", text, {"name": name})


# ---- the commands' arguments and answers ----------------------------------------------------
def _fqn(value: Any) -> str:
    if not isinstance(value, str) or not value.startswith("/") or len(value) > 1024 or value.endswith("/"):
        raise IpcError("bad-request", "node: expected a fully qualified node name (/namespace/name)")
    return value


def _fqns(args: dict) -> list[str]:
    nodes = args.get("nodes")
    if not isinstance(nodes, list) or len(nodes) > MAX_NODES_PER_COMMAND:
        raise IpcError("bad-request", f"nodes: expected a list of at most {MAX_NODES_PER_COMMAND} node names")
    return list(dict.fromkeys(_fqn(n) for n in nodes))


def _name(args: dict) -> str:
    name = args.get("name")
    if not isinstance(name, str) or not name or len(name) > 512:
        raise IpcError("bad-request", "name: expected a parameter name of 1 to 512 characters")
    return name


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


# ---- the clients ----------------------------------------------------------------------------
class NodeClients:
    """One node's four parameter clients, the calls open on each, the operations that hold them and when
    they were last used."""

    __slots__ = ("fqn", "clients", "pending", "used", "ops", "ready")

    def __init__(self, fqn: str, clients: dict[str, Any]):
        self.fqn = fqn
        self.clients = clients
        self.pending: dict[str, dict[int, tuple[Op, int]]] = {kind: {} for kind in clients}
        self.used = time.monotonic()
        self.ops = 0              # operations in flight on this set: it is not given to another node
        self.ready: dict[str, float] = {}  # kind -> when its server was first seen matched

    def open_calls(self) -> int:
        return sum(len(p) for p in self.pending.values())


class Op:
    """One operation on one node: its generator, the requests of its current step, its deadline and its end.

    A step is one request, or a list of requests sent at once (a read's value and descriptor)."""

    __slots__ = ("fqn", "gen", "done", "deadline", "answering", "limit", "holds", "steps", "many", "responses",
                 "unsent", "sent", "sent_at")

    def __init__(self, fqn: str, gen: Operation, done: Callable[[Any], None], deadline: float | None,
                 limit: float):
        self.fqn = fqn
        self.gen = gen
        self.done = done          # called once with the result or an IpcError
        # the node's time: parameter_service_timeout for its services to match once the operation has its
        # client set, then as much from its first request (None: in line for a client set)
        self.deadline = deadline
        self.answering = False
        self.limit = limit        # the request's: past it the operation ends whatever it waits for
        self.holds: NodeClients | None = None   # its node's client set, once it has it
        self.steps: list[Step] = []
        self.many = False         # the step was a list: the generator gets a list of responses
        self.responses: list[Any] = []
        self.unsent: set[int] = set()            # requests of the step waiting for their service
        self.sent: dict[int, list[tuple[str, int]]] = {}  # request index -> [(kind, sequence number)] sent
        self.sent_at: dict[int, float] = {}              # request index -> when it was last sent


class _Own:
    """What rclpy's ParameterService callbacks need of their service: the node."""

    def __init__(self, node):
        self._node = node

    def _get_node(self):
        return self._node


class Record:
    __slots__ = ("key", "values")

    def __init__(self, key: Any):
        self.key = key
        self.values: dict[str, ParameterValue] = {}


class ParameterClients:
    """The pooled parameter clients and the ``param_*`` operations (ROS thread only)."""

    def __init__(self, node, stats: Stats, *, timeout: float, negative_cache_s: float, max_clients: int,
                 idle_s: float):
        self.node = node
        self.stats = stats
        self.timeout = timeout
        self.negative_cache_s = negative_cache_s
        self.max_clients = max_clients
        self.idle_s = idle_s
        ns = node.get_namespace()
        self.own_fqn = (ns.rstrip("/") + "/" + node.get_name()) if ns != "/" else "/" + node.get_name()
        self._nodes: collections.OrderedDict[str, NodeClients] = collections.OrderedDict()
        self._ops: set[Op] = set()
        self._line: collections.deque[Op] = collections.deque()  # operations waiting for a client set
        # fqn -> (monotonic time until which it is answered at once, the start key of the node that did not answer)
        self._unavailable: dict[str, tuple[float, Any]] = {}
        self._records: collections.OrderedDict[str, Record] = collections.OrderedDict()
        self._events = None
        # cyclic subscriptions on parameters (rosworker/configurations/feed.py): called with each /parameter_events message
        self.listeners: list[Callable[[Any], None]] = []
        stats.parameter_client_cap = max_clients

    # ---- executor hooks -------------------------------------------------------------------
    def active(self) -> bool:
        return bool(self._ops)

    def poll(self) -> None:
        """Take every response that came, send what waited for its service, end what ran out of time."""
        for clients in list(self._nodes.values()):
            for kind, pending in clients.pending.items():
                while pending:
                    client = clients.clients[kind]
                    with client.handle:
                        header, response = client.handle.take_response(client.srv_type.Response)
                    if header is None:
                        break
                    entry = pending.pop(header.request_id.sequence_number, None)
                    if entry is not None and entry[0] in self._ops:
                        self._answered(entry[0], entry[1], response)
        for op in list(self._line):  # first come, first served, as client sets come free
            if op in self._ops:
                self._dispatch(op)
                if op in self._ops and op.holds is None:
                    break  # no set came free for it: none for those behind it either
        now = time.monotonic()
        for op in list(self._ops):
            if op.unsent and op.holds is not None and op in self._ops:
                self._dispatch(op)
            if op.sent and op in self._ops:
                self._resend_reads(op, now)
            if op in self._ops and op.deadline is not None and now >= op.deadline:
                self._timed_out(op)
            elif op in self._ops and now >= op.limit:
                self._out_of_time(op)
        self._gauges()

    def sweep_idle(self) -> None:
        """Destroy the client sets unused for ``idle_s`` (none with calls open); read the events."""
        self._drain_events()
        cutoff = time.monotonic() - self.idle_s
        for fqn, clients in list(self._nodes.items()):
            if clients.used < cutoff and not clients.ops and not clients.open_calls():
                self._destroy(fqn)
        now = time.monotonic()
        for fqn in [f for f, (until, _) in self._unavailable.items() if until <= now]:
            del self._unavailable[fqn]
        self._gauges()

    def shutdown(self) -> None:
        for op in list(self._ops):
            self._finish(op, IpcError("shutdown", "The gateway is shutting down"))
        for fqn in list(self._nodes):
            self._destroy(fqn)

    # ---- the commands --------------------------------------------------------------------
    def run(self, fqn: str, gen: Operation, done: Callable[[Any], None], limit: float | None = None) -> None:
        """Start one operation on ``fqn``; ``done`` gets its result or an IpcError (maybe at once), by
        ``limit`` (a ``time.monotonic()``: the request's deadline) at the latest."""
        self._drain_events()
        cached = self._unavailable.get(fqn)
        now = time.monotonic()
        if cached is not None and cached[1] != self._start_key(fqn):
            del self._unavailable[fqn]  # the node started again since it did not answer: ask this one
            cached = None
        until = cached[0] if cached is not None else None
        if until is not None and until > now and fqn != self.own_fqn:
            gen.close()
            done(IpcError("node-unavailable",
                          f"Parameter service not available for node (cached): {fqn}; it did not answer "
                          f"recently, asked again after {math.ceil(until - now)} s",
                          {"node": fqn, "retry_after_s": max(1, math.ceil(until - now))}))
            return
        # The node's time starts with its first request; until then (a client set to wait for, its
        # services to match) the request's deadline bounds it.
        op = Op(fqn, gen, done, None, now + 2 * self.timeout if limit is None else max(now, limit))
        self._ops.add(op)
        self._advance(op, None)
        self._gauges()

    def run_all(self, fqns: list[str], make: Callable[[str], Operation], done: Callable[[dict], None],
                limit: float | None = None) -> None:
        """One operation per node, started at once (those past the client cap wait in line);
        ``done({fqn: result or IpcError})`` after the last, by ``limit`` at the latest."""
        results: dict[str, Any] = {}
        if not fqns:
            done(results)
            return

        def one(fqn: str) -> Callable[[Any], None]:
            def finished(result: Any) -> None:
                results[fqn] = result
                if len(results) == len(fqns):
                    done(results)
            return finished

        for fqn in fqns:
            self.run(fqn, make(fqn), one(fqn), limit)

    # ---- the IPC commands (ipc/PROTOCOL.md "param_*") ------------------------------------------
    def handlers(self) -> dict[str, Callable[[Task], None]]:
        return {"param_list": self.cmd_list, "param_get": self.cmd_get, "param_set": self.cmd_set,
                "param_reset": self.cmd_reset, "param_reset_all": self.cmd_reset_all}

    def cmd_list(self, task: Task) -> None:
        self.run_all(_fqns(task.args), self.op_list,
                     lambda results: task.reply({"nodes": {f: _outcome(r, "parameters") for f, r in results.items()}}),
                     _limit(task))

    def cmd_get(self, task: Task) -> None:
        fqn = _fqn(task.args.get("node"))
        self.run(fqn, self.op_get(fqn, _name(task.args)), _answer(task), _limit(task))

    def cmd_set(self, task: Task) -> None:
        fqn = _fqn(task.args.get("node"))
        if "value" not in task.args:
            raise IpcError("bad-request", "value: missing")
        self.run(fqn, self.op_set(fqn, _name(task.args), task.args["value"]), _answer(task), _limit(task))

    def cmd_reset(self, task: Task) -> None:
        fqn = _fqn(task.args.get("node"))
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
        if not _same(current, default):
            yield from self._set(name, default)
        return {}

    def op_reset_all(self, fqn: str) -> Operation:
        names, values = yield from self._read_all(fqn)
        record = yield from self._record(fqn, (names, values))
        changed = [(n, record.values[n]) for n, v in zip(names, values, strict=True)
                   if n in record.values and not _same(v, record.values[n])]
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
        record = self._records.get(fqn)
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
        key = self._start_key(fqn)
        record = self._records.get(fqn)
        if record is not None and record.key == key:
            self._records.move_to_end(fqn)
            return record
        if read is None:
            read = yield from self._read_all(fqn)
        record = Record(key)
        record.values.update(zip(*read, strict=True))
        self._records[fqn] = record
        while len(self._records) > MAX_RECORDS:
            self._records.popitem(last=False)
        return record

    def _start_key(self, fqn: str) -> Any:
        """Which start of the node this is: the GID of its /parameter_events publisher (None: none)."""
        namespace, _, name = fqn.rpartition("/")
        namespace = namespace or "/"
        try:
            infos = self.node.get_publishers_info_by_topic(EVENTS_TOPIC)
        except Exception:
            return None
        for info in infos:
            if info.node_name == name and info.node_namespace == namespace:
                return tuple(info.endpoint_gid)
        return None

    # ---- driving an operation -------------------------------------------------------------
    def _advance(self, op: Op, response: Any) -> None:
        try:
            step = op.gen.send(response)
        except StopIteration as stop:
            self._finish(op, stop.value)
            return
        except IpcError as exc:
            self._finish(op, exc)
            return
        except Exception as exc:
            log.exception("parameter operation on %s failed", op.fqn)
            self._finish(op, IpcError("internal", f"parameter operation failed: {type(exc).__name__}"))
            return
        op.many = isinstance(step, list)
        op.steps = step if op.many else [step]
        op.responses = [None] * len(op.steps)
        op.unsent = set(range(len(op.steps)))
        op.sent, op.sent_at = {}, {}
        if op.fqn == self.own_fqn:
            self._local(op)
        else:
            self._dispatch(op)

    def _answered(self, op: Op, index: int, response: Any) -> None:
        sent = op.sent.pop(index, None)
        if sent is None:
            return  # a second answer to a request sent twice
        self._forget(op, sent)
        op.responses[index] = response
        if not op.sent and not op.unsent:
            self._advance(op, op.responses if op.many else op.responses[0])

    def _local(self, op: Op) -> None:
        """The gateway's own node: rclpy's parameter service callbacks run here on the node itself (it
        serves no parameter services, and calling its own would wait on this thread)."""
        op.unsent.clear()
        for i, (kind, request) in enumerate(op.steps):
            callback = getattr(ParameterService, f"_{SERVICE_NAMES[kind]}_callback")
            op.responses[i] = callback(_Own(self.node), request, SERVICES[kind].Response())
        self._advance(op, op.responses if op.many else op.responses[0])

    def _dispatch(self, op: Op) -> None:
        """Send the step's requests whose services are ready (the others wait for the next round); an
        operation without its client set gets in line for one."""
        if op.holds is None:
            try:
                clients = self._clients_for(op.fqn, queued=bool(self._line) and self._line[0] is not op)
            except Exception as exc:  # noqa: BLE001 - rclpy refused a client: this node's answer
                self._finish(op, IpcError("node-unavailable", f"No parameter clients for {op.fqn}: {exc}",
                                          {"node": op.fqn, "retry_after_s": 2}))
                return
            if clients is None:
                if op not in self._line:
                    self._line.append(op)
                    self.stats.parameter_waits += 1
                return
            if self._line and self._line[0] is op:
                self._line.popleft()
            elif op in self._line:
                self._line.remove(op)
            op.holds = clients
            clients.ops += 1
            op.deadline = time.monotonic() + self.timeout  # its services have this long to be matched
        clients = op.holds
        clients.used = time.monotonic()
        for i in sorted(op.unsent):
            kind, request = op.steps[i]
            client = clients.clients[kind]
            ready = clients.ready.get(kind)
            if ready is None:
                if not client.service_is_ready():
                    if not self._offers_services(op.fqn):
                        self._finish(op, IpcError("node-unavailable", "Parameter service not available for node: "
                                                  f"{op.fqn} (the node has no parameter services, or has gone)",
                                                  {"node": op.fqn, "retry_after_s": 2}))
                        return
                    continue  # discovered but not matched yet: tried again on the next round
                ready = clients.ready[kind] = time.monotonic()
            if time.monotonic() - ready < SETTLE:
                continue  # the server's reply writer may not have matched the client's reader yet
            with client.handle:
                seq = client.handle.send_request(request)
            clients.pending[kind][seq] = (op, i)
            op.sent[i] = [(kind, seq)]
            op.sent_at[i] = time.monotonic()
            if not op.answering:
                op.answering = True
                op.deadline = op.sent_at[i] + self.timeout  # the node's time to answer starts with its first request
            op.unsent.discard(i)
            self.stats.parameter_calls += 1

    def _resend_reads(self, op: Op, now: float) -> None:
        """A read unanswered for ``RESEND_AFTER`` s is sent again (at most ``MAX_SENDS`` times in all): a
        new client's first reply can be lost before the server's reply writer matched it; the first
        answer counts.  A set is never sent twice."""
        clients = op.holds
        if clients is None:
            return
        for i, sent in op.sent.items():
            kind = sent[0][0]
            if kind in READS and len(sent) < MAX_SENDS and now - op.sent_at[i] >= RESEND_AFTER:
                client = clients.clients[kind]
                with client.handle:
                    seq = client.handle.send_request(op.steps[i][1])
                clients.pending[kind][seq] = (op, i)
                sent.append((kind, seq))
                op.sent_at[i] = now
                self.stats.parameter_calls += 1
                self.stats.parameter_resends += 1

    def _forget(self, op: Op, sent: list[tuple[str, int]]) -> None:
        """No answer is awaited any more for these requests (a late one is dropped)."""
        clients = self._nodes.get(op.fqn)
        if clients is not None:
            for kind, seq in sent:
                clients.pending[kind].pop(seq, None)

    def _offers_services(self, fqn: str) -> bool:
        namespace, _, name = fqn.rpartition("/")
        try:
            services = self.node.get_service_names_and_types_by_node(name, namespace or "/")
        except Exception:  # the node is not in the graph (NodeNameNonExistentError)
            return False
        return any(s == f"{fqn}/get_parameters" for s, _ in services)

    def _out_of_time(self, op: Op) -> None:
        """The request's deadline came first: not the node's fault, so nothing is remembered of it."""
        if op.holds is None:
            self._finish(op, IpcError("pool-busy", f"{op.fqn} waited in line for a parameter client set until "
                                      f"the request's deadline (all {self.max_clients} were in use: "
                                      "max_parameter_clients); retry shortly",
                                      {"node": op.fqn, "max_parameter_clients": self.max_clients}))
        else:
            self._finish(op, IpcError("deadline-exceeded", f"The request's deadline came before {op.fqn} "
                                      "answered (it waited in line for a client set first)", {"node": op.fqn}))

    def _timed_out(self, op: Op) -> None:
        self.stats.parameter_timeouts += 1
        self._unavailable[op.fqn] = (time.monotonic() + self.negative_cache_s, self._start_key(op.fqn))
        what = "did not respond" if op.sent else "was not available"
        log.warning("parameter service of %s %s within %g s (answered at once for %g s)", op.fqn, what,
                    self.timeout, self.negative_cache_s)
        self._finish(op, IpcError("node-unavailable",
                                  f"Parameter service {what} for node: {op.fqn} (within {self.timeout:g} s)",
                                  {"node": op.fqn, "timeout_s": self.timeout,
                                   "retry_after_s": max(1, math.ceil(self.negative_cache_s))}))

    def _finish(self, op: Op, result: Any) -> None:
        if op not in self._ops:
            return
        self._ops.discard(op)
        if op in self._line:
            self._line.remove(op)
        if op.holds is not None:
            op.holds.ops -= 1
            op.holds = None
        for sent in op.sent.values():
            self._forget(op, sent)
        op.sent = {}
        op.unsent = set()
        op.gen.close()
        self._gauges()
        op.done(result)

    # ---- the pool --------------------------------------------------------------------------
    def _clients_for(self, fqn: str, queued: bool = False) -> NodeClients | None:
        """The node's client set, made (the least recently used free one goes at the cap); None when
        every set is held by an operation in flight, or ``queued`` (others wait in line before it)."""
        clients = self._nodes.get(fqn)
        if clients is not None:
            self._nodes.move_to_end(fqn)
            return clients
        if queued:
            return None
        while len(self._nodes) >= self.max_clients:
            idle = next((f for f, c in self._nodes.items() if not c.ops and not c.open_calls()), None)
            if idle is None:
                return None
            self._destroy(idle)
        made = {}
        try:
            for kind, srv in SERVICES.items():
                made[kind] = self.node.create_client(srv, f"{fqn}/{SERVICE_NAMES[kind]}",
                                                     qos_profile=qos_profile_parameters)
        except Exception:
            for client in made.values():
                self.node.destroy_client(client)
            raise
        clients = self._nodes[fqn] = NodeClients(fqn, made)
        self._gauges()
        return clients

    def _destroy(self, fqn: str) -> None:
        clients = self._nodes.pop(fqn, None)
        if clients is None:
            return
        for client in clients.clients.values():
            try:
                self.node.destroy_client(client)
            except Exception:
                log.exception("destroying a parameter client of %s failed", fqn)
        self._gauges()

    def _gauges(self) -> None:
        self.stats.parameter_clients = len(self._nodes)
        self.stats.parameter_calls_in_flight = len(self._ops)
        self.stats.parameter_waiting = len(self._line)

    # ---- /parameter_events ---------------------------------------------------------------------
    def drain_events(self) -> None:
        """Take the /parameter_events messages that came (the parameter feeds' ticks)."""
        self._drain_events()

    def _drain_events(self) -> None:
        """Parameters declared since: they join their node's record with the value they were declared with."""
        if self._events is None:
            self._events = self.node.create_subscription(ParameterEvent, EVENTS_TOPIC, lambda _msg: None,
                                                         qos_profile_parameter_events)
        for _ in range(EVENTS_PER_DRAIN):
            taken = self._events.handle.take_message(ParameterEvent, False)
            if taken is None:
                return
            event = taken[0]
            self.stats.parameter_events += 1
            for listener in self.listeners:  # cyclic subscriptions on parameters (rosworker/configurations/feed.py)
                listener(event)
            record = self._records.get(event.node)
            if record is None or not event.new_parameters:
                continue
            if record.key != self._start_key(event.node):
                continue
            for p in event.new_parameters:
                record.values.setdefault(p.name, p.value)
