"""Faults as a collection to observe (``core/notifier.py``): every fault event, in an entity's scope.

Event-driven: no subscription and no polling of its own.  The fault manager
calls :meth:`FaultObservable.on_fault` on each fault event (ROS thread), and only
while an observer exists, so events nobody watches cost one attribute test.

An observer's target is an entity's scope (``core/notifier.py`` ``parse_scope``):
``{"nodes": [FQN, ...], "code": CODE | null}`` (``""``: every fault).  A fault
belongs to the scope when every one of its reporting sources is one of
``nodes`` or below one (medkit's all-sources scope, :func:`in_scope`) and, with a
``code``, when it is that fault.  The change handed on is medkit's
(``trigger_fault_subscriber.cpp``): the fault as ``GET /faults`` lists it plus
``event_type`` (``fault_confirmed``, ``fault_updated``, ``fault_cleared``).
"""

from __future__ import annotations

import time
from typing import Any

from ..core.notifier import ScopedObservable


def in_scope(sources: Any, nodes: list[str] | None) -> bool:
    """medkit's all-sources rule: every one of ``sources`` is one of ``nodes`` or below one (None: any)."""
    if nodes is None:
        return True
    if not nodes or not isinstance(sources, list) or not sources:
        return False
    return all(isinstance(s, str) and any(s == f or s.startswith(f.rstrip("/") + "/") for f in nodes)
               for s in sources)


class FaultObservable(ScopedObservable):
    with_code = True

    def on_fault(self, event_type: str, fault: dict[str, Any]) -> None:
        """A fault event (ROS thread, from the fault manager)."""
        code, sources = fault.get("fault_code"), fault.get("reporting_sources")
        watchers = [o for o in list(self.observers)
                    if self.scope(o)["code"] in (None, code) and in_scope(sources, self.scope(o)["nodes"])]
        if watchers:
            self.notify(watchers, {**fault, "event_type": event_type}, time.time_ns())
