"""Lifecycle status: whether a node is ready, for ``GET /{apps|components}/{id}/status`` (``lifecycle_state``).

medkit's default path (``lifecycle_handlers.cpp``, ``lifecycle_status_helpers.cpp``): a node that
offers a ``lifecycle_msgs/srv/GetState`` and a ``lifecycle_msgs/srv/ChangeState`` service is a
managed node, and it is ready only in the state labelled ``active``; any other node in the graph is
ready.  This module answers the first part: is the node managed, and if so its state's label.

The ``get_state`` call is the operations' (``rosworker/operations/services.py``): a pooled client, the request
sent on the ROS thread and its answer taken by the executor's poller, never waited on.  It has
``STATE_TIMEOUT`` s in all (a new client's matching included; medkit's reader: half a second for the
service to show, half a second for the answer), less when the request's deadline is nearer.  A node
that does not answer in time has no state (medkit: notReady); when its client had been matched to it
for ``ANSWER_MIN`` s or more, so that it had its chance, its ``get_state`` path is answered at once,
with no state, for ``NEGATIVE_CACHE_S`` s: a hung node costs one request its timeout, not every
request (a client not matched in time is no verdict on the node: the next request asks again).
"""

from __future__ import annotations

import collections
import time
from typing import Any

from ipc.errors import IpcError

from ..core import args
from ..core.task import Task
from .interfaces import load_interface
from .services import SETTLE, ServiceClients

GET_STATE = "lifecycle_msgs/srv/GetState"
CHANGE_STATE = "lifecycle_msgs/srv/ChangeState"
STATE_TIMEOUT = 1.5       # seconds a get_state call has, from the request (matching its client included)
ANSWER_MIN = 0.5          # seconds a matched client's request must have had before "did not answer" counts
NEGATIVE_CACHE_S = 10.0   # seconds a node that did not answer is answered at once (no state)
MAX_UNANSWERED = 4096     # nodes remembered as not answering (the oldest go first)
ANSWER_MARGIN = 0.1       # seconds before the request's deadline by which it is answered


def get_state_path(services: list[tuple[str, list[str]]]) -> str | None:
    """The node's get_state service when it offers both lifecycle services (medkit's rule), else None."""
    get_state, change_state = None, False
    for path, types in services:
        if GET_STATE in types:
            get_state = path
        elif CHANGE_STATE in types:
            change_state = True
    return get_state if change_state else None


class _Reply:
    """What :meth:`ServiceClients.call` answers, turned into this command's answer."""

    __slots__ = ("task", "owner", "path")

    def __init__(self, task: Task, owner: LifecycleStates, path: str):
        self.task, self.owner, self.path = task, owner, path

    def reply(self, result: dict[str, Any]) -> None:
        state = (result.get("response") or {}).get("current_state") or {}
        label = state.get("label")
        self.task.reply({"managed": True, "state": label if isinstance(label, str) else None})

    def fail(self, error: IpcError) -> None:
        pooled = self.owner.services.entries.get(self.path)
        since = pooled.ready_since if pooled is not None else None
        if since is not None and time.monotonic() - since >= SETTLE + ANSWER_MIN:
            self.owner.unanswered(self.path)  # it could be asked, and did not answer
        self.task.reply({"managed": True, "state": None, "error": error.message[:300]})


class LifecycleStates:
    """The ``lifecycle_state`` command (ROS thread only)."""

    def __init__(self, node, services: ServiceClients):
        self.node = node
        self.services = services
        self._unanswered: collections.OrderedDict[str, float] = collections.OrderedDict()  # path -> until
        self.handlers = {"lifecycle_state": self.cmd_state}

    def unanswered(self, path: str) -> None:
        self._unanswered[path] = time.monotonic() + NEGATIVE_CACHE_S
        self._unanswered.move_to_end(path)
        while len(self._unanswered) > MAX_UNANSWERED:
            self._unanswered.popitem(last=False)

    def cmd_state(self, task: Task) -> None:
        fqn = args.node(task.args)
        namespace, _, name = fqn.rpartition("/")
        try:
            services = self.node.get_service_names_and_types_by_node(name, namespace or "/")
        except Exception:  # noqa: BLE001 - the node is not in the graph (any more)
            task.reply({"managed": False, "state": None, "online": False})
            return
        path = get_state_path(services)
        if path is None:
            task.reply({"managed": False, "state": None})
            return
        now = time.monotonic()
        until = self._unanswered.get(path)
        if until is not None and until > now:
            task.reply({"managed": True, "state": None, "cached": True})
            return
        self._unanswered.pop(path, None)
        timeout = min(STATE_TIMEOUT, task.deadline - now - ANSWER_MARGIN)
        if timeout <= 0:
            raise IpcError("deadline-exceeded", "No time left to ask the node its lifecycle state", {"node": fqn})
        self.services.call(_Reply(task, self, path), path, GET_STATE, load_interface(GET_STATE, "srv"), {}, timeout)
