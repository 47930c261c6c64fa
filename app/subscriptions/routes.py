"""``{entity}/cyclic-subscriptions``: SOVD cyclic subscriptions, streamed over Server-Sent Events.

The routes check what a client sends (medkit's rules and error texts) and keep
the subscriptions with their single owner, the ROS worker (``sub_*``
commands), so that any HTTP worker can stream a subscription made through
another.  The stream itself is ``app/subscriptions/hub.py``.
"""

from __future__ import annotations

import re
from datetime import UTC, datetime
from typing import Any
from urllib.parse import parse_qsl, unquote, urlsplit

from flask import Blueprint, current_app, request

from ipc.errors import IpcError
from ipc.events import INTERVALS
from ipc.protocol import BYTES_MODES
from ipc.topics import InvalidTopic, normalize_topic

from ..core import rosclient
from ..core.auth import authorize_change
from ..core.bodies import json_object
from ..core.common import BAD_PERCENT, config, json_response, lookup
from ..core.entities import API_BASE
from ..core.errors import ApiError
from . import feeds
from . import hub as streams

bp = Blueprint("subscriptions", __name__, url_prefix=API_BASE)

ENTITY = "/<any(apps, components, functions):collection>/<entity_id>"
MAX_RESOURCE_LENGTH = 4096
_RESOURCE = re.compile(r"^/api/v1/([^/?#]+)/([^/?#]+)/([^/?#]+)(/.*)?$")
_SUB_ID = re.compile(r"^sub_[0-9a-f]{16}$")
UNKNOWN_CLIENT = "unknown"


def _bad(message: str, parameter: str, value: Any, **extra: Any) -> ApiError:
    params = {"parameter": parameter, "value": value, **extra}
    return ApiError(400, "invalid-parameter", message, params)


def _vendor(code: str, message: str, params: dict[str, Any]) -> ApiError:
    return ApiError(400, "vendor-error", message, params, vendor_code=code)


def _body() -> dict[str, Any]:
    return json_object('{"resource", "interval", "duration", "protocol"}')


def _interval(body: dict[str, Any], required: bool) -> str | None:
    if "interval" not in body or body["interval"] is None:
        if required:
            raise _bad("interval: missing required field", "interval", None)
        return None
    value = body["interval"]
    if not isinstance(value, str) or value not in INTERVALS:
        raise _bad("Invalid interval. Must be 'fast', 'normal', or 'slow'.", "interval",
                   value if isinstance(value, (str, int, float)) else str(value)[:100])
    return value


def _duration(body: dict[str, Any], required: bool) -> int | None:
    if "duration" not in body or body["duration"] is None:
        if required:
            raise _bad("duration: missing required field", "duration", None)
        return None
    value = body["duration"]
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise _bad("Duration must be a positive integer (seconds).", "duration",
                   value if isinstance(value, (int, float)) else str(value)[:100])
    limit = config().max_stream_duration
    if value > limit:
        raise ApiError(400, "invalid-parameter", f"Duration must not exceed {limit} seconds.",
                       {"parameter": "duration", "max_value": limit})
    return value


def parse_resource(resource: Any, collection: str, entity_id: str,
                   others: tuple[str, ...] = ()) -> tuple[str, str]:
    """``(topic, bytes mode)`` of a resource URI that names ``data/{topic}`` of this entity; for a
    collection in ``others``, ``(collection, the rest of the path, still percent-encoded)``."""
    if resource is None:
        raise _bad("resource: missing required field", "resource", None)
    if not isinstance(resource, str) or not resource or len(resource) > MAX_RESOURCE_LENGTH:
        raise _bad(f"resource: must be a URI path of 1 to {MAX_RESOURCE_LENGTH} characters", "resource",
                   str(resource)[:300])

    def invalid(why: str) -> ApiError:
        return _vendor("x-medkit-invalid-resource-uri", "Invalid resource URI: " + why,
                       {"parameter": "resource", "value": resource[:300]})

    if any(ord(c) < 0x20 or c == "\x7f" for c in resource):
        raise invalid("it contains control characters")
    parts = urlsplit(resource)
    if parts.scheme or parts.netloc or parts.fragment:
        raise invalid("give the path only (/api/v1/{apps|components|functions}/{id}/data/{topic})")
    if BAD_PERCENT.search(parts.path):
        raise invalid("it contains an invalid percent-encoding")
    match = _RESOURCE.match(parts.path)
    if not match or match.group(1) not in ("apps", "components", "functions"):
        raise invalid("Resource URI must match /api/v1/{apps|components|functions}/{id}/{collection}[/{path}]")
    try:
        decoded = [unquote(part, errors="strict") for part in parts.path.split("/")]
    except UnicodeDecodeError:
        raise invalid("it does not decode to UTF-8") from None
    if any(seg in ("..", ".") for part in decoded for seg in part.split("/")):
        raise invalid("Resource path must not contain '..' as a path segment")
    kind, rid, what, rest = match.group(1), unquote(match.group(2)), match.group(3), match.group(4) or ""
    if kind != collection or rid != entity_id:
        raise _vendor("x-medkit-entity-mismatch", "Resource URI must reference the same entity as the route",
                      {"parameter": "resource", "value": resource[:300]})
    if what in others:  # feeds: executions and parameters (app/subscriptions/feeds.py)
        return what, rest
    if what != "data":
        raise _vendor("x-medkit-collection-not-supported",
                      f"Collection '{unquote(what)[:100]}' not supported for {collection}",
                      {"collection": unquote(what)[:100], "entity_type": collection})
    data_id = unquote(rest[1:])
    if not data_id.strip("/"):
        raise invalid("Data collection requires a resource path (e.g. /api/v1/apps/{id}/data/{topic})")
    try:
        topic = normalize_topic(data_id)
    except InvalidTopic as exc:
        raise invalid(str(exc)) from None
    mode = "array"
    for name, value in parse_qsl(parts.query, keep_blank_values=True):
        if name == "bytes":
            if value not in BYTES_MODES:
                raise invalid("query parameter 'bytes' must be 'array' or 'base64'")
            mode = value
    return topic, mode


def public(sub: dict[str, Any]) -> dict[str, Any]:
    """The SOVD body of a subscription from the ROS worker's record of it."""
    base = f"{API_BASE}/{sub['collection']}/{sub['entity_id']}/cyclic-subscriptions/{sub['id']}"
    expires = datetime.fromtimestamp(sub["expires_at_ns"] / 1e9, UTC)
    return {"id": sub["id"], "observed_resource": sub["resource"], "event_source": base + "/events",
            "protocol": "sse", "interval": sub["interval"], "duration": sub["duration"],
            "expires_at": expires.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"}


def _call(cmd: str, args: dict[str, Any], sub_id: str | None = None) -> dict[str, Any]:
    try:
        return rosclient.get().call(cmd, args)
    except IpcError as exc:
        if exc.code == "no-such-subscription":
            raise ApiError(404, "resource-not-found", "Subscription not found",
                           {"subscription_id": (sub_id or "")[:100]}) from None
        raise ApiError.from_ipc(exc) from None


def _known(sub_id: str) -> None:
    if not _SUB_ID.match(sub_id):
        raise ApiError(404, "resource-not-found", "Subscription not found", {"subscription_id": sub_id[:100]})


def _client() -> str:
    """Whose subscription this is, for ``max_subscriptions_per_client``: the address that
    app/core/clientaddr.py resolved (read from the environ: Werkzeug's ``request.remote_addr`` is
    read before that resolution).  A listener without peer addresses (a UNIX socket with no
    trusted proxy in front) gives none; its clients share one name instead of being refused."""
    return (request.environ.get("REMOTE_ADDR") or UNKNOWN_CLIENT)[:256]


@bp.post(ENTITY + "/cyclic-subscriptions")
def create(collection: str, entity_id: str):
    authorize_change()
    entity = lookup(collection, entity_id)
    body = _body()
    protocol = body.get("protocol", "sse")
    if protocol != "sse":
        raise _vendor("x-medkit-unsupported-protocol", f"Protocol '{str(protocol)[:50]}' not available",
                      {"parameter": "protocol", "value": str(protocol)[:100]})
    interval = _interval(body, required=True)
    duration = _duration(body, required=True)
    topic, mode = parse_resource(body.get("resource"), collection, entity.id, feeds.COLLECTIONS)
    if topic in feeds.COLLECTIONS:  # feeds: an execution or a parameter (app/subscriptions/feeds.py)
        kind, target = feeds.target(topic, mode, entity, body["resource"])
        sub = _call("sub_create", {"collection": collection, "entity_id": entity.id, "resource": body["resource"],
                                   "bytes": "array", "interval": interval, "duration": duration,
                                   "client": _client(), "kind": kind, "target": target})
        answer = public(sub)
        return json_response(answer, 201, headers={"Location": answer["event_source"].removesuffix("/events")})
    sub = _call("sub_create", {"collection": collection, "entity_id": entity.id, "resource": body["resource"],
                               "topic": topic, "bytes": mode, "interval": interval, "duration": duration,
                               "client": _client()})
    answer = public(sub)
    return json_response(answer, 201, headers={"Location": answer["event_source"].removesuffix("/events")})


@bp.get(ENTITY + "/cyclic-subscriptions")
def listing(collection: str, entity_id: str):
    entity = lookup(collection, entity_id)
    items = _call("sub_list", {"collection": collection, "entity_id": entity.id}).get("items") or []
    return json_response({"items": [public(s) for s in items]})


@bp.get(ENTITY + "/cyclic-subscriptions/<sub_id>")
def detail(collection: str, entity_id: str, sub_id: str):
    entity = lookup(collection, entity_id)
    _known(sub_id)
    return json_response(public(_call("sub_get", {"collection": collection, "entity_id": entity.id,
                                                  "id": sub_id}, sub_id)))


@bp.put(ENTITY + "/cyclic-subscriptions/<sub_id>")
def update(collection: str, entity_id: str, sub_id: str):
    authorize_change()
    entity = lookup(collection, entity_id)
    body = _body()
    interval = _interval(body, required=False)
    duration = _duration(body, required=False)
    _known(sub_id)
    sub = _call("sub_update", {"collection": collection, "entity_id": entity.id, "id": sub_id,
                               "interval": interval, "duration": duration}, sub_id)
    return json_response(public(sub))


@bp.delete(ENTITY + "/cyclic-subscriptions/<sub_id>")
def delete(collection: str, entity_id: str, sub_id: str):
    authorize_change()
    entity = lookup(collection, entity_id)
    _known(sub_id)
    _call("sub_delete", {"collection": collection, "entity_id": entity.id, "id": sub_id}, sub_id)
    return current_app.response_class(status=204)


@bp.get(ENTITY + "/cyclic-subscriptions/<sub_id>/events")
def events(collection: str, entity_id: str, sub_id: str):
    entity = lookup(collection, entity_id)
    _known(sub_id)
    sub = _call("sub_get", {"collection": collection, "entity_id": entity.id, "id": sub_id}, sub_id)
    return current_app.response_class(
        streams.body(sub, request.environ), mimetype="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})
