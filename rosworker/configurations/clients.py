"""The ``param_*`` operations on other nodes: their driving, their deadlines and the negative cache.

One command is one *operation* per node (``commands.py``), written as a generator
that yields ``(service, request)`` and is sent each response (:meth:`ParameterClients._advance`);
the operations of a multi-node command (a listing, a reset of everything) start
at once and the command is answered when the last one ends.  An operation needs
its node's client set (``pool.py``); when all ``max_parameter_clients`` sets are held by
operations in flight, it waits in line (first come, first served) for one to
be free, within the request's deadline (``pool-busy`` for a node still in line
when the deadline comes), so a component of 200 nodes lists all of them.  Once
it has its clients, the node's services have ``parameter_service_timeout`` to
be matched, and the node as much again from the operation's first request to
answer (a read unanswered for ``RESEND_AFTER`` s is sent again: a new client's
first reply can be lost before the server has matched it); past either the
node is answered ``node-unavailable``.  A node that was asked and did not
answer is remembered for ``parameter_negative_cache_s``, so a hung node costs
one request its timeout and the next ones nothing (medkit's issues 318 and
531); one whose services were not matched in time (just started, a loaded
machine) is not, or it would be refused that long right after its start.  A
remembered node is asked again at once when it answers one of the timed-out
requests late (slow, not hung: the pool listens for the last ``MAX_LATE``) or
when a new start of it is in the graph (``defaults.py``'s start keys).  A node
whose services are not in the graph is answered at once.

Everything runs on the ROS thread; responses are taken by :meth:`ParameterClients.poll`,
which the executor runs when a client with requests open has a response, and at
the operations' deadlines (``RosExecutor.add_poller``: :meth:`ParameterClients.waitables`,
:meth:`ParameterClients.due`): nothing ever waits on this thread.  A SIGTERM answers the operations in flight
``shutdown`` (:meth:`ParameterClients.shutdown`), not their callers' deadline.

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

from rclpy.parameter_service import ParameterService

from ipc.errors import IpcError

from ..core.stats import Stats
from .defaults import Defaults
from .pool import LATE, SERVICE_NAMES, SERVICES, ClientPool, NodeClients, Sent

log = logging.getLogger("sovd.rosworker.parameters")

# A new client whose server shows up waits this long more before its first request: the server's reply
# writer may not have matched the client's reader yet (rclpy only tells about the request side), and a
# reply sent before that is lost (seen with hundreds of new clients at once).  services.py does the same.
SETTLE = 0.25
READS = ("list", "describe", "get")   # requests that may be sent again: asking twice changes nothing
RESEND_AFTER = 0.5                   # seconds a read waits for its answer before it is sent again
MAX_SENDS = 3                        # times one read is sent at most
MATCH_POLL = 0.002                   # seconds between looks at a service's match while a request waits

Step = tuple[str, Any]                          # (service kind, request)
Operation = Generator[Step | list[Step], Any, Any]


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
        self.sent: dict[int, Sent] = {}          # request index -> [(kind, sequence number)] sent
        self.sent_at: dict[int, float] = {}      # request index -> when it was last sent


class _Own:
    """What rclpy's ParameterService callbacks need of their service: the node."""

    def __init__(self, node):
        self._node = node

    def _get_node(self):
        return self._node


class ParameterClients:
    """The ``param_*`` operations over the pooled parameter clients (ROS thread only)."""

    def __init__(self, node, stats: Stats, defaults: Defaults, *, timeout: float, negative_cache_s: float,
                 max_clients: int, idle_s: float):
        self.node = node
        self.stats = stats
        self.defaults = defaults
        self.timeout = timeout
        self.negative_cache_s = negative_cache_s
        self.max_clients = max_clients
        ns = node.get_namespace()
        self.own_fqn = (ns.rstrip("/") + "/" + node.get_name()) if ns != "/" else "/" + node.get_name()
        self.pool = ClientPool(node, stats, max_clients=max_clients, idle_s=idle_s)
        self._ops: set[Op] = set()
        self.polled = 0.0  # when poll() last ran: what due() counts from
        self._line: collections.deque[Op] = collections.deque()  # operations waiting for a client set
        # fqn -> (monotonic time until which it is answered at once, the start keys of the node that did not answer)
        self._unavailable: dict[str, tuple[float, frozenset]] = {}

    # ---- executor hooks -------------------------------------------------------------------
    def waitables(self) -> list:
        """The clients with requests awaiting an answer (late ones too): their responses wake the ROS thread."""
        return [client for clients in self.pool.sets() for kind, client in clients.clients.items()
                if clients.pending[kind]]

    def due(self) -> float | None:
        """When :meth:`poll` must run without a response: soon while a request waits for its service to
        match (or an operation for a client set); else the first deadline, limit or read to send again."""
        if not self._ops:
            return None
        if self._line:
            return self.polled + MATCH_POLL
        due = math.inf
        for op in self._ops:
            if op.unsent:
                return self.polled + MATCH_POLL
            due = min(due, op.limit, op.deadline if op.deadline is not None else math.inf)
            for i, sent in op.sent.items():
                if sent[0][0] in READS and len(sent) < MAX_SENDS:
                    due = min(due, op.sent_at[i] + RESEND_AFTER)
        return due if due != math.inf else None

    def poll(self) -> None:
        """Take every response that came, send what waited for its service, end what ran out of time."""
        self.polled = time.monotonic()
        for clients in self.pool.sets():
            self._take(clients)
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

    def _take(self, clients: NodeClients) -> None:
        """Take the set's responses: each to its operation; a late one to a timed-out operation clears
        the node from the negative cache (it is slow, not hung); any other is dropped."""
        for entry, response in clients.responses():
            if entry is LATE:
                if self._unavailable.pop(clients.fqn, None) is not None:
                    log.info("%s answered a timed-out parameter request late: asked again", clients.fqn)
            elif entry[0] in self._ops:
                self._answered(entry[0], entry[1], response)

    def sweep_idle(self) -> None:
        """Destroy the client sets unused for ``parameter_client_idle_s`` (none with calls open); forget the
        nodes remembered as unavailable for long enough; read the events."""
        self.defaults.drain()
        self.pool.sweep()
        now = time.monotonic()
        for fqn in [f for f, (until, _) in self._unavailable.items() if until <= now]:
            del self._unavailable[fqn]
        self._gauges()

    def shutdown(self) -> None:
        for op in list(self._ops):
            self._finish(op, IpcError("shutdown", "The gateway is shutting down"))
        self.pool.close()
        self._gauges()

    # ---- the commands --------------------------------------------------------------------
    def run(self, fqn: str, gen: Operation, done: Callable[[Any], None], limit: float | None = None) -> None:
        """Start one operation on ``fqn``; ``done`` gets its result or an IpcError (maybe at once), by
        ``limit`` (a ``time.monotonic()``: the request's deadline) at the latest."""
        self.defaults.drain()
        clients = self.pool.get(fqn)
        if fqn in self._unavailable and clients is not None:
            self._take(clients)  # a late answer since: slow, not hung
        cached = self._unavailable.get(fqn)
        now = time.monotonic()
        if cached is not None and self.defaults.start_keys(fqn) - cached[1]:
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
                clients = self.pool.acquire(op.fqn, queued=bool(self._line) and self._line[0] is not op)
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
            op.sent[i] = [(kind, clients.send(kind, request, (op, i)))]
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
                sent.append((kind, clients.send(kind, op.steps[i][1], (op, i))))
                op.sent_at[i] = now
                self.stats.parameter_calls += 1
                self.stats.parameter_resends += 1

    def _forget(self, op: Op, sent: Sent) -> None:
        """No answer is awaited any more for these requests (a late one is dropped)."""
        clients = self.pool.get(op.fqn)
        if clients is not None:
            clients.forget(sent)

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
        if op.sent:  # it was asked and did not answer (hung): remembered, so the next requests cost nothing
            self._unavailable[op.fqn] = (time.monotonic() + self.negative_cache_s,
                                         self.defaults.start_keys(op.fqn))
            if op.holds is not None:  # unless it answers late after all
                for sent in op.sent.values():
                    op.holds.await_late(sent)
                op.sent = {}
            log.warning("parameter service of %s did not respond within %g s (answered at once for %g s)",
                        op.fqn, self.timeout, self.negative_cache_s)
            what, retry = "did not respond", max(1, math.ceil(self.negative_cache_s))
        else:  # its services were not matched yet (a node just started, a loaded machine): not remembered,
            # or a node read at once after its start would be refused for parameter_negative_cache_s
            log.warning("parameter services of %s were not matched within %g s", op.fqn, self.timeout)
            what, retry = "was not available", 2
        self._finish(op, IpcError("node-unavailable",
                                  f"Parameter service {what} for node: {op.fqn} (within {self.timeout:g} s)",
                                  {"node": op.fqn, "timeout_s": self.timeout, "retry_after_s": retry}))

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

    def _gauges(self) -> None:
        self.stats.parameter_calls_in_flight = len(self._ops)
        self.stats.parameter_waiting = len(self._line)
