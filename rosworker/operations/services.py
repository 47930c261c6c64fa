"""Pooled ROS 2 service clients for ``POST .../operations/{op}/executions`` (ROS thread only).

One client per service path, made on the first call, kept in LRU order up to
``max_clients``, dropped after ``idle`` seconds unused, when its server leaves
the graph, or when the path is called with another type.

A call never blocks the ROS thread: the request is sent on the client's rcl
handle (``send_request``), the call waits in :attr:`ServiceClients.pending`,
and the executor's poller (:meth:`poll`, ``RosExecutor.add_poller``) takes the
responses from the handles (``take_response``) when a client with calls sent has
one (the waiter wakes the ROS thread), and at the calls' deadlines.  No rclpy future, no executor, no spin.  A call that has no response
within its deadline (``service_call_timeout``) is answered ``not-responding``:
the server may or may not have run it.  Its late response is taken and
dropped.
"""

from __future__ import annotations

import collections
import logging
import time
from typing import Any

from ipc.errors import IpcError

from ..core.executor import RosExecutor
from ..core.stats import Stats
from ..core.task import Task
from ..ros.decode import from_plain
from ..ros.encode import to_plain
from ..ros.msgtypes import ConversionError
from . import lru

log = logging.getLogger("sovd.rosworker.services")

# A new client whose server shows up waits this long more before its first request: the server's
# reply writer may not have matched the client's reader yet (rclpy only tells about the request
# side), and a reply sent before that is lost.
SETTLE = 0.25
# Requests one client has out at once; more wait in line.  A server's request reader keeps the
# services' default history (10): a burst beyond it is dropped at the server, unanswered.
MAX_IN_FLIGHT = 8
MATCH_WAIT = 1.0   # seconds a call waits for a new client to match its server before it is 503
MATCH_POLL = 0.002  # seconds between looks at a new client's match while a call waits for it


class Pooled:
    __slots__ = ("path", "type_name", "srv", "client", "last_used", "ready_since", "calls", "waiting")

    def __init__(self, path: str, type_name: str, srv: type, client):
        self.path = path
        self.type_name = type_name
        self.srv = srv
        self.client = client
        self.last_used = time.monotonic()
        self.ready_since: float | None = None   # when the server was first seen matched
        self.calls: dict[int, tuple[Task, float]] = {}   # sequence number -> (task, deadline)
        self.waiting: list[tuple[Task, Any, float, float]] = []  # (task, request, deadline, ready by)

    def ready(self, now: float) -> bool:
        """The server is there and the client has been matched to it for SETTLE seconds."""
        if self.ready_since is None:
            if not self.client.service_is_ready():
                return False
            self.ready_since = now
        return now - self.ready_since >= SETTLE


class ServiceClients:
    def __init__(self, node, executor: RosExecutor, stats: Stats, max_clients: int, idle: float):
        self.node = node
        self.executor = executor
        self.stats = stats
        self.max_clients = max_clients
        self.idle = idle
        self.entries: collections.OrderedDict[str, Pooled] = collections.OrderedDict()
        self.in_flight = 0
        self.polled = 0.0  # when poll() last ran: what due() counts from
        executor.add_poller("service clients", self.waitables, self.poll, self.due)

    def waitables(self) -> list:
        """The clients with calls sent (their responses wake the ROS thread)."""
        if not self.in_flight:
            return []
        return [p.client for p in self.entries.values() if p.calls]

    def due(self) -> float | None:
        """When :meth:`poll` must run without a response: a call's deadline, or soon while a call waits for
        its client to match its server (rclpy has no event for a match)."""
        if not self.in_flight:
            return None
        due = None
        for pooled in self.entries.values():
            if pooled.waiting:
                return self.polled + MATCH_POLL
            for _task, deadline in pooled.calls.values():
                if due is None or deadline < due:
                    due = deadline
        return due

    def _client(self, path: str, type_name: str, srv: type) -> Pooled:
        pooled = lru.reuse(self.entries, path, type_name)
        if pooled is not None:
            return pooled
        if path in self.entries:
            self._destroy(path, "type-change")
        try:
            client = self.node.create_client(srv, path)
        except Exception as exc:
            raise IpcError("service-unavailable", f"Could not create a client for {path}: {exc}",
                           {"service": path}) from None
        lru.make_room(self.entries, self.max_clients, lambda e: bool(e.calls or e.waiting),
                      lambda oldest: self._destroy(oldest, "lru"))
        pooled = self.entries[path] = Pooled(path, type_name, srv, client)
        self._count()
        return pooled

    def call(self, task: Task, path: str, type_name: str, srv: type, data: Any, timeout: float) -> None:
        """Send the request; ``task`` is answered from :meth:`poll` (or now, on an error)."""
        try:
            request = from_plain(srv.Request, data, path="parameters")
        except ConversionError as exc:
            raise IpcError("invalid-operation-data", exc.message, {"service": path}) from None
        pooled = self._client(path, type_name, srv)
        now = time.monotonic()
        pooled.last_used = now
        self.in_flight += 1
        self.stats.operation_calls_in_flight = self.in_flight
        self.stats.operation_calls_total += 1
        if pooled.ready(now) and not pooled.waiting and len(pooled.calls) < MAX_IN_FLIGHT:
            self._send(pooled, task, request, now + timeout)
        else:
            # A new client has not matched its server yet (or there is none): wait a moment.
            pooled.waiting.append((task, request, now + timeout, now + min(MATCH_WAIT, timeout)))

    def _send(self, pooled: Pooled, task: Task, request: Any, deadline: float) -> None:
        try:
            with pooled.client.handle:
                seq = pooled.client.handle.send_request(request)
        except Exception as exc:  # noqa: BLE001 - rcl refused it: the client's answer, not a crash
            self._done()
            task.fail(IpcError("service-unavailable", f"Sending the request to {pooled.path} failed: {exc}",
                               {"service": pooled.path}))
            return
        pooled.calls[seq] = (task, deadline)

    def poll(self) -> None:
        now = self.polled = time.monotonic()
        for pooled in list(self.entries.values()):
            if pooled.waiting:
                ready = pooled.ready(now)
                still = []
                for task, request, deadline, ready_by in pooled.waiting:
                    if ready and len(pooled.calls) < MAX_IN_FLIGHT and now < deadline:
                        self._send(pooled, task, request, deadline)
                    elif now >= deadline:
                        self._done()
                        self.stats.operation_timeouts += 1
                        task.fail(IpcError("not-responding", f"The call to {pooled.path} waited in line for "
                                                             "the whole service call timeout; it was not sent",
                                           {"service": pooled.path}))
                    elif now >= ready_by and pooled.ready_since is None:
                        self._done()
                        task.fail(IpcError("service-unavailable", f"No server of {pooled.path} is available",
                                           {"service": pooled.path}))
                    else:
                        still.append((task, request, deadline, ready_by))
                pooled.waiting = still
            if not pooled.calls:
                continue
            while True:
                with pooled.client.handle:
                    header, response = pooled.client.handle.take_response(pooled.srv.Response)
                if header is None:
                    break
                waiting = pooled.calls.pop(header.request_id.sequence_number, None)
                if waiting is None:
                    continue  # answered after its deadline: nobody waits any more
                self._done()
                try:
                    waiting[0].reply({"response": to_plain(response)})
                except Exception as exc:  # noqa: BLE001 - a response that does not encode
                    waiting[0].fail(IpcError("internal", f"The response of {pooled.path} could not be "
                                                         f"encoded: {exc}", {"service": pooled.path}))
            for seq, (task, deadline) in list(pooled.calls.items()):
                if now >= deadline:
                    del pooled.calls[seq]
                    self._done()
                    self.stats.operation_timeouts += 1
                    task.fail(IpcError("not-responding",
                                       f"The server of {pooled.path} did not answer within the "
                                       "service call timeout; the call may or may not have been carried out",
                                       {"service": pooled.path}))

    def _done(self) -> None:
        self.in_flight -= 1
        self.stats.operation_calls_in_flight = self.in_flight

    def _destroy(self, path: str, cause: str) -> None:
        pooled = self.entries.pop(path)
        for task, *_ in [*pooled.calls.values(), *pooled.waiting]:
            self._done()
            task.fail(IpcError("service-unavailable", f"The client of {path} was dropped ({cause}) before "
                                                      "its server answered; the call may or may not have "
                                                      "been carried out", {"service": path}))
        pooled.calls.clear()
        pooled.waiting.clear()
        self._count()
        try:
            self.node.destroy_client(pooled.client)
        except Exception:
            log.exception("destroying the client of %s failed", path)

    def _count(self) -> None:
        self.stats.operation_service_clients = len(self.entries)

    def check_graph(self) -> None:
        """Drop idle clients whose server left the graph, or whose path now carries another type."""
        now = time.monotonic()
        names: dict[str, list[str]] | None = None
        for path, pooled in list(self.entries.items()):
            if pooled.calls or pooled.waiting or now - pooled.last_used < MATCH_WAIT:
                continue
            if not pooled.client.service_is_ready():
                self._destroy(path, "server-left")
                continue
            if names is None:
                names = dict(self.node.get_service_names_and_types())
            if set(names.get(path, ())) - {pooled.type_name}:
                self._destroy(path, "type-change")

    def sweep_idle(self) -> None:
        if not self.idle:
            return
        limit = time.monotonic() - self.idle
        for path in [p for p, e in self.entries.items() if e.last_used < limit and not e.calls
                     and not e.waiting]:
            self._destroy(path, "idle")

    def shutdown(self) -> None:
        for path in list(self.entries):
            self._destroy(path, "shutdown")
