"""The subscriptions family's part of the OpenAPI document: cyclic subscriptions and their streams."""

from __future__ import annotations

from typing import Any

from ..core.entities import PARAM_NAMES
from ..openapi import build as oa

INTERVAL = {"enum": ["fast", "normal", "slow"], "description": "fast 50 ms, normal 200 ms, slow 500 ms"}
SCHEMAS: dict[str, Any] = {
    "CyclicSubscription": oa.obj(
        ["id", "observed_resource", "event_source", "protocol", "interval", "duration", "expires_at"],
        id={**oa.STR, "pattern": "^sub_[0-9a-f]{16}$"},
        observed_resource={**oa.STR, "description": "the resource URI as the client gave it"},
        event_source={**oa.STR, "description": "URI of the text/event-stream of this subscription"},
        protocol={"const": "sse"}, interval=INTERVAL,
        duration={**oa.INT, "minimum": 1, "description": "seconds, counted from creation or the last update"},
        expires_at={**oa.STR, "format": "date-time", "description": "RFC 3339 UTC"},
    ),
    "CyclicSubscriptionList": oa.obj(["items"], items={"type": "array", "items": oa.ref("CyclicSubscription")}),
    "CyclicSubscriptionCreateRequest": oa.obj(
        ["resource", "interval", "duration"],
        resource={**oa.STR, "description": "/api/v1/{apps|components|functions}/{id}/data/{topic}, in any "
                                        "spelling the data route accepts, with its query (?bytes=base64); "
                                        # executions and parameters (app/operations/resources.py, app/configurations/resources.py)
                                        "or …/operations/{op_id}/executions/{exec_id} (the goal's status "
                                        "and feedback; the stream ends after a last frame with the result); "
                                        "or …/configurations/{param_id} (the parameter's value)",
                  "examples": ["/api/v1/apps/temp_sensor/data/powertrain/engine/temperature",
                               "/api/v1/apps/calibration/operations/long_calibration/executions/"
                               "0123456789abcdef0123456789abcdef",
                               "/api/v1/apps/temp_sensor/configurations/publish_rate"]},
        protocol={**oa.STR, "default": "sse", "description": "only sse"}, interval=INTERVAL,
        duration={**oa.INT, "minimum": 1, "description": "seconds, at most max_stream_duration (3600)"},
    ),
    "CyclicSubscriptionUpdateRequest": oa.obj([], interval=INTERVAL,
                                            duration={**oa.INT, "minimum": 1, "description": "seconds from now"}),
}


def _subscription_paths(collection: str) -> dict[str, Any]:
    """medkit's cyclic subscriptions, on apps, components and functions."""
    title, param = oa.schema_name(collection), PARAM_NAMES[collection]
    base = f"/{collection}/{{{param}}}/cyclic-subscriptions"
    sub_param = {"name": "subscription_id", "in": "path", "required": True, "schema": oa.STR}
    params = [oa.id_param(collection)]
    not_found = ("404", "Unknown entity (`entity-not-found`) or subscription (`resource-not-found`, "
                        "`Subscription not found`, parameters `subscription_id`); "
                        # what a GET of the execution or parameter answers (app/*/resources.py)
                        "on create, an unknown operation (`operation-not-found`), execution or parameter "
                        "(`resource-not-found`)")
    bad = ("400", "A missing or invalid field (`invalid-parameter`), or a resource that is malformed, "
                  "traverses paths or is `data` without a topic (`x-medkit-invalid-resource-uri`), names "
                  "another entity (`x-medkit-entity-mismatch`) or another collection than `data`, "
                  "`operations/{op}/executions/{exec}` or `configurations/{param}` "
                  "(`x-medkit-collection-not-supported`), or a protocol other than sse "
                  "(`x-medkit-unsupported-protocol`)")
    # With an API token configured, what changes a subscription needs it (README, "who may do it").
    unauthorized = ("401", "An API token is configured and the request has none (`unauthorized`)")
    forbidden = ("403", "An API token is configured and the request's is wrong (`forbidden`)")
    token = {"security": [{"bearerAuth": []}, {}]}
    full = ("503", "At the max_subscriptions cap, or this client's max_subscriptions_per_client cap "
                   "(`service-unavailable`), or the ROS worker is away; "
                   "retry after `Retry-After` seconds")
    created = {"description": "Created", "headers": {"Location": {"schema": oa.STR}},
               "content": {"application/json": {"schema": oa.ref("CyclicSubscription")}}}
    create = oa.op(f"create{title}CyclicSubscription", "Subscriptions",
                 f"Stream a data item of a {collection[:-1]} every interval (SSE)", None, bad, unauthorized,
                 forbidden, not_found, *oa.BODY_ERRORS, full, "504", **token, parameters=params,
                 requestBody={"required": True, "content": {"application/json": {
                     "schema": oa.ref("CyclicSubscriptionCreateRequest")}}})
    create["responses"] = {"201": created, **create["responses"]}
    delete = oa.op(f"delete{title}CyclicSubscription", "Subscriptions", "Cancel a subscription; an open "
                 "stream of it ends at once", None, unauthorized, forbidden, not_found, "503", "504", **token,
                 parameters=params + [sub_param])
    delete["responses"] = {"204": {"description": "Deleted"}, **delete["responses"]}
    events = {"description": "text/event-stream: `data: {\"timestamp\", \"payload\"}` every interval, "
                             "payload being exactly what a GET of the resource answers; `{\"timestamp\", "
                             "\"error\"}` while that GET would answer an error; `:` keep-alives",
              "content": {"text/event-stream": {"schema": oa.STR}}}
    return {
        base: {
            "get": oa.op(f"list{title}CyclicSubscriptions", "Subscriptions", f"A {collection[:-1]}'s active "
                       "subscriptions", oa.ok("CyclicSubscriptionList"), "400", "404", "503", "504",
                       parameters=params),
            "post": create,
        },
        base + "/{subscription_id}": {
            "get": oa.op(f"get{title}CyclicSubscription", "Subscriptions", "One subscription",
                       oa.ok("CyclicSubscription"), not_found, "503", "504", parameters=params + [sub_param]),
            "put": oa.op(f"update{title}CyclicSubscription", "Subscriptions", "Change interval and/or duration "
                       "(a new duration counts from now); applies to open streams",
                       oa.ok("CyclicSubscription"), bad, unauthorized, forbidden, not_found, *oa.BODY_ERRORS,
                       "503", "504", **token, parameters=params + [sub_param], requestBody={"required": True,
                                                                                          "content": {
                           "application/json": {"schema": oa.ref("CyclicSubscriptionUpdateRequest")}}}),
            "delete": delete,
        },
        base + "/{subscription_id}/events": {
            "get": oa.op(f"stream{title}CyclicSubscriptionEvents", "Subscriptions", "The subscription's "
                       "Server-Sent Events stream", events, not_found, "503", "504",
                       parameters=params + [sub_param]),
        },
    }


SPEC = oa.Spec(paths=lambda: {k: v for c in oa.RESOURCE_COLLECTIONS for k, v in _subscription_paths(c).items()},
            schemas=SCHEMAS,
            tags=({"name": "Subscriptions", "description": "Cyclic subscriptions: live data over SSE"},))
