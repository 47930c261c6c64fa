"""The pool of parameter client sets: one set of four clients per node (ROS thread only).

Every node's parameters are read and changed through its own services
(``rcl_interfaces``: ``list_parameters``, ``describe_parameters``,
``get_parameters``, ``set_parameters``).  :class:`ClientPool` makes a node's
:class:`NodeClients` when an operation first needs it and keeps at most
``max_parameter_clients`` sets, least recently used first: at the cap the
least recently used set that no operation holds and no call is open on goes;
when every set is held, none is made (the operation waits in line for one,
``clients.py``).  A set unused for ``parameter_client_idle_s`` is destroyed by
the idle sweep.

A set sends a request with its client handle's ``send_request`` and takes the
responses with ``take_response`` (:meth:`NodeClients.responses`, from the
operations' poll in ``clients.py``): no future, no spin.  It knows which
operation's request each sequence number is.  The requests of an operation
that timed out stay listened for (``LATE``, the last ``MAX_LATE`` per set), so
that a node that answers one late is told slow from hung.
"""

from __future__ import annotations

import collections
import logging
import time
from collections.abc import Iterator
from typing import Any

from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
from rclpy.qos import qos_profile_parameters

from ..core.stats import Stats

log = logging.getLogger("sovd.rosworker.parameters")

SERVICES = {"list": ListParameters, "describe": DescribeParameters, "get": GetParameters,
            "set": SetParameters}
SERVICE_NAMES = {"list": "list_parameters", "describe": "describe_parameters", "get": "get_parameters",
                 "set": "set_parameters"}
MAX_LATE = 16                        # requests of timed-out operations per node still listened for
LATE = ("late", -1)                  # their entry in NodeClients.pending

Sent = list[tuple[str, int]]         # (service kind, sequence number) of the requests sent for one step


class NodeClients:
    """One node's four parameter clients, the calls open on each, the operations that hold them and when
    they were last used."""

    __slots__ = ("fqn", "clients", "pending", "used", "ops", "ready")

    def __init__(self, fqn: str, clients: dict[str, Any]):
        self.fqn = fqn
        self.clients = clients
        # kind -> sequence number -> (operation, request index), or LATE
        self.pending: dict[str, dict[int, tuple[Any, int]]] = {kind: {} for kind in clients}
        self.used = time.monotonic()
        self.ops = 0              # operations in flight on this set: it is not given to another node
        self.ready: dict[str, float] = {}  # kind -> when its server was first seen matched

    def open_calls(self) -> int:
        return sum(1 for p in self.pending.values() for entry in p.values() if entry is not LATE)

    def send(self, kind: str, request: Any, entry: tuple[Any, int]) -> int:
        """Send ``request`` on the ``kind`` client; its answer goes to ``entry``.  Its sequence number."""
        client = self.clients[kind]
        with client.handle:
            seq = client.handle.send_request(request)
        self.pending[kind][seq] = entry
        return seq

    def responses(self) -> Iterator[tuple[Any, Any]]:
        """Take every response that came: ``(entry, response)``, ``entry`` being what the request was sent
        for (or ``LATE``); one to a request no longer awaited is dropped."""
        for kind, pending in self.pending.items():
            client = self.clients[kind]
            while pending:
                with client.handle:
                    header, response = client.handle.take_response(client.srv_type.Response)
                if header is None:
                    break
                entry = pending.pop(header.request_id.sequence_number, None)
                if entry is not None:
                    yield entry, response

    def forget(self, sent: Sent) -> None:
        """No answer is awaited any more for these requests (a late one is dropped)."""
        for kind, seq in sent:
            self.pending[kind].pop(seq, None)

    def await_late(self, sent: Sent) -> None:
        """Keep listening for these requests' answers (at most ``MAX_LATE`` per set, the oldest go)."""
        for kind, seq in sent:
            self.pending[kind][seq] = LATE
        late = [(kind, seq) for kind, p in self.pending.items() for seq, entry in p.items() if entry is LATE]
        for kind, seq in late[:max(0, len(late) - MAX_LATE)]:
            del self.pending[kind][seq]


class ClientPool:
    """The client sets by node, the least recently used first (ROS thread only)."""

    def __init__(self, node, stats: Stats, *, max_clients: int, idle_s: float):
        self.node = node
        self.stats = stats
        self.max_clients = max_clients
        self.idle_s = idle_s
        self._sets: collections.OrderedDict[str, NodeClients] = collections.OrderedDict()
        stats.parameter_client_cap = max_clients

    def get(self, fqn: str) -> NodeClients | None:
        """The node's set if it has one (made by :meth:`acquire`)."""
        return self._sets.get(fqn)

    def sets(self) -> list[NodeClients]:
        return list(self._sets.values())

    def acquire(self, fqn: str, queued: bool = False) -> NodeClients | None:
        """The node's client set, made (the least recently used free one goes at the cap); None when
        every set is held by an operation in flight, or ``queued`` (others wait in line before it).
        Raises what rclpy raises when it refuses a client."""
        clients = self._sets.get(fqn)
        if clients is not None:
            self._sets.move_to_end(fqn)
            return clients
        if queued:
            return None
        while len(self._sets) >= self.max_clients:
            idle = next((f for f, c in self._sets.items() if not c.ops and not c.open_calls()), None)
            if idle is None:
                return None
            self.destroy(idle)
        made = {}
        try:
            for kind, srv in SERVICES.items():
                made[kind] = self.node.create_client(srv, f"{fqn}/{SERVICE_NAMES[kind]}",
                                                     qos_profile=qos_profile_parameters)
        except Exception:
            for client in made.values():
                self.node.destroy_client(client)
            raise
        clients = self._sets[fqn] = NodeClients(fqn, made)
        self.stats.parameter_clients = len(self._sets)
        return clients

    def sweep(self) -> None:
        """Destroy the sets unused for ``idle_s`` (none that an operation holds or a call is open on)."""
        cutoff = time.monotonic() - self.idle_s
        for fqn, clients in list(self._sets.items()):
            if clients.used < cutoff and not clients.ops and not clients.open_calls():
                self.destroy(fqn)

    def destroy(self, fqn: str) -> None:
        clients = self._sets.pop(fqn, None)
        if clients is None:
            return
        for client in clients.clients.values():
            try:
                self.node.destroy_client(client)
            except Exception:
                log.exception("destroying a parameter client of %s failed", fqn)
        self.stats.parameter_clients = len(self._sets)

    def close(self) -> None:
        for fqn in list(self._sets):
            self.destroy(fqn)
