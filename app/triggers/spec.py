"""The triggers family's part of the OpenAPI document: condition triggers and their event streams."""

from __future__ import annotations

from typing import Any

from ..core.entities import PARAM_NAMES
from ..openapi import build as oa

_CONDITION = {
    "type": "object", "required": ["condition_type"],
    "properties": {
        "condition_type": {"enum": ["OnChange", "OnChangeTo", "EnterRange", "LeaveRange"],
                           "description": "OnChange: every change, and the first value; OnChangeTo: the value "
                                          "becomes target_value; EnterRange/LeaveRange: the value crosses into "
                                          "or out of [lower_bound, upper_bound] (inclusive; NaN is in no range)"},
        "target_value": {"description": "OnChangeTo: any JSON value"},
        "lower_bound": {"type": "number"}, "upper_bound": {"type": "number"}},
}
SCHEMAS: dict[str, Any] = {
    "Trigger": oa.obj(
        ["id", "status", "observed_resource", "event_source", "protocol", "trigger_condition", "multishot",
         "persistent"],
        id={**oa.STR, "pattern": "^trig_[0-9a-f]{16}$"},
        status={"enum": ["active", "terminated"], "description": "terminated: a one-shot trigger that fired"},
        observed_resource=oa.STR, event_source=oa.STR, protocol={"const": "sse"}, trigger_condition=_CONDITION,
        multishot={"type": "boolean"}, persistent={"type": "boolean"},
        lifetime={**oa.INT, "minimum": 1, "description": "seconds (from creation, or from the last PUT)"},
        path={**oa.STR, "description": "JSON Pointer into the payload (the message, fault event or log entry)"}),
    "TriggerList": oa.obj(["items"], items={"type": "array", "items": oa.ref("Trigger")}),
    "TriggerCreateRequest": oa.obj(
        ["resource", "trigger_condition"],
        resource={**oa.STR, "description": "/api/v1/{apps|components|functions}/{id}/data/{topic}, "
                                        "…/{id}/faults, …/{id}/faults/{fault_code} or …/{id}/logs (faults and "
                                        "logs in the entity's scope, as its /faults and /logs routes have it)",
                  "examples": ["/api/v1/apps/temp_sensor/data/powertrain/engine/temperature",
                               "/api/v1/apps/temp_sensor/faults", "/api/v1/apps/temp_sensor/logs"]},
        trigger_condition=_CONDITION, path={**oa.STR, "maxLength": 1024, "description": "JSON Pointer (RFC 6901)"},
        protocol={**oa.STR, "default": "sse"}, multishot={"type": "boolean", "default": False},
        persistent={"type": "boolean", "default": False, "description": "kept across gateway restarts"},
        lifetime={**oa.INT, "minimum": 1, "description": "seconds; absent: no expiry"}),
    "TriggerUpdateRequest": oa.obj(["lifetime"], lifetime={**oa.INT, "minimum": 1, "description": "seconds from now"}),
}


def _trigger_paths(collection: str) -> dict[str, Any]:
    """medkit's triggers, on apps, components and functions."""
    title, param = oa.schema_name(collection), PARAM_NAMES[collection]
    base = f"/{collection}/{{{param}}}/triggers"
    trig_param = {"name": "trigger_id", "in": "path", "required": True, "schema": oa.STR}
    params = [oa.id_param(collection)]
    not_found = ("404", "Unknown entity (`entity-not-found`) or trigger (`resource-not-found`, `Trigger not "
                        "found`, parameters `trigger_id`)")
    bad = ("400", "A missing or invalid field, condition, JSON Pointer or lifetime, a `target_value` of more "
                  "than 4096 bytes of JSON (parameters `max_bytes`) or a `path` of more than 1024 characters, "
                  "an unknown or not observable collection, a range condition without `path` on faults or logs "
                  "(`invalid-parameter`, parameters `parameter`), a malformed resource "
                  "(`x-medkit-invalid-resource-uri`) or one of another entity (`x-medkit-entity-mismatch`)")
    unauthorized = ("401", "An API token is configured and the request has none (`unauthorized`)")
    forbidden = ("403", "An API token is configured and the request's is wrong (`forbidden`)")
    token = {"security": [{"bearerAuth": []}, {}]}
    full = ("503", "At the max_triggers cap, this client's max_triggers_per_client cap, or the "
                   "max_trigger_bytes cap of what all triggers hold (`service-unavailable`), or the ROS worker "
                   "is away; retry after `Retry-After` seconds")
    created = {"description": "Created", "headers": {"Location": {"schema": oa.STR}},
               "content": {"application/json": {"schema": oa.ref("Trigger")}}}
    create = oa.op(f"create{title}Trigger", "Triggers", f"Watch a data item, the faults or the logs of a "
                 f"{collection[:-1]} for a condition (events over SSE)", None, bad, unauthorized, forbidden,
                 not_found, *oa.BODY_ERRORS,
                 full, "504", **token, parameters=params, requestBody={"required": True, "content": {
                     "application/json": {"schema": oa.ref("TriggerCreateRequest")}}})
    create["responses"] = {"201": created, **create["responses"]}
    delete = oa.op(f"delete{title}Trigger", "Triggers", "Remove a trigger; an open stream of it ends at once",
                 None, unauthorized, forbidden, not_found, "503", "504", **token, parameters=params + [trig_param])
    delete["responses"] = {"204": {"description": "Deleted"}, **delete["responses"]}
    events = {"description": "text/event-stream: `data: {\"timestamp\", \"payload\"}` each time the "
                             "condition fires, payload being the message (data), the fault plus `event_type` "
                             "(faults) or the log entry (logs); `{\"timestamp\", \"error\"}` when "
                             "a message cannot be read; `:` keep-alives every 15 s",
              "content": {"text/event-stream": {"schema": oa.STR}}}
    return {
        base: {"get": oa.op(f"list{title}Triggers", "Triggers", f"A {collection[:-1]}'s triggers",
                          oa.ok("TriggerList"), "400", "404", "503", "504", parameters=params),
               "post": create},
        base + "/{trigger_id}": {
            "get": oa.op(f"get{title}Trigger", "Triggers", "One trigger", oa.ok("Trigger"), not_found, "503", "504",
                       parameters=params + [trig_param]),
            "put": oa.op(f"update{title}Trigger", "Triggers", "A new lifetime, counted from now", oa.ok("Trigger"),
                       bad, unauthorized, forbidden, not_found, *oa.BODY_ERRORS, "503", "504", **token,
                       parameters=params + [trig_param], requestBody={"required": True, "content": {
                           "application/json": {"schema": oa.ref("TriggerUpdateRequest")}}}),
            "delete": delete},
        base + "/{trigger_id}/events": {
            "get": oa.op(f"stream{title}TriggerEvents", "Triggers", "The trigger's Server-Sent Events stream",
                       events, not_found, "503", "504", parameters=params + [trig_param])},
    }


SPEC = oa.Spec(paths=lambda: {k: v for c in oa.RESOURCE_COLLECTIONS for k, v in _trigger_paths(c).items()},
            schemas=SCHEMAS, tags=({"name": "Triggers", "description": "Condition triggers: events over SSE"},))
