"""The triggers family: SOVD condition triggers, and their event streams over Server-Sent Events.

- ``routes.py``: ``{entity}/triggers`` (create, list, get, update, delete, events);
- ``hub.py``: the HTTP worker's streams of them (``app/sse/``);
- ``spec.py``: its part of the OpenAPI document.

What a trigger may observe is any collection a family made observable (``core/resources.py``: the
data family's topics, the faults, the logs); this family knows none of them.
"""

from __future__ import annotations

from ..core.family import Family
from . import hub, routes, spec

FAMILY = Family(
    name="triggers",
    blueprints=(routes.bp,),
    spec=spec.SPEC,
    capabilities=lambda cfg: {"triggers": True},
    setup=hub.setup,
)
