"""The operations family: an entity's ROS 2 services and actions, their executions, and its status.

- ``routes.py``: ``{entity}/operations``, ``…/{op_id}``, ``…/executions`` (call, goal, cancel, stop);
- ``status.py``: ``GET /{apps|components}/{id}/status`` (a managed node's lifecycle state);
- ``resources.py``: an execution as cyclic subscriptions stream it;
- ``spec.py``: its part of the OpenAPI document.
"""

from __future__ import annotations

from ..core.family import Family, Health, counters_section
from . import resources, routes, spec, status

FAMILY = Family(
    name="operations",
    blueprints=(routes.bp, status.bp),
    spec=spec.SPEC,
    # service and action clients, calls in flight, goals, timeouts (ipc/counters.py)
    health=(Health("x-medkit-operations", counters_section("operations"), spec.HEALTH_SCHEMA),),
    # executing them needs allow_operations
    capabilities=lambda cfg: {"operations": True, "async_actions": True,
                              "operation_execution": bool(cfg.allow_operations)},
    setup=resources.setup,
)
