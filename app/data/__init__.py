"""The data family: an entity's data items, one sample of a topic, publishing one message.

- ``routes.py``: ``{entity}/data``, ``{entity}/data/{data_id}`` (GET, PUT); ``checks.py``: what a request
  carries; ``model.py``: a sample's body, or its error;
- ``resources.py``: topics as cyclic subscriptions stream them and triggers observe them;
- ``spec.py``: its part of the OpenAPI document.
"""

from __future__ import annotations

from typing import Any

from ipc import counters

from ..core.family import Family, Health
from . import resources, routes, spec


def provider(stats: dict[str, Any] | None, cfg: Any) -> dict[str, Any]:
    """/health's x-medkit-data-provider: the pool's counters, and its evictions by cause."""
    section = counters.health_defaults("data_provider", cfg)
    section["evictions"] = {}  # evictions_total by cause, as the ROS worker counts them
    if stats:
        if isinstance(stats.get("data_provider"), dict):
            section.update(stats["data_provider"])
        details = stats.get("details")
        if isinstance(details, dict) and isinstance(details.get("evictions"), dict):
            section["evictions"] = dict(details["evictions"])
    return section


FAMILY = Family(
    name="data",
    blueprints=(routes.bp,),
    spec=spec.SPEC,
    health=(Health("x-medkit-data-provider", provider, spec.HEALTH_SCHEMA, required=True),),
    capabilities=lambda cfg: {"data_access": True, "publishing": bool(cfg.allow_publish)},
    setup=resources.setup,
)
