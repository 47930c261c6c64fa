"""``{entity}/triggers``: SOVD condition triggers, their events over Server-Sent Events.

medkit's contract (``docs/api/rest.rst`` "Triggers", ``trigger_handlers.cpp``):
POST 201 with the trigger, GET the entity's list or one, PUT its lifetime
(counted again from now), DELETE 204 (an open stream of it ends at once),
GET ``.../events`` the stream.  The routes check what a client sends with
medkit's rules and texts; the triggers live in the ROS worker (``trig_*``
commands, ``rosworker/triggers/registry.py``), so one made through one HTTP worker is
streamed through any other.  Writes pass what every write passes (the role of
``app/auth/``, the locks of ``app/locks/``), like the cyclic subscriptions'.

Observable resources: the collections a family made observable
(``core/resources.py``: the data family's topics, the faults and the logs in the
entity's scope); medkit's other collections (operations, updates) are refused as
not observable on this gateway yet.
"""

from __future__ import annotations

import json
import math
from typing import Any

from flask import Blueprint, request

from ipc import jsonpointer

from ..core.bodies import json_object
from ..core.common import json_response, lookup
from ..core.entities import API_BASE
from ..core.errors import ApiError
from ..core.records import Records, created
from ..core.resources import Observable, Resource, client, observables, parse_resource
from ..sse import hub as sse
from . import hub

bp = Blueprint("triggers", __name__, url_prefix=API_BASE)

ENTITY = "/<any(apps, components, functions):collection>/<entity_id>"
CONDITIONS = ("OnChange", "OnChangeTo", "EnterRange", "LeaveRange")
MAX_LIFETIME = 2**31 - 1
TARGET_VALUE_MAX = 4096  # bytes of the JSON of an OnChangeTo target_value (rosworker/triggers/registry.py checks it too)
MEDKIT_COLLECTIONS = ("data", "faults", "operations", "updates", "logs")
TRIGGERS = Records("trig", "Trigger", "trigger_id", "no-such-trigger")


def _bad(message: str, parameter: str, value: Any = None) -> ApiError:
    params: dict[str, Any] = {"parameter": parameter}
    if value is not None:
        params["value"] = value if isinstance(value, (bool, int, float)) else str(value)[:300]
    return ApiError(400, "invalid-parameter", message, params)


def _condition(body: dict[str, Any]) -> dict[str, Any]:
    condition = body.get("trigger_condition")
    if not isinstance(condition, dict):
        raise _bad("Missing or invalid 'trigger_condition'", "trigger_condition")
    kind = condition.get("condition_type")
    if not isinstance(kind, str):
        raise _bad("Missing or invalid 'condition_type' in trigger_condition", "trigger_condition.condition_type")
    if kind not in CONDITIONS:
        raise _bad(f"Unknown condition_type '{kind[:100]}'. Supported: {', '.join(CONDITIONS)}",
                   "trigger_condition.condition_type", kind)
    out: dict[str, Any] = {"condition_type": kind}
    if kind == "OnChangeTo":
        if "target_value" not in condition:
            raise _bad("OnChangeTo requires 'target_value'", "trigger_condition.target_value")
        size = len(json.dumps(condition["target_value"], separators=(",", ":")).encode())
        if size > TARGET_VALUE_MAX:
            raise ApiError(400, "invalid-parameter", f"'target_value' too large (max {TARGET_VALUE_MAX} bytes of "
                           f"JSON; this one has {size})", {"parameter": "trigger_condition.target_value",
                                                           "max_bytes": TARGET_VALUE_MAX, "bytes": size})
        out["target_value"] = condition["target_value"]
    elif kind in ("EnterRange", "LeaveRange"):
        for name in ("lower_bound", "upper_bound"):
            value = condition.get(name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise _bad(f"{kind} requires '{name}' (a finite number)", f"trigger_condition.{name}", value)
            out[name] = value
        if out["lower_bound"] > out["upper_bound"]:
            raise _bad("'lower_bound' must not exceed 'upper_bound'", "trigger_condition.lower_bound",
                       out["lower_bound"])
    return out


def _lifetime(body: dict[str, Any], required: bool) -> int | None:
    value = body.get("lifetime")
    if value is None:
        if required:
            raise _bad("Missing or invalid 'lifetime'", "lifetime")
        return None
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or not 0 < value <= MAX_LIFETIME:
        raise _bad("Lifetime must be a positive integer (seconds)", "lifetime", value)
    return value


def _flag(body: dict[str, Any], name: str) -> bool:
    value = body.get(name, False)
    if value is None:
        return False
    if not isinstance(value, bool):
        raise _bad(f"'{name}' must be a boolean", name, value)
    return value


def _path(body: dict[str, Any]) -> str:
    value = body.get("path")
    if value is None:
        return ""
    if not isinstance(value, str):
        raise _bad("Invalid JSON Pointer in 'path'", "path", value)
    if len(value) > jsonpointer.MAX_LENGTH:
        raise _bad(f"Path too long (max {jsonpointer.MAX_LENGTH})", "path")
    try:
        jsonpointer.parse(value)
    except ValueError as exc:
        raise _bad(f"Invalid JSON Pointer in 'path': {exc}", "path", value) from None
    return value


def _observable(resource: Resource) -> Observable:
    """The collection a trigger's resource names, if a family made it observable (``core/resources.py``)."""
    observable = observables().get(resource.what)
    if observable is not None:
        return observable
    name = resource.what[:100]
    if name in MEDKIT_COLLECTIONS or name.startswith("x-"):
        raise ApiError(400, "invalid-parameter",
                       f"Collection '{name}' is not observable by triggers on this gateway; "
                       f"supported: {', '.join(observables())}", {"parameter": "resource", "collection": name})
    raise ApiError(400, "invalid-parameter", "Unknown collection. Supported: data, faults, operations, updates, logs, "
                   "or x-* vendor extensions", {"parameter": "resource", "collection": name})


def public(trigger: dict[str, Any]) -> dict[str, Any]:
    """The SOVD body of a trigger from the ROS worker's record of it."""
    base = f"{API_BASE}/{trigger['collection']}/{trigger['entity_id']}/triggers/{trigger['id']}"
    out = {"id": trigger["id"], "status": trigger["status"], "observed_resource": trigger["resource"],
           "event_source": base + "/events", "protocol": "sse", "trigger_condition": trigger["condition"],
           "multishot": trigger["multishot"], "persistent": trigger["persistent"]}
    if trigger.get("lifetime") is not None:
        out["lifetime"] = trigger["lifetime"]
    if trigger.get("path"):
        out["path"] = trigger["path"]
    return out


@bp.post(ENTITY + "/triggers")
def create(collection: str, entity_id: str):
    entity = lookup(collection, entity_id)
    body = json_object('{"resource", "trigger_condition", "path", "protocol", "multishot", "persistent", '
                       '"lifetime"}')
    condition = _condition(body)
    resource = parse_resource(body.get("resource"), collection, entity.id)
    observable = _observable(resource)
    path = _path(body)
    # What of it: a topic; the entity's scope (faults, logs); and whether the condition can apply.
    target, mode = observable.resolve(resource, entity, condition, path)
    protocol = body.get("protocol", "sse")
    if protocol != "sse":
        raise _bad("Unsupported protocol. Supported: 'sse'", "protocol", protocol)
    args = {"collection": collection, "entity_id": entity.id, "resource": body["resource"],
            "source": observable.source or observable.collection,
            "target": target, "bytes": mode, "path": path, "condition": condition,
            "multishot": _flag(body, "multishot"), "persistent": _flag(body, "persistent"),
            "lifetime": _lifetime(body, required=False), "client": client()}
    return created(public(TRIGGERS.call("create", args)))


@bp.get(ENTITY + "/triggers")
def listing(collection: str, entity_id: str):
    return json_response({"items": [public(t) for t in TRIGGERS.listing(collection, entity_id)]})


@bp.get(ENTITY + "/triggers/<trigger_id>")
def detail(collection: str, entity_id: str, trigger_id: str):
    return json_response(public(TRIGGERS.get(collection, entity_id, trigger_id)))


@bp.put(ENTITY + "/triggers/<trigger_id>")
def update(collection: str, entity_id: str, trigger_id: str):
    entity = lookup(collection, entity_id)
    body = json_object('{"lifetime"}')
    lifetime = _lifetime(body, required=True)
    return json_response(public(TRIGGERS.of("update", collection, entity, trigger_id, lifetime=lifetime)))


@bp.delete(ENTITY + "/triggers/<trigger_id>")
def delete(collection: str, entity_id: str, trigger_id: str):
    return TRIGGERS.delete(collection, entity_id, trigger_id)


@bp.get(ENTITY + "/triggers/<trigger_id>/events")
def events(collection: str, entity_id: str, trigger_id: str):
    trigger = TRIGGERS.get(collection, entity_id, trigger_id)
    if trigger["status"] != "active" and not trigger.get("replayable"):
        raise ApiError(404, "resource-not-found", "Trigger expired or inactive", {"trigger_id": trigger_id})
    return sse.response(hub.body(trigger, request.environ))
