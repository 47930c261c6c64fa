"""``{entity}/cyclic-subscriptions``: SOVD cyclic subscriptions, streamed over Server-Sent Events.

The routes check what a client sends (medkit's rules and error texts) and keep
the subscriptions with their single owner, the ROS worker (``sub_*``
commands), so that any HTTP worker can stream a subscription made through
another.  The stream itself is ``app/subscriptions/hub.py``.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any
from urllib.parse import unquote

from flask import Blueprint, request

from ipc.events import INTERVALS

from ..core.bodies import json_object
from ..core.common import config, json_response, lookup
from ..core.entities import API_BASE
from ..core.errors import ApiError
from ..core.records import Records, created
from ..core.resources import bad, client, parse_resource, streamables, vendor
from ..sse import hub as sse
from . import hub

bp = Blueprint("subscriptions", __name__, url_prefix=API_BASE)

ENTITY = "/<any(apps, components, functions):collection>/<entity_id>"
SUBSCRIPTIONS = Records("sub", "Subscription", "subscription_id", "no-such-subscription")


def _body() -> dict[str, Any]:
    return json_object('{"resource", "interval", "duration", "protocol"}')


def _given(body: dict[str, Any], field: str, required: bool) -> Any:
    """The body's ``field``; None where it is missing or null, which a create refuses."""
    value = body.get(field)
    if value is None and required:
        raise bad(f"{field}: missing required field", field, None)
    return value


def _interval(body: dict[str, Any], required: bool) -> str | None:
    value = _given(body, "interval", required)
    if value is None:
        return None
    if not isinstance(value, str) or value not in INTERVALS:
        raise bad("Invalid interval. Must be 'fast', 'normal', or 'slow'.", "interval",
                   value if isinstance(value, (str, int, float)) else str(value)[:100])
    return value


def _duration(body: dict[str, Any], required: bool) -> int | None:
    value = _given(body, "duration", required)
    if value is None:
        return None
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise bad("Duration must be a positive integer (seconds).", "duration",
                   value if isinstance(value, (int, float)) else str(value)[:100])
    limit = config().max_stream_duration
    if value > limit:
        raise ApiError(400, "invalid-parameter", f"Duration must not exceed {limit} seconds.",
                       {"parameter": "duration", "max_value": limit})
    return value


def public(sub: dict[str, Any]) -> dict[str, Any]:
    """The SOVD body of a subscription from the ROS worker's record of it."""
    base = f"{API_BASE}/{sub['collection']}/{sub['entity_id']}/cyclic-subscriptions/{sub['id']}"
    expires = datetime.fromtimestamp(sub["expires_at_ns"] / 1e9, UTC)
    return {"id": sub["id"], "observed_resource": sub["resource"], "event_source": base + "/events",
            "protocol": "sse", "interval": sub["interval"], "duration": sub["duration"],
            "expires_at": expires.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"}


@bp.post(ENTITY + "/cyclic-subscriptions")
def create(collection: str, entity_id: str):
    entity = lookup(collection, entity_id)
    body = _body()
    protocol = body.get("protocol", "sse")
    if protocol != "sse":
        raise vendor("x-medkit-unsupported-protocol", f"Protocol '{str(protocol)[:50]}' not available",
                      {"parameter": "protocol", "value": str(protocol)[:100]})
    interval = _interval(body, required=True)
    duration = _duration(body, required=True)
    resource = parse_resource(body.get("resource"), collection, entity.id)
    streamable = streamables().get(resource.what)  # the family whose collection it is (core/resources.py)
    if streamable is None:
        what = unquote(resource.what)[:100]
        raise vendor("x-medkit-collection-not-supported", f"Collection '{what}' not supported for {collection}",
                     {"collection": what, "entity_type": collection})
    target = streamable.resolve(resource, entity)   # a topic and bytes mode, or a kind and its target
    return created(public(SUBSCRIPTIONS.call("create", {
        "collection": collection, "entity_id": entity.id, "resource": body["resource"], "bytes": "array",
        **target, "interval": interval, "duration": duration, "client": client()})))


@bp.get(ENTITY + "/cyclic-subscriptions")
def listing(collection: str, entity_id: str):
    return json_response({"items": [public(s) for s in SUBSCRIPTIONS.listing(collection, entity_id)]})


@bp.get(ENTITY + "/cyclic-subscriptions/<sub_id>")
def detail(collection: str, entity_id: str, sub_id: str):
    return json_response(public(SUBSCRIPTIONS.get(collection, entity_id, sub_id)))


@bp.put(ENTITY + "/cyclic-subscriptions/<sub_id>")
def update(collection: str, entity_id: str, sub_id: str):
    entity = lookup(collection, entity_id)
    body = _body()
    interval = _interval(body, required=False)
    duration = _duration(body, required=False)
    return json_response(public(SUBSCRIPTIONS.of("update", collection, entity, sub_id, interval=interval,
                                                 duration=duration)))


@bp.delete(ENTITY + "/cyclic-subscriptions/<sub_id>")
def delete(collection: str, entity_id: str, sub_id: str):
    return SUBSCRIPTIONS.delete(collection, entity_id, sub_id)


@bp.get(ENTITY + "/cyclic-subscriptions/<sub_id>/events")
def events(collection: str, entity_id: str, sub_id: str):
    return sse.response(hub.body(SUBSCRIPTIONS.get(collection, entity_id, sub_id), request.environ))
