"""The configurations family: the ROS 2 parameters of an entity's nodes (SOVD configurations).

- ``routes.py``: ``{entity}/configurations`` (list, read, set, reset one, reset all);
- ``resources.py``: a parameter as cyclic subscriptions stream it;
- ``spec.py``: its part of the OpenAPI document.
"""

from __future__ import annotations

from typing import Any

from ..core.family import Family, Health
from . import resources, routes, spec

# /health's x-medkit-configurations: the parameter counters of the ROS worker's ``details`` (ipc/counters.py).
KEYS = ("parameter_clients", "parameter_client_cap", "parameter_calls_in_flight", "parameter_waiting",
        "parameter_waits", "parameter_calls", "parameter_resends", "parameter_timeouts", "parameter_events")


def health(stats: dict[str, Any] | None, cfg: Any) -> dict[str, Any]:
    """The ROS worker's parameter counters (its ``details``); the cap from the settings before it answers."""
    details = (stats or {}).get("details")
    details = details if isinstance(details, dict) else {}
    section = {key: details.get(key, 0) for key in KEYS}
    if not details:
        section["parameter_client_cap"] = cfg.max_parameter_clients
    return section


FAMILY = Family(
    name="configurations",
    blueprints=(routes.bp,),
    spec=spec.SPEC,
    health=(Health("x-medkit-configurations", health),),
    capabilities=lambda cfg: {"configurations": True,  # ui: the Parameters panel shows its editor when writes are on
                              "configuration_writes": bool(cfg.allow_configurations)},
    setup=resources.setup,
)
