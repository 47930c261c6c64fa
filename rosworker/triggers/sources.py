"""Faults and logs as observable resources of triggers (medkit's ``faults`` and ``logs`` collections).

Two more kinds of :data:`rosworker.triggers.registry.SOURCES`, event-driven: no
subscription and no polling of their own (``active`` is always false).  The
fault manager (``faults.py``) calls :meth:`FaultSource.on_fault` on each fault
event, and the log book (``logs.py``) :meth:`LogSource.on_line` on each line it
buffers, both on the ROS thread, and only while a trigger of that kind exists:
the hook is set on the first trigger and cleared with the last, so faults and
lines nobody watches cost one attribute test.

Targets.  The HTTP side resolves the entity's scope when the trigger is made
and sends it as the trigger's ``target`` (JSON): ``{"nodes": [FQN, ...]}``
for logs, ``{"nodes": [...], "code": CODE | null}`` for faults.  The rules are
those of the faults and logs routes: a fault belongs to the entity when every
one of its reporting sources is one of ``nodes`` or below one (medkit's
all-sources scope); a line when its logger name is one of the nodes' in slash
or dot form.

Payloads, as medkit's code sends them: a fault event's is the fault as
``GET /faults`` lists it plus ``event_type`` (``fault_confirmed``,
``fault_updated``, ``fault_cleared``; ``trigger_fault_subscriber.cpp``); a
line's is the entry as ``GET /logs`` lists it (``log_manager.cpp``
``entry_to_json``).  The condition is evaluated on the payload, or on the
value at ``path`` in it (a payload without that path is not evaluated).
"""

from __future__ import annotations

import json
import logging
import time
from typing import Any

import orjson

from ipc import jsonpointer
from ipc.errors import IpcError

log = logging.getLogger("sovd.rosworker.triggersources")

MAX_NODES = 10000
LEVELS = {10: "debug", 20: "info", 30: "warning", 40: "error", 50: "fatal"}


def parse_target(text: str, with_code: bool) -> dict[str, Any]:
    """The scope a trigger's ``target`` names; IpcError("bad-request") when it is not one."""
    try:
        doc = json.loads(text)
    except ValueError:
        doc = None
    nodes = doc.get("nodes") if isinstance(doc, dict) else None
    if not isinstance(nodes, list) or len(nodes) > MAX_NODES \
            or not all(isinstance(n, str) and n.startswith("/") for n in nodes):
        raise IpcError("bad-request", "target: expected {\"nodes\": [node names]}")
    out: dict[str, Any] = {"nodes": sorted(set(nodes))}
    if with_code:
        code = doc.get("code")
        if code is not None and (not isinstance(code, str) or not code or len(code) > 256):
            raise IpcError("bad-request", "target: code must be a fault code or null")
        out["code"] = code
    return out


def in_scope(sources: Any, nodes: list[str]) -> bool:
    """The faults routes' rule: every reporting source is one of ``nodes`` or below one."""
    if not nodes or not isinstance(sources, list) or not sources:
        return False
    return all(isinstance(s, str) and any(s == f or s.startswith(f.rstrip("/") + "/") for f in nodes)
               for s in sources)


class _EventSource:
    """What faults and logs share: the triggers of the kind, the hook, one evaluation per event."""

    kind = ""
    with_code = False

    def __init__(self, registry):
        # Imported here, not at the top: triggers.py imports this module at its end.
        from .registry import fires

        self.registry = registry
        self.stats = registry.stats
        self._fires = fires
        self.triggers: list = []
        self.scopes: dict[str, dict[str, Any]] = {}   # trigger id -> its parsed target
        self.owner = None                               # the FaultManager or LogBook, once bound

    def active(self) -> bool:
        return False  # event-driven: the executor never polls this source

    def poll(self) -> None:  # pragma: no cover - never called (active() is false)
        pass

    def bind(self, owner) -> None:
        """The fault manager or log book whose events this source sees (main.py, before restore)."""
        self.owner = owner
        self._hook()

    def check_target(self, text: str) -> None:
        """Refuse a target that names no scope (at create and restore, before the trigger is added)."""
        parse_target(text, self.with_code)

    def attach(self, trigger) -> None:
        self.scopes[trigger.id] = parse_target(trigger.target, self.with_code)
        self.triggers.append(trigger)
        self._indexed()
        self._hook()

    def detach(self, trigger) -> None:
        if trigger in self.triggers:
            self.triggers.remove(trigger)
            self.scopes.pop(trigger.id, None)
            self._indexed()
            self._hook()

    def close(self) -> None:
        self.triggers.clear()
        self.scopes.clear()
        self._indexed()
        self._hook()

    def _indexed(self) -> None:
        pass

    def _hook(self) -> None:
        raise NotImplementedError

    def _evaluate(self, watchers: list, payload: dict[str, Any], stamp: int) -> None:
        """Each watching trigger's condition on ``payload`` (or the value at its path); fire the ones that hold."""
        text: bytes | None = None
        for trigger in watchers:
            value = jsonpointer.resolve(payload, trigger.tokens)
            if value is jsonpointer.MISSING:
                continue
            previous, trigger.previous = trigger.previous, value
            if self._fires(trigger.condition, previous, value):
                if text is None:
                    text = orjson.dumps(payload)
                self.registry.fire(trigger, stamp, payload=text)


class FaultSource(_EventSource):
    """``…/faults`` and ``…/faults/{code}``: evaluated on every fault event of the entity's scope."""

    kind = "faults"
    with_code = True

    def _hook(self) -> None:
        if self.owner is not None:
            self.owner.trigger_hook = self.on_fault if self.triggers else None

    def on_fault(self, event_type: str, fault: dict[str, Any]) -> None:
        """A fault event (ROS thread, from ``FaultManager._event``)."""
        code, sources = fault.get("fault_code"), fault.get("reporting_sources")
        watchers = [t for t in list(self.triggers)
                    if (self.scopes[t.id]["code"] in (None, code)) and in_scope(sources, self.scopes[t.id]["nodes"])]
        if watchers:
            self.stats.trigger_messages += 1
            self._evaluate(watchers, {**fault, "event_type": event_type}, time.time_ns())


class LogSource(_EventSource):
    """``…/logs``: evaluated on every line of the entity's nodes, as the log book buffers it."""

    kind = "logs"

    def __init__(self, registry):
        super().__init__(registry)
        self.by_logger: dict[str, list] = {}   # logger name (slash and dot form) -> its triggers

    def _indexed(self) -> None:
        from ..logs.book import names_of

        index: dict[str, list] = {}
        for trigger in self.triggers:
            names = {name for fqn in self.scopes[trigger.id]["nodes"] for name in names_of(fqn)}
            for name in names:
                index.setdefault(name, []).append(trigger)
        self.by_logger = index

    def _hook(self) -> None:
        if self.owner is not None:
            self.owner.trigger_hook = self.on_line if self.triggers else None

    def on_line(self, entry) -> None:
        """A line the log book buffered (ROS thread, from ``LogBook.add``)."""
        watchers = self.by_logger.get(entry.name)
        if not watchers:
            return
        self.stats.trigger_messages += 1
        self._evaluate(list(watchers), entry_json(entry), time.time_ns())


def entry_json(entry) -> dict[str, Any]:
    """medkit's ``entry_to_json``: the line as ``GET …/logs`` lists it (``app/routes/logs.py`` ``item``)."""
    context: dict[str, Any] = {"node": entry.name}
    if entry.function:
        context["function"] = entry.function
    if entry.file:
        context["file"] = entry.file
    if entry.line:
        context["line"] = entry.line
    whole = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(entry.sec))
    return {"id": f"log_{entry.id}", "timestamp": f"{whole}.{min(entry.nanosec, 999_999_999):09d}Z",
            "severity": LEVELS.get(entry.level, "debug"), "message": entry.msg, "context": context}
