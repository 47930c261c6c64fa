"""What the ROS worker keeps per entity for a family, by id: the shared half of their routes.

Cyclic subscriptions (``sub_*`` commands, ids ``sub_<16 hex>``) and triggers
(``trig_*``, ``trig_<16 hex>``) are records of the ROS worker, one list per
entity; their routes list, get, update, delete and stream them the same way.
:class:`Records` is that way: the entity looked up first, an id that cannot be
one answered 404 without asking the ROS worker, the worker's ``no-such-...``
answered as the contract's 404 naming the record (``roscall.py``).  A family
keeps its own body checks and its own SOVD shape of a record.
"""

from __future__ import annotations

import re
from typing import Any

from flask import Response, current_app

from .common import json_response, lookup
from .entities import Entity
from .errors import ApiError
from .roscall import ros_call


class Records:
    """The records of one family: ``prefix`` names its commands and ids (``"sub"``: ``sub_get``,
    ``sub_0123...``), ``label`` its 404 (``"Subscription"``), ``id_param`` the 404's parameter."""

    def __init__(self, prefix: str, label: str, id_param: str, missing: str):
        self.prefix = prefix
        self.label = label
        self.id_param = id_param
        self.missing = missing                      # the ROS worker's error code: "no-such-subscription"
        self.pattern = re.compile(rf"^{prefix}_[0-9a-f]{{16}}$")

    def call(self, cmd: str, args: dict[str, Any], record_id: str | None = None) -> dict[str, Any]:
        """``<prefix>_<cmd>`` on the ROS worker; its ``missing`` answered as a 404 naming ``record_id``."""
        return ros_call(f"{self.prefix}_{cmd}", args, not_found={
            self.missing: (f"{self.label} not found", {self.id_param: (record_id or "")[:100]})})

    def not_found(self, record_id: str) -> ApiError:
        return ApiError(404, "resource-not-found", f"{self.label} not found", {self.id_param: record_id[:100]})

    def of(self, cmd: str, collection: str, entity: Entity, record_id: str, **extra: Any) -> dict[str, Any]:
        """``cmd`` on one record of ``entity`` (an id that cannot be one: 404 at once)."""
        if not self.pattern.match(record_id):
            raise self.not_found(record_id)
        return self.call(cmd, {"collection": collection, "entity_id": entity.id, "id": record_id, **extra},
                         record_id)

    def get(self, collection: str, entity_id: str, record_id: str) -> dict[str, Any]:
        """One record, the entity looked up first."""
        return self.of("get", collection, lookup(collection, entity_id), record_id)

    def listing(self, collection: str, entity_id: str) -> list[dict[str, Any]]:
        entity = lookup(collection, entity_id)
        return self.call("list", {"collection": collection, "entity_id": entity.id}).get("items") or []

    def delete(self, collection: str, entity_id: str, record_id: str) -> Response:
        """``DELETE``: 204 (a write: the role and lock checks ran before the route)."""
        self.of("delete", collection, lookup(collection, entity_id), record_id)
        return current_app.response_class(status=204)


def created(answer: dict[str, Any]) -> Response:
    """201 with a new record's body; ``Location``: the record (its ``event_source`` without ``/events``)."""
    return json_response(answer, 201, headers={"Location": answer["event_source"].removesuffix("/events")})
