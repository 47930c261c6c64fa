"""The subscriptions family: SOVD cyclic subscriptions, and their streams over Server-Sent Events.

- ``routes.py``: ``{entity}/cyclic-subscriptions`` (create, list, get, update, delete, events);
- ``hub.py``: the HTTP worker's streams of them (``app/sse/``);
- ``spec.py``: its part of the OpenAPI document.

What a subscription may watch is any collection a family made streamable (``core/resources.py``:
the data family's topics, the operations' executions, the configurations' parameters); this family
knows none of them.
"""

from __future__ import annotations

from ..core.family import Family
from . import hub, routes, spec

FAMILY = Family(
    name="subscriptions",
    blueprints=(routes.bp,),
    spec=spec.SPEC,
    capabilities=lambda cfg: {"cyclic_subscriptions": True},
    setup=hub.setup,
)
