"""The logs family: the robot's ``/rosout``, per entity, as medkit serves it.

- ``routes.py``: ``{entity}/logs`` and ``{entity}/logs/configuration``;
- ``resources.py``: the logs as triggers observe them;
- ``spec.py``: its part of the OpenAPI document.
"""

from __future__ import annotations

from ..core.family import Family, Health, counters_section
from . import resources, routes, spec

FAMILY = Family(
    name="logs",
    blueprints=(routes.bp,),
    spec=spec.SPEC,
    health=(Health("x-medkit-logs", counters_section("logs"), spec.HEALTH_SCHEMA),),  # /rosout's ring buffers
    capabilities=lambda cfg: {"logs": True},
    setup=resources.setup,
)
