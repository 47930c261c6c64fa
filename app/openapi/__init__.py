"""The OpenAPI 3.1 document of every implemented route (``GET /api/v1/docs``).

It is also the single list the root overview (``GET /api/v1/``) takes its
``endpoints`` from, so the two cannot disagree.  Schemas are JSON Schema
2020-12 (OpenAPI 3.1), and the test suite validates real responses against them.

Names that generated clients see are medkit's (its published spec): the tags
(``Server``, ``Discovery``, ``Data``), the ``operationId``s (``listApps``,
``getAppDataItem``, ``listComponentHosts`` ...), the schema names
(``ComponentList``, ``AppDetail``, ``DataValue`` ...) and one error response,
``components.responses.GenericError``, that every error status refers to
(each with its own description).  :func:`scoped_document` narrows the document
to one part of the tree (``GET /{collection}/docs`` and below, medkit's
``docs`` capability).
"""

from __future__ import annotations

import re
from functools import lru_cache
from typing import Any

from ipc import counters

from ..core import unimplemented
from ..core.entities import API_BASE, COLLECTIONS, KINDS, PARAM_NAMES, RELATIONS

SOVD_VERSION = "1.0.0"
ENTITY_ID = {"type": "string", "pattern": "^[A-Za-z0-9_-]{1,256}$"}
STR = {"type": "string"}
INT = {"type": "integer"}
OBJ = {"type": "object"}
STR_LIST = {"type": "array", "items": STR}


def ref(name: str) -> dict[str, str]:
    return {"$ref": f"#/components/schemas/{name}"}


def _obj(required: list[str], **props: Any) -> dict[str, Any]:
    """An object schema; keyword names spell JSON names: ``__`` is ``-``, a leading ``X_`` is ``x-``."""
    return {"type": "object", "required": required,
            "properties": {k.replace("__", "-").replace("X_", "x-"): v for k, v in props.items()}}


INTERVAL = {"enum": ["fast", "normal", "slow"], "description": "fast 50 ms, normal 200 ms, slow 500 ms"}


def _title(collection: str) -> str:
    """``Component`` for ``components``: medkit's schema-name stem."""
    return KINDS[collection][1]


def _counter_props(section: str) -> dict[str, Any]:
    """The properties of a /health section: its declared counters (ipc/counters.py), typed."""
    return {c.name: {"type": "boolean"} if c.kind == counters.FLAG else INT for c in counters.section(section)}


LINKS = {"type": "object", "required": ["self"], "properties": {"self": STR},
         "additionalProperties": STR, "description": "HATEOAS links: `self` and the owning entity"}
CAPABILITIES = {"type": "array", "items": _obj(["name", "href"], name=STR, href=STR)}
X_MEDKIT_ENTITY = {
    "areas": _obj([], source=STR),
    "components": _obj(["source"], source={"enum": ["runtime"]},
                       capabilities={**CAPABILITIES, "description": "detail only: the capabilities again"}),
    "apps": _obj(["source", "is_online", "component_id", "ros2"], source={"enum": ["heuristic"]},
                 is_online={"type": "boolean"}, component_id=ENTITY_ID, ros2=ref("XMedkitRos2")),
    "functions": _obj(["source"], source={"enum": ["runtime"]},
                      hosts={**STR_LIST, "description": "detail only: the ids of the apps it hosts"}),
}
# Detail URIs of what the gateway serves, per collection: (required, optional).
DETAIL_URIS = {
    "areas": (["subareas", "components", "contains", "data"], []),
    "components": (["status", "data", "subcomponents", "hosts"], []),
    "apps": (["status", "data"], ["is-located-on", "belongs-to"]),
    "functions": (["hosts", "data"], []),
}
# Entity details link the resources (medkit's detail URIs): operations, configurations, faults, logs, triggers.
for _collection in ("components", "apps", "functions"):
    DETAIL_URIS[_collection][0].extend(("operations", "configurations", "faults", "logs", "triggers"))


def _entity_schemas() -> dict[str, Any]:
    """``XMedkit<Kind>``, ``<Kind>ListItem``, ``<Kind>List`` and ``<Kind>Detail`` per collection."""
    out: dict[str, Any] = {
        "XMedkitRos2": _obj(["node"], node={**STR, "description": "fully qualified ROS node name"}),
        "XMedkitCollection": _obj(["total_count"], total_count=INT),
    }
    for collection in COLLECTIONS:
        kind, name = KINDS[collection][0], _title(collection)
        out[f"XMedkit{name}"] = X_MEDKIT_ENTITY[collection]
        item = _obj(["id", "name", "href", "type", "x-medkit"], id=ENTITY_ID, name=STR,
                    href={"type": "string", "pattern": f"^{API_BASE}/{collection}/"},
                    type={"const": kind}, description=STR, X_medkit=ref(f"XMedkit{name}"))
        if collection == "functions":
            item["properties"]["hosts"] = {**STR_LIST, "description": "the ids of the apps it hosts"}
        out[f"{name}ListItem"] = item
        out[f"{name}List"] = _obj(["items", "x-medkit"], items={"type": "array", "items": ref(f"{name}ListItem")},
                                  X_medkit=ref("XMedkitCollection"), _links=LINKS)
        required, optional = DETAIL_URIS[collection]
        uris = {key: {"type": "string", "pattern": f"^{API_BASE}/"} for key in required + optional}
        detail = _obj(["id", "name", "type", *required, "capabilities", "_links", "x-medkit"],
                      id=ENTITY_ID, name=STR, type={"const": kind}, description=STR,
                      capabilities=CAPABILITIES,
                      _links={**LINKS, "required": ["self", "collection"]},
                      X_medkit=ref(f"XMedkit{name}"))
        detail["properties"].update(uris)
        out[f"{name}Detail"] = detail
    return out


SCHEMAS: dict[str, Any] = {
    "GenericError": {
        **_obj(["error_code", "message"], error_code=STR,
               vendor_code={"type": "string", "pattern": "^x-medkit-"}, message=STR,
               parameters={"type": "object", "minProperties": 1}),
        "additionalProperties": False,
        "description": "SOVD GenericError. `vendor_code` is present when `error_code` is `vendor-error`.",
    },
    **_entity_schemas(),
    "DataItem": _obj(
        ["id", "name", "category", "x-medkit"], id=STR, name=STR, category={"const": "currentData"},
        X_medkit=_obj(
            ["ros2"],
            ros2=_obj(["topic", "direction"], topic=STR, type=STR,
                      direction={"enum": ["publish", "subscribe", "both"]}),
            type_info={**_obj(["schema", "default_value"], schema=OBJ, default_value=OBJ),
                       "description": "only when the message type is installed"},
            member_ids={**STR_LIST, "description": "components and functions: apps using the topic"},
        ),
    ),
    "DataList": _obj(
        ["items", "x-medkit"], items={"type": "array", "items": ref("DataItem")},
        X_medkit=_obj(["entity_id", "total_count"], entity_id=ENTITY_ID, total_count=INT,
                      aggregated={"type": "boolean", "enum": [True]}, aggregation_sources=STR_LIST,
                      aggregation_level={"enum": ["component", "function", "area"]}),
    ),
    "DataValue": _obj(
        ["id", "data", "x-medkit"], id=STR,
        data={**OBJ, "description": "the message, fields with their ROS names and real types; "
                                    "{} without data.  A float that is NaN or +-inf is the string "
                                    '"NaN", "Infinity" or "-Infinity" (as in the proto3 JSON mapping); '
                                    "the type's schema in the data listing says so"},
        X_medkit=_obj(
            ["entity_id", "timestamp", "ros2", "publisher_count", "subscriber_count", "status"],
            entity_id=ENTITY_ID,
            timestamp={**INT, "description": "ns since the epoch when the gateway received it (now without data)"},
            ros2=_obj(["topic"], topic=STR,
                      type={**STR, "description": "from the graph: the publishers' type, or the "
                                                  "subscribers' on a topic without publishers"}),
            publisher_count=INT, subscriber_count=INT,
            status={"enum": ["data", "metadata_only"]},
            type_info={**_obj(["schema", "default_value"], schema=OBJ, default_value=OBJ),
                       "description": "as in the data listing; only when the type is known and installed"},
            reason={"enum": ["not-in-graph", "no-publishers", "timeout", "unsupported-type",
                             "evicted", "shutdown"], "description": "only with metadata_only"},
        ),
    ),
    "DataWriteRequest": _obj(["type", "data"],
                           type={"type": "string", "pattern": "^[A-Za-z][A-Za-z0-9_]*/msg/[A-Za-z][A-Za-z0-9_]*$",
                                 "examples": ["std_msgs/msg/Float32"]},
                           data={**OBJ, "examples": [{"data": 50.0}, {"range_max": "Infinity"}],
                                 "description": "the message's fields (left out: default).  Float fields "
                                                'take a number, "NaN", "Infinity" or "-Infinity"; null '
                                                "is read as NaN"}),
    "DataWriteResult": _obj(
        ["id", "data", "x-medkit"], id=STR, data=OBJ,
        X_medkit=_obj(["ros2", "entity_id", "status", "subscriber_count", "unmatched_subscriber_count"],
                      ros2=_obj(["topic", "type"], topic=STR, type=STR),
                      entity_id=ENTITY_ID, status={"const": "published"},
                      subscriber_count={**INT, "description": "subscriptions the message went to"},
                      unmatched_subscriber_count={**INT, "description": "subscribers in the graph it did not "
                                                  "reach (another QoS or message-type version)"},
                      warning={**STR, "description": "only when unmatched_subscriber_count > 0"}),
    ),
    "CyclicSubscription": _obj(
        ["id", "observed_resource", "event_source", "protocol", "interval", "duration", "expires_at"],
        id={**STR, "pattern": "^sub_[0-9a-f]{16}$"},
        observed_resource={**STR, "description": "the resource URI as the client gave it"},
        event_source={**STR, "description": "URI of the text/event-stream of this subscription"},
        protocol={"const": "sse"}, interval=INTERVAL,
        duration={**INT, "minimum": 1, "description": "seconds, counted from creation or the last update"},
        expires_at={**STR, "format": "date-time", "description": "RFC 3339 UTC"},
    ),
    "CyclicSubscriptionList": _obj(["items"], items={"type": "array", "items": ref("CyclicSubscription")}),
    "CyclicSubscriptionCreateRequest": _obj(
        ["resource", "interval", "duration"],
        resource={**STR, "description": "/api/v1/{apps|components|functions}/{id}/data/{topic}, in any "
                                        "spelling the data route accepts, with its query (?bytes=base64); "
                                        # feeds (app/subscriptions/feeds.py): executions and parameters
                                        "or …/operations/{op_id}/executions/{exec_id} (the goal's status "
                                        "and feedback; the stream ends after a last frame with the result); "
                                        "or …/configurations/{param_id} (the parameter's value)",
                  "examples": ["/api/v1/apps/temp_sensor/data/powertrain/engine/temperature",
                               "/api/v1/apps/calibration/operations/long_calibration/executions/"
                               "0123456789abcdef0123456789abcdef",
                               "/api/v1/apps/temp_sensor/configurations/publish_rate"]},
        protocol={**STR, "default": "sse", "description": "only sse"}, interval=INTERVAL,
        duration={**INT, "minimum": 1, "description": "seconds, at most max_stream_duration (3600)"},
    ),
    "CyclicSubscriptionUpdateRequest": _obj([], interval=INTERVAL,
                                            duration={**INT, "minimum": 1, "description": "seconds from now"}),
    "HealthStatus": _obj(
        ["status", "timestamp", "discovery", "x-medkit-data-provider", "x-medkit-subscription-executor",
         "x-medkit-streams"],
        status={"enum": ["healthy", "degraded", "unhealthy"],
                "description": "unhealthy: the ROS worker is down or not answering; degraded: one of "
                               "its tasks ran past the watchdog threshold"},
        timestamp=INT, discovery=_obj(["mode", "strategy"], mode=STR, strategy=STR),
        X_medkit__data__provider=_obj(
            [*counters.health_keys("data_provider"), "evictions"], **_counter_props("data_provider"),
            evictions={"type": "object", "additionalProperties": INT,
                       "description": "evictions_total by cause (graph, type_change, lru, idle, qos_rebuild, "
                                      "manual, shutdown, bytes); empty until the ROS worker first answers"}),
        X_medkit__subscription__executor={
            **_obj(list(counters.health_keys("executor")), **_counter_props("executor")),
            "description": "While the ROS worker is down: worker_alive false, the last counters received "
                           "(or zeros)"},
        X_medkit__streams={**_obj(list(counters.health_keys("streams")), **_counter_props("streams")),
                           "description": "cyclic subscriptions held, and the SSE streams of every HTTP worker "
                                          "(summed at each request)"},
        # logs (issue 22): /rosout's ring buffers
        X_medkit__logs={**_obj(list(counters.health_keys("logs")), **_counter_props("logs")),
                        "description": "/rosout's ring buffers: lines held, taken, pushed out, dropped, lost"},
    ),
    "RootOverview": _obj(
        ["name", "version", "api_base", "endpoints", "capabilities"], name=STR,
        version={"type": "string", "pattern": r"^\d+\.\d+\.\d+"}, api_base={"const": API_BASE},
        endpoints={"type": "array", "items": {"type": "string",
                                              "pattern": f"^(GET|PUT|POST|DELETE) ({API_BASE}/|/metrics$)"}},
        capabilities={**_obj(["discovery", "data_access", "publishing"]),
                      "additionalProperties": {"type": "boolean"}},
    ),
    "VersionInfo": _obj(["items"], items={"type": "array", "minItems": 1, "items": _obj(
        ["version", "base_uri", "vendor_info"], version=STR, base_uri={"const": API_BASE},
        vendor_info=_obj(["name", "version"], name=STR, version=STR))}),
}

# Descriptions of the error statuses, by status; every one refers to components.responses.GenericError.
ERRORS: dict[str, str] = {
    "400": ("Invalid entity ID (`invalid-parameter`, parameters `details`, `entity_id`), an id of "
            "another entity type (`Invalid entity type for route: expected App, got Component`, "
            "parameters `entity_id`, `expected_type`, `actual_type`), an invalid topic name or "
            "query parameter (`invalid-parameter`), or an invalid body (`invalid-request`)"),
    "404": "Unknown entity (`entity-not-found`, `Entity not found`, parameters `entity_id`)",
    "500": "Error (`internal-error`, or `vendor-error` with a `vendor_code`)",
    "502": ("The newest message on the topic cannot be decoded as its type (`vendor-error`, "
            "`x-medkit-message-undecodable`, parameters `topic`, `type`): its publisher may be "
            "built against another version of the message package"),
    "503": ("The ROS worker is down or restarting (`vendor-error`, "
            "`x-medkit-ros-worker-unavailable`), busy (`x-medkit-ros-worker-backpressure`), "
            "shutting down (`x-medkit-gateway-shutdown`), every pooled topic waits for its first "
            "message (`x-medkit-pool-busy`), or too many callers wait on cold topics "
            "(`x-medkit-cold-wait-cap-exceeded`, parameters `topic`, `cold_wait_cap`, `entity_id`, "
            "`topic_name`); retry after `Retry-After` seconds"),
    "504": "The ROS worker did not answer in time (`not-responding`)",
    "408": ("The request body did not arrive within `body_timeout` (`invalid-request`); the connection "
            "is closed"),
    "413": ("Request body larger than `max_body_bytes` (`payload-too-large`, parameters "
            "`max_body_bytes`), with a Content-Length or chunked"),
    "415": ("The body is not declared `Content-Type: application/json` (`invalid-request`, parameters "
            "`details`, `content_type`); parameters such as `charset` are allowed"),
    "429": ("Too many requests from this client, or from all clients together, while rate limiting is "
            "on (`rate-limit-exceeded`, parameters `retry_after`, `limit`, `reset`, `scope`); retry after "
            "`Retry-After` seconds"),
    "default": "Error (`internal-error`, or `vendor-error` with a `vendor_code`)",
}
GENERIC_ERROR = {
    "description": "SOVD GenericError response",
    "headers": {
        "Retry-After": {"description": "on a 503 worth retrying: seconds to wait", "required": False,
                        "schema": INT},
        "WWW-Authenticate": {"description": "on a 401", "required": False, "schema": STR},
        "X-RateLimit-Limit": {"description": "while rate limiting is on (every answer of a limited "
                              "route): the burst of the client's or the global token bucket, whichever "
                              "is closer to empty", "required": False, "schema": INT},
        "X-RateLimit-Remaining": {"description": "requests that bucket lets through now",
                                  "required": False, "schema": INT},
        "X-RateLimit-Reset": {"description": "Unix time at which that bucket is full again",
                              "required": False, "schema": INT},
        "X-Request-Id": {"description": "the request's id (every answer): the client's own when it "
                         "sent a valid one (1–128 of `[A-Za-z0-9._-]`), else a new one",
                         "required": False, "schema": STR},
    },
    "content": {"application/json": {"schema": ref("GenericError")}},
}


# What every operation that takes a JSON body may answer because of the body itself
# (``app/core/bodies.py``).
BODY_ERRORS = ("408", "413", "415")


def _error(description: str) -> dict[str, Any]:
    """An error response: ``components.responses.GenericError`` with its own description."""
    return {"$ref": "#/components/responses/GenericError", "description": description}


def _ok(schema: str, description: str = "OK") -> dict[str, Any]:
    return {"description": description, "content": {"application/json": {"schema": ref(schema)}}}


def _op(op_id: str, tag: str, summary: str, ok: dict | None, *errors: str | tuple[str, str],
        limited: bool = True, **extra: Any) -> dict[str, Any]:
    """One operation; ``errors`` are statuses (described from :data:`ERRORS`) or (status, description).

    ``limited``: the route is subject to rate limiting (everything but health and metrics), so
    it documents 429.
    """
    responses: dict[str, Any] = {"200": ok} if ok is not None else {}
    for err in errors:
        status, text = err if isinstance(err, tuple) else (err, ERRORS[err])
        responses[status] = _error(text)
    if limited:
        responses["429"] = _error(ERRORS["429"])
    responses["default"] = _error(ERRORS["default"])
    return {"operationId": op_id, "tags": [tag], "summary": summary, "responses": responses, **extra}


def _id_param(collection: str) -> dict[str, Any]:
    return {"name": PARAM_NAMES[collection], "in": "path", "required": True, "schema": ENTITY_ID}


def _entity_paths(collection: str) -> dict[str, Any]:
    name = PARAM_NAMES[collection]
    kind = collection[:-1]
    title = _title(collection)
    base = f"/{collection}/{{{name}}}"
    id_param = _id_param(collection)
    data_param = {"name": "data_id", "in": "path", "required": True, "schema": STR,
                  "description": ("ROS topic. May span several path segments and be percent-encoded: "
                                  "`powertrain%2Fengine%2Ftemperature`, `powertrain/engine/temperature` "
                                  "and `/powertrain/engine/temperature` (written `data//powertrain/...`) "
                                  "all name `/powertrain/engine/temperature`. A topic `/docs` is read as "
                                  "`data//docs`: `data/docs` is the scoped OpenAPI document.")}
    bytes_param = {"name": "bytes", "in": "query", "required": False,
                   "schema": {"enum": ["array", "base64"], "default": "array"},
                   "description": "how byte and uint8 arrays are sent: arrays of integers (default) "
                                  "or base64 strings"}
    not_impl = ("501", "Not implemented for ROS 2 (`not-implemented`)")
    put_op = _op(f"put{title}DataItem", "Data", f"Publish one message to a topic through a {kind}",
                 _ok("DataWriteResult", "Published"),
                 ("400", ERRORS["400"] + "; a message type the topic's publishers and subscribers do not "
                         "use (`invalid-parameter`, parameters `topic`, `type`, `topic_types`: nothing is "
                         "published or created).  The entity is checked before the body, as medkit does"),
                 ("401", "An API token is configured and the request has none (`unauthorized`)"),
                 ("403", "Publishing is disabled (`--allow-publish` not given) or the token is wrong "
                         "(`forbidden`)"),
                 "404", *BODY_ERRORS, "500", "503", "504",
                 parameters=[id_param, data_param],
                 requestBody={"required": True,
                              "content": {"application/json": {"schema": ref("DataWriteRequest")}}},
                 security=[{"bearerAuth": []}, {}])
    return {
        f"/{collection}": {"get": _op(f"list{title}s", "Discovery", f"List {collection}",
                                      _ok(f"{title}List"), "503", "504")},
        base: {"get": _op(f"get{title}", "Discovery", f"Get one {kind}", _ok(f"{title}Detail"),
                          "400", "404", "503", "504", parameters=[id_param])},
        base + "/data": {"get": _op(f"list{title}Data", "Data", f"Data items of a {kind} (metadata only)",
                                    _ok("DataList"), "400", "404", "503", "504", parameters=[id_param])},
        base + "/data/{data_id}": {
            "get": _op(f"get{title}DataItem", "Data", f"Read one sample of a topic through a {kind}",
                       _ok("DataValue"), "400", "404", "502", "503", "504",
                       parameters=[id_param, data_param, bytes_param]),
            "put": put_op,
        },
        base + "/data-categories": {"get": _op(f"list{title}DataCategories", "Data", "Data categories",
                                               _ok("DataCategoryList", "medkit's answer; never sent by this "
                                                   "gateway, which answers 501"), not_impl,
                                               parameters=[id_param])},
        base + "/data-groups": {"get": _op(f"list{title}DataGroups", "Data", "Data groups",
                                           _ok("DataGroupList", "medkit's answer; never sent by this "
                                               "gateway, which answers 501"), not_impl,
                                           parameters=[id_param])},
    }


# medkit's operationIds of the relation collections.
RELATION_OPS = {
    ("areas", "components"): ("listAreaComponents", "Components in an area"),
    ("areas", "contains"): ("listAreaContains", "Components contained in an area and its subareas"),
    ("areas", "subareas"): ("listSubareas", "Subareas of an area"),
    ("components", "subcomponents"): ("listSubcomponents", "Subcomponents of a component"),
    ("components", "hosts"): ("listComponentHosts", "Apps hosted on a component"),
    ("components", "depends-on"): ("listComponentDependencies", "Components a component depends on"),
    ("apps", "is-located-on"): ("getAppHost", "The component an app runs on"),
    ("apps", "belongs-to"): ("getAppArea", "The area of the app's host component"),
    ("apps", "depends-on"): ("listAppDependencies", "Apps an app depends on"),
    ("functions", "hosts"): ("listFunctionHosts", "Apps that host a function"),
}


def _relation_paths() -> dict[str, Any]:
    paths: dict[str, Any] = {}
    for (collection, relation), (target, _) in RELATIONS.items():
        op_id, summary = RELATION_OPS[(collection, relation)]
        title, param = _title(collection), PARAM_NAMES[collection]
        if collection == "apps":  # medkit checks these like an entity detail
            errors: tuple = ("400", "404")
        else:
            errors = (("400", f"Invalid {title.lower()} ID (`invalid-parameter`, parameters `details`, "
                              f"`{param}`)"),
                      ("404", f"{title} not found (`entity-not-found`, parameters `{param}`); an id of "
                              f"another entity type is not found here either"))
        paths[f"/{collection}/{{{param}}}/{relation}"] = {"get": _op(
            op_id, "Discovery", summary, _ok(f"{_title(target)}List"), *errors, "503", "504",
            parameters=[_id_param(collection)])}
    return paths


DOC = {"description": "OpenAPI 3.1 document", "content": {"application/json": {"schema": OBJ}}}


# GET .../status (app/operations/status.py): medkit's LifecycleStatusResponse; its default path sends the status only.
SCHEMAS["LifecycleStatusResponse"] = _obj(
    ["status"], status={"enum": ["ready", "notReady"], "description": "ready: in the graph, and a managed "
                        "(lifecycle) node in the state active"},
    start=STR, restart=STR, force__restart=STR, shutdown=STR, force__shutdown=STR)


LIFECYCLE_TAG = ("GET .../status: ready or notReady; the transitions (PUT .../status/{transition}) are not "
                 "implemented: 501 (Lifecycle control not available for this entity)")


def _status_paths() -> dict[str, Any]:
    return {f"/{collection}/{{{PARAM_NAMES[collection]}}}/status": {"get": _op(
        f"get{_title(collection)}Status", "Lifecycle", f"Whether the {collection[:-1]} is ready: a managed "
        "(lifecycle) node read through its get_state service", _ok("LifecycleStatusResponse"), "400", "404",
        "503", "504", parameters=[_id_param(collection)])} for collection in ("apps", "components")}


def _docs_paths() -> dict[str, Any]:
    """The scoped documents (``/docs`` itself is with the server routes)."""
    doc = DOC
    no_doc = ("404", "No such entity (`resource-not-found`, `No capability description available for "
                     "the requested path`)")
    paths: dict[str, Any] = {}
    for collection in COLLECTIONS:
        title, param = _title(collection), PARAM_NAMES[collection]
        paths[f"/{collection}/docs"] = {"get": _op(
            f"get{title}sDocs", "Server", f"This document narrowed to /{collection}", doc)}
        paths[f"/{collection}/{{{param}}}/docs"] = {"get": _op(
            f"get{title}Docs", "Server", f"This document narrowed to one {collection[:-1]}", doc, no_doc,
            "503", "504", parameters=[_id_param(collection)])}
        paths[f"/{collection}/{{{param}}}/data/docs"] = {"get": _op(
            f"get{title}DataDocs", "Server", f"This document narrowed to the data of one {collection[:-1]}",
            doc, no_doc, "503", "504", parameters=[_id_param(collection)])}
    return paths


def _subscription_paths(collection: str) -> dict[str, Any]:
    """medkit's cyclic subscriptions, on apps, components and functions."""
    title, param = _title(collection), PARAM_NAMES[collection]
    base = f"/{collection}/{{{param}}}/cyclic-subscriptions"
    sub_param = {"name": "subscription_id", "in": "path", "required": True, "schema": STR}
    params = [_id_param(collection)]
    not_found = ("404", "Unknown entity (`entity-not-found`) or subscription (`resource-not-found`, "
                        "`Subscription not found`, parameters `subscription_id`); "
                        # feeds (app/subscriptions/feeds.py): what a GET of the execution or parameter answers
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
    created = {"description": "Created", "headers": {"Location": {"schema": STR}},
               "content": {"application/json": {"schema": ref("CyclicSubscription")}}}
    create = _op(f"create{title}CyclicSubscription", "Subscriptions",
                 f"Stream a data item of a {collection[:-1]} every interval (SSE)", None, bad, unauthorized,
                 forbidden, not_found, *BODY_ERRORS, full, "504", **token, parameters=params,
                 requestBody={"required": True, "content": {"application/json": {
                     "schema": ref("CyclicSubscriptionCreateRequest")}}})
    create["responses"] = {"201": created, **create["responses"]}
    delete = _op(f"delete{title}CyclicSubscription", "Subscriptions", "Cancel a subscription; an open "
                 "stream of it ends at once", None, unauthorized, forbidden, not_found, "503", "504", **token,
                 parameters=params + [sub_param])
    delete["responses"] = {"204": {"description": "Deleted"}, **delete["responses"]}
    events = {"description": "text/event-stream: `data: {\"timestamp\", \"payload\"}` every interval, "
                             "payload being exactly what a GET of the resource answers; `{\"timestamp\", "
                             "\"error\"}` while that GET would answer an error; `:` keep-alives",
              "content": {"text/event-stream": {"schema": STR}}}
    return {
        base: {
            "get": _op(f"list{title}CyclicSubscriptions", "Subscriptions", f"A {collection[:-1]}'s active "
                       "subscriptions", _ok("CyclicSubscriptionList"), "400", "404", "503", "504",
                       parameters=params),
            "post": create,
        },
        base + "/{subscription_id}": {
            "get": _op(f"get{title}CyclicSubscription", "Subscriptions", "One subscription",
                       _ok("CyclicSubscription"), not_found, "503", "504", parameters=params + [sub_param]),
            "put": _op(f"update{title}CyclicSubscription", "Subscriptions", "Change interval and/or duration "
                       "(a new duration counts from now); applies to open streams",
                       _ok("CyclicSubscription"), bad, unauthorized, forbidden, not_found, *BODY_ERRORS,
                       "503", "504", **token, parameters=params + [sub_param], requestBody={"required": True,
                                                                                          "content": {
                           "application/json": {"schema": ref("CyclicSubscriptionUpdateRequest")}}}),
            "delete": delete,
        },
        base + "/{subscription_id}/events": {
            "get": _op(f"stream{title}CyclicSubscriptionEvents", "Subscriptions", "The subscription's "
                       "Server-Sent Events stream", events, not_found, "503", "504",
                       parameters=params + [sub_param]),
        },
    }


# ---- triggers (app/triggers/routes.py) ------------------------------------------------------------
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
SCHEMAS.update({
    "Trigger": _obj(
        ["id", "status", "observed_resource", "event_source", "protocol", "trigger_condition", "multishot",
         "persistent"],
        id={**STR, "pattern": "^trig_[0-9a-f]{16}$"},
        status={"enum": ["active", "terminated"], "description": "terminated: a one-shot trigger that fired"},
        observed_resource=STR, event_source=STR, protocol={"const": "sse"}, trigger_condition=_CONDITION,
        multishot={"type": "boolean"}, persistent={"type": "boolean"},
        lifetime={**INT, "minimum": 1, "description": "seconds (from creation, or from the last PUT)"},
        path={**STR, "description": "JSON Pointer into the payload (the message, fault event or log entry)"}),
    "TriggerList": _obj(["items"], items={"type": "array", "items": ref("Trigger")}),
    "TriggerCreateRequest": _obj(
        ["resource", "trigger_condition"],
        resource={**STR, "description": "/api/v1/{apps|components|functions}/{id}/data/{topic}, "
                                        "…/{id}/faults, …/{id}/faults/{fault_code} or …/{id}/logs (faults and "
                                        "logs in the entity's scope, as its /faults and /logs routes have it)",
                  "examples": ["/api/v1/apps/temp_sensor/data/powertrain/engine/temperature",
                               "/api/v1/apps/temp_sensor/faults", "/api/v1/apps/temp_sensor/logs"]},
        trigger_condition=_CONDITION, path={**STR, "maxLength": 1024, "description": "JSON Pointer (RFC 6901)"},
        protocol={**STR, "default": "sse"}, multishot={"type": "boolean", "default": False},
        persistent={"type": "boolean", "default": False, "description": "kept across gateway restarts"},
        lifetime={**INT, "minimum": 1, "description": "seconds; absent: no expiry"}),
    "TriggerUpdateRequest": _obj(["lifetime"], lifetime={**INT, "minimum": 1, "description": "seconds from now"}),
})


def _trigger_paths(collection: str) -> dict[str, Any]:
    """medkit's triggers, on apps, components and functions."""
    title, param = _title(collection), PARAM_NAMES[collection]
    base = f"/{collection}/{{{param}}}/triggers"
    trig_param = {"name": "trigger_id", "in": "path", "required": True, "schema": STR}
    params = [_id_param(collection)]
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
    created = {"description": "Created", "headers": {"Location": {"schema": STR}},
               "content": {"application/json": {"schema": ref("Trigger")}}}
    create = _op(f"create{title}Trigger", "Triggers", f"Watch a data item, the faults or the logs of a "
                 f"{collection[:-1]} for a condition (events over SSE)", None, bad, unauthorized, forbidden, not_found, *BODY_ERRORS,
                 full, "504", **token, parameters=params, requestBody={"required": True, "content": {
                     "application/json": {"schema": ref("TriggerCreateRequest")}}})
    create["responses"] = {"201": created, **create["responses"]}
    delete = _op(f"delete{title}Trigger", "Triggers", "Remove a trigger; an open stream of it ends at once",
                 None, unauthorized, forbidden, not_found, "503", "504", **token, parameters=params + [trig_param])
    delete["responses"] = {"204": {"description": "Deleted"}, **delete["responses"]}
    events = {"description": "text/event-stream: `data: {\"timestamp\", \"payload\"}` each time the "
                             "condition fires, payload being the message (data), the fault plus `event_type` "
                             "(faults) or the log entry (logs); `{\"timestamp\", \"error\"}` when "
                             "a message cannot be read; `:` keep-alives every 15 s",
              "content": {"text/event-stream": {"schema": STR}}}
    return {
        base: {"get": _op(f"list{title}Triggers", "Triggers", f"A {collection[:-1]}'s triggers",
                          _ok("TriggerList"), "400", "404", "503", "504", parameters=params),
               "post": create},
        base + "/{trigger_id}": {
            "get": _op(f"get{title}Trigger", "Triggers", "One trigger", _ok("Trigger"), not_found, "503", "504",
                       parameters=params + [trig_param]),
            "put": _op(f"update{title}Trigger", "Triggers", "A new lifetime, counted from now", _ok("Trigger"),
                       bad, unauthorized, forbidden, not_found, *BODY_ERRORS, "503", "504", **token,
                       parameters=params + [trig_param], requestBody={"required": True, "content": {
                           "application/json": {"schema": ref("TriggerUpdateRequest")}}}),
            "delete": delete},
        base + "/{trigger_id}/events": {
            "get": _op(f"stream{title}TriggerEvents", "Triggers", "The trigger's Server-Sent Events stream",
                       events, not_found, "503", "504", parameters=params + [trig_param])},
    }


METRICS_OP = _op(
    "getMetrics", "Server", "Prometheus metrics (text exposition format); beside the API, at /metrics",
    {"description": "The gateway's metrics in Prometheus' text format: HTTP requests by route template, "
                    "latency, streams, rate limiting (sovd_http_*); the ROS worker's counters "
                    "(sovd_ros_*; sovd_ros_worker_up 0 while it does not answer); ROS-worker restarts "
                    "(sovd_supervisor_*). Never rate-limited.",
     "content": {"text/plain": {"schema": STR}}},
    limited=False, servers=[{"url": "/", "description": "outside the API base: GET /metrics"}])


def _not_implemented_paths() -> dict[str, Any]:
    """medkit's routes this gateway does not serve (``app/core/unimplemented.py``): each answers 501."""
    out: dict[str, Any] = {}
    for route, path, collection in unimplemented.paths():
        params = [{"name": name, "in": "path", "required": True,
                   "schema": ENTITY_ID if collection and name == PARAM_NAMES[collection] else STR}
                  for name in re.findall(r"\{([^}]+)\}", path)]
        feature = unimplemented.FEATURES[route.feature]
        op_id = route.op.replace("{Kind}", unimplemented.KINDS[collection] if collection else "")
        out.setdefault(path, {})[route.method.lower()] = _op(
            op_id, feature.tag, route.summary + " (not implemented)",
            {"description": "medkit's answer; never sent by this gateway, which answers 501",
             "content": {"application/json": {"schema": OBJ}}},
            ("501", f"Not implemented on this gateway (`not-implemented`, \"{feature.message}\", parameters "
                    f"`feature`: `{route.feature}`), whatever the ids"),
            parameters=params)
    return out

# ---- operations: services and actions (app/operations/routes.py) ----------------------------
_ROS2_OP = _obj(["type", "kind"], service=STR, action=STR, type=STR, kind={"enum": ["service", "action"]})
SCHEMAS.update({
    "OperationItem": _obj(
        ["id", "name", "proximity_proof_required", "asynchronous_execution", "x-medkit"],
        id={**STR, "description": "the short name; `<member_id>:<name>` when several members of a "
                                  "component or function expose it; the ROS path without its leading "
                                  "slash when one member exposes it at two paths"},
        name=STR, proximity_proof_required={"type": "boolean"}, asynchronous_execution={"type": "boolean"},
        X_medkit=_obj(["ros2", "entity_id", "source"], ros2=_ROS2_OP, entity_id=STR, source=STR,
                      member_ids=STR_LIST,
                      type_info={**OBJ, "description": "JSON schemas of request and response (service) "
                                                       "or goal, result and feedback (action), and "
                                                       "their `default_value`s"})),
    "OperationList": _obj(["items"], items={"type": "array", "items": ref("OperationItem")},
                          X_medkit=_obj([], total_count=INT)),
    "OperationDetail": _obj(["item"], item=ref("OperationItem")),
    "ExecutionRequest": _obj([], parameters={**OBJ, "description": "the request (service) or goal "
                                                                   "(action); `request` and `goal` are "
                                                                   "accepted too"},
                             type={**STR, "description": "override of the interface type"}),
    "OperationExecutionResult": _obj(["parameters"], parameters={**OBJ, "description": "the response"}),
    "ExecutionStarted": _obj(["id", "status"], id={**STR, "pattern": "^[0-9a-f]{32}$"},
                             status={"enum": ["pending", "running", "completed", "failed"]}),
    "ExecutionList": _obj(["items"], items={"type": "array", "items": _obj(["id"], id=STR)}),
    "OperationExecution": _obj(
        ["status", "capability", "x-medkit"],
        status={"enum": ["pending", "running", "completed", "failed"]}, capability=STR,
        parameters={**OBJ, "description": "the result once the goal is done, else its latest feedback"},
        X_medkit=_obj(["goal_id", "ros2_status", "ros2"], goal_id=STR,
                      ros2_status={"enum": ["accepted", "executing", "canceling", "succeeded", "canceled",
                                            "aborted", "unknown"]},
                      ros2=_obj(["action", "type"], action=STR, type=STR), feedback=OBJ, result=OBJ,
                      message={**STR, "description": "why a goal reads `unknown` (the ROS worker "
                                                     "restarted, or the action server left)"})),
    "ExecutionUpdateRequest": _obj(["capability"], capability={**STR, "description": "only `stop`"}),
    "DataCategoryList": _obj(["items"], items={"type": "array", "items": OBJ}),
    "DataGroupList": _obj(["items"], items={"type": "array", "items": OBJ}),
})
SCHEMAS["HealthStatus"]["properties"]["x-medkit-operations"] = _obj(
    list(counters.health_keys("operations")), **_counter_props("operations"))
_OP_ERRORS = {
    "400": ("A request or goal that does not fit the type (`invalid-parameter`, naming the field), an "
            "ambiguous operation id (`invalid-request`, parameters `operation_ids`), an unknown type "
            "(`x-medkit-ros2-type-introspection-failed`), a rejected goal or cancel "
            "(`x-medkit-ros2-action-rejected`, parameters `return_code` for a cancel), or an unsupported "
            "capability (`invalid-parameter`)"),
    "401": "An API token is configured and the request has none (`unauthorized`)",
    "403": "Operations are disabled (`--allow-operations` not given) or the token is wrong (`forbidden`)",
    "404": ("Unknown entity (`entity-not-found`), operation (`operation-not-found`), member or execution "
            "(`resource-not-found`)"),
    "409": "`execute` on a running goal (`precondition-not-fulfilled`)",
    "503": ("No server (`x-medkit-ros2-service-unavailable`, `x-medkit-ros2-action-unavailable`), too many "
            "goals kept for the action (`service-unavailable`), or the ROS worker is down; retry after "
            "`Retry-After` seconds"),
    "504": ("The server did not answer within `service_call_timeout` (`not-responding`): the outcome is "
            "unknown"),
}


def _operation_paths(collection: str) -> dict[str, Any]:
    title, param = _title(collection), PARAM_NAMES[collection]
    base = f"/{collection}/{{{param}}}/operations"
    op_param = {"name": "operation_id", "in": "path", "required": True, "schema": STR}
    exec_param = {"name": "execution_id", "in": "path", "required": True, "schema": STR}
    errs = [(k, v) for k, v in _OP_ERRORS.items()]
    reads = [e for e in errs if e[0] in ("400", "404", "503", "504")]
    writes = [e for e in errs if e[0] != "409"]
    secured = {"security": [{"bearerAuth": []}, {}]}

    def body(schema: str) -> dict[str, Any]:
        return {"required": True, "content": {"application/json": {"schema": ref(schema)}}}

    started = {"description": "Goal accepted (action); `Location` names the execution",
               "headers": {"Location": {"schema": STR}},
               "content": {"application/json": {"schema": ref("ExecutionStarted")}}}
    create = _op(f"create{title}Execution", "Operations", "Call a service (200) or send an action goal "
                 "(202)", _ok("OperationExecutionResult", "Service response"), *writes, *BODY_ERRORS,
                 parameters=[_id_param(collection), op_param], requestBody=body("ExecutionRequest"), **secured)
    create["responses"] = {"202": started, **create["responses"]}
    update = _op(f"update{title}Execution", "Operations", "Stop a goal (`capability: stop`)", None,
                 *errs, *BODY_ERRORS, parameters=[_id_param(collection), op_param, exec_param],
                 requestBody=body("ExecutionUpdateRequest"), **secured)
    update["responses"] = {"202": {**started, "description": "Cancel accepted"}, **update["responses"]}
    cancel = _op(f"cancel{title}Execution", "Operations", "Cancel a goal", None, *writes,
                 parameters=[_id_param(collection), op_param, exec_param], **secured)
    cancel["responses"] = {"204": {"description": "Cancel accepted"}, **cancel["responses"]}
    return {
        base: {"get": _op(f"list{title}Operations", "Operations", "Services and actions",
                          _ok("OperationList"), *reads, parameters=[_id_param(collection)])},
        base + "/{operation_id}": {"get": _op(f"get{title}Operation", "Operations", "One operation",
                                              _ok("OperationDetail"), *reads,
                                              parameters=[_id_param(collection), op_param])},
        base + "/{operation_id}/executions": {
            "get": _op(f"list{title}Executions", "Operations", "An action's goals, newest first",
                       _ok("ExecutionList"), *reads, parameters=[_id_param(collection), op_param]),
            "post": create},
        base + "/{operation_id}/executions/{execution_id}": {
            "get": _op(f"get{title}Execution", "Operations", "A goal's status, feedback and result",
                       _ok("OperationExecution"), *reads, parameters=[_id_param(collection), op_param,
                                                                        exec_param]),
            "put": update, "delete": cancel},
    }


# ---- configurations: the nodes' ROS 2 parameters (app/configurations/routes.py) ----
RESET_MEANS = ("ROS 2 has no default service: the gateway records each parameter's value the first time it "
               "reads the node (per node start: a restarted node is a new record); reset sets that value back. "
               "A parameter first seen after a change cannot be reset to an earlier value; with no record, 404.")
PARAM_VALUE = {"description": "bool, integer (int64), number (NaN and infinities as \"NaN\", \"Infinity\", "
                              "\"-Infinity\"), string, or an array of one of those; byte_array: integers 0-255"}
SCHEMAS.update({
    "ConfigurationMetaData": _obj(["id", "name", "type"], id={**STR, "description": "the parameter's name; "
                                  "`<app_id>:<name>` on an entity of several nodes"}, name=STR,
                                  type={"const": "parameter"}, **{"x-medkit": OBJ}),
    "ConfigurationMetaDataList": _obj(["items"], items={"type": "array", "items": ref("ConfigurationMetaData")},
                                      **{"x-medkit": {**OBJ, "description": "entity_id, source, aggregation_level, "
                                         "is_aggregated, parameters (name, value, type of each, x-medkit source and "
                                         "node), source_ids, queried_nodes; partial with unavailable_nodes (503 "
                                         "class) and failed_nodes when some node did not answer"}}),
    "ConfigurationReadValue": _obj(["id", "data"], id=STR, data=PARAM_VALUE, **{"x-medkit": {
        **OBJ, "description": "ros2.node, entity_id, source, source_app (several nodes), parameter: name, value, "
                              "type (bool, int, double, string, byte_array, bool_array, int_array, double_array, "
                              "string_array) and, on a read, description, read_only, integer_range / "
                              "floating_point_range, additional_constraints, dynamic_typing"}}),
    "ConfigurationWriteValue": _obj(["data"], data=PARAM_VALUE),
    "ConfigurationDeleteMultiStatus": _obj(["entity_id", "results"], entity_id=STR, results={
        "type": "array", "items": _obj(["node", "app_id", "success"], node=STR, app_id=STR,
                                       success={"type": "boolean"}, error=STR,
                                       details={**OBJ, "description": "reset: names set back; failed: name "
                                                                      "and the node's reason of each"})}),
})


def _configuration_paths(collection: str) -> dict[str, Any]:
    """medkit's configurations on apps, components and functions."""
    title, param = _title(collection), PARAM_NAMES[collection]
    base = f"/{collection}/{{{param}}}/configurations"
    params = [_id_param(collection)]
    cfg_param = {"name": "config_id", "in": "path", "required": True, "schema": {**STR, "maxLength": 512},
                 "description": "the parameter's name; `<app_id>:<name>` on an entity of several nodes"}
    token = {"security": [{"bearerAuth": []}, {}]}
    unavailable = ("503", "The node's parameter services are missing, gone, or did not answer within "
                          "parameter_service_timeout (`vendor-error`, `x-medkit-ros2-node-unavailable`; a node "
                          "that timed out is answered at once for parameter_negative_cache_s), or the ROS worker "
                          "is away; retry after `Retry-After` seconds")
    forbidden = ("403", "Changing configurations is off (`forbidden`: --allow-configurations), a wrong API token "
                        "(`forbidden`), or a read-only parameter (`vendor-error`, "
                        "`x-medkit-ros2-parameter-read-only`)")
    unauthorized = ("401", "An API token is configured and the request has none (`unauthorized`)")
    not_found = ("404", "Unknown entity (`entity-not-found`), parameter or source app (`resource-not-found`), or "
                        "no recorded default (reset)")
    bad = ("400", "A value of the wrong type or out of range, with the node's own reason in `details` "
                  "(`invalid-parameter`), an id too long, a body without `data`, or a bare id on an entity of "
                  "several nodes (`invalid-request`)")
    write = _op(f"set{title}Configuration", "Configuration", "Set one ROS 2 parameter; answers the value as the "
                "node now reports it", _ok("ConfigurationReadValue"), bad, unauthorized, forbidden, not_found,
                *BODY_ERRORS, unavailable, "504", **token, parameters=params + [cfg_param],
                requestBody={"required": True, "content": {"application/json": {
                    "schema": ref("ConfigurationWriteValue")}}})
    reset_one = _op(f"delete{title}Configuration", "Configuration", "Reset one parameter to its default. "
                    + RESET_MEANS, None, bad, unauthorized, forbidden, not_found, unavailable, "504", **token,
                    parameters=params + [cfg_param])
    reset_one["responses"] = {"204": {"description": "Reset"}, **reset_one["responses"]}
    reset_all = _op(f"deleteAll{title}Configurations", "Configuration", "Reset every parameter of the entity's "
                    "nodes to its default. " + RESET_MEANS, None, unauthorized, forbidden, ("404", ERRORS["404"]),
                    "503", "504", **token, parameters=params)
    reset_all["responses"] = {"204": {"description": "All reset"},
                              "207": _ok("ConfigurationDeleteMultiStatus", "Some parameters were not reset: "
                                         "each node's entry names them and the node's reason"),
                              **reset_all["responses"]}
    return {
        base: {
            "get": _op(f"list{title}Configurations", "Configuration", f"The ROS 2 parameters of a "
                       f"{collection[:-1]}'s nodes; a node that does not answer makes the list partial",
                       _ok("ConfigurationMetaDataList"), "400", "404", unavailable, "504", parameters=params),
            "delete": reset_all,
        },
        base + "/{config_id}": {
            "get": _op(f"get{title}Configuration", "Configuration", "One parameter: value, type, description, "
                       "read-only, ranges", _ok("ConfigurationReadValue"), bad, not_found, unavailable, "504",
                       parameters=params + [cfg_param]),
            "put": write,
            "delete": reset_one,
        },
    }


# ---- logs (issue 22): {entity}/logs and logs/configuration (app/logs/routes.py) ----
SEVERITY = {"enum": ["debug", "info", "warning", "error", "fatal"]}
SCHEMAS.update({
    "LogEntry": _obj(
        ["id", "timestamp", "severity", "message", "context"],
        id={"type": "string", "pattern": "^log_[0-9]+$"},
        timestamp={"type": "string", "description": "ISO 8601 UTC with nanoseconds"}, severity=SEVERITY,
        message=STR, context=_obj(["node"], node={**STR, "description": "the logger name (dots)"},
                                  function=STR, file=STR, line=INT)),
    "LogEntryList": _obj(
        ["items"], items={"type": "array", "items": ref("LogEntry"), "description": "oldest first"},
        X_medkit={**_obj(["entity_id", "aggregation_level", "aggregated"], entity_id=STR,
                         aggregation_level={"enum": ["component", "function"]}, aggregated={"const": True},
                         app_count=INT, host_count=INT, aggregation_sources=STR_LIST),
                  "description": "components and functions only"}),
    "LogConfiguration": _obj(["severity_filter", "max_entries"], severity_filter=SEVERITY,
                             max_entries={**INT, "minimum": 1, "maximum": 10000}),
    "LogConfigurationUpdate": _obj([], severity_filter=SEVERITY,
                                   max_entries={**INT, "minimum": 1, "maximum": 10000}),
})


def _logs_paths(collection: str) -> dict[str, Any]:
    """medkit's logs of an app (its node's /rosout lines), a component or a function (their apps')."""
    title = _title(collection)
    base = f"/{collection}/{{{PARAM_NAMES[collection]}}}/logs"
    params = [_id_param(collection)]
    query = [{"name": "severity", "in": "query", "required": False, "schema": {"enum": ["", *SEVERITY["enum"]]},
              "description": "minimum severity (the stricter of this and the entity's severity_filter)"},
             {"name": "context", "in": "query", "required": False, "schema": {**STR, "maxLength": 256},
              "description": "substring of the logger name (at most 256 bytes)"}]
    bad = ("400", "Invalid entity ID, or a bad `severity`, `context`, `severity_filter` or `max_entries` "
                  "(`invalid-parameter`)")
    token = {"security": [{"bearerAuth": []}, {}]}
    put = _op(f"update{title}LogConfiguration", "Logs", "Change what the entity's logs show (204)", None, bad,
              ("401", "An API token is configured and the request has none (`unauthorized`)"),
              ("403", "An API token is configured and the request's is wrong (`forbidden`)"), "404",
              *BODY_ERRORS, "503", "504", **token, parameters=params,
              requestBody={"required": True, "content": {"application/json": {
                  "schema": ref("LogConfigurationUpdate")}}})
    put["responses"] = {"204": {"description": "Updated"}, **put["responses"]}
    return {
        base: {"get": _op(f"list{title}Logs", "Logs", f"A {collection[:-1]}'s /rosout lines, oldest first",
                          _ok("LogEntryList"), bad, "404", "503", "504", parameters=params + query)},
        base + "/configuration": {
            "get": _op(f"get{title}LogConfiguration", "Logs", "What the entity's logs show",
                       _ok("LogConfiguration"), "400", "404", "503", "504", parameters=params),
            "put": put,
        },
    }


# ---- faults (issue 22): /faults, /faults/stream and {entity}/faults (app/faults/routes.py) ----
FAULT_STATUS = {"enum": ["PREFAILED", "CONFIRMED", "PREPASSED", "HEALED", "CLEARED"]}
SCHEMAS.update({
    "FaultListItem": _obj(
        ["fault_code", "severity", "severity_label", "description", "first_occurred", "last_occurred",
         "occurrence_count", "status", "reporting_sources"],
        fault_code={**STR, "maxLength": 256, "description": "the status name, upper-cased, each run of "
                                                             "non-alphanumerics `_` (or `fault_codes`)"},
        severity={**INT, "minimum": 0, "maximum": 3, "description": "0 INFO, 1 WARN, 2 ERROR, 3 CRITICAL"},
        severity_label={"enum": ["INFO", "WARN", "ERROR", "CRITICAL"]}, description=STR,
        first_occurred={"type": "number", "description": "Unix time, seconds"},
        last_occurred={"type": "number", "description": "Unix time, seconds"},
        last_passed={"type": "number", "description": "Unix time, seconds; once the status passed"},
        occurrence_count={**INT, "minimum": 1, "description": "episodes: a new failure after passing counts one"},
        status=FAULT_STATUS,
        reporting_sources={**STR_LIST, "description": "the nodes that reported it (fully qualified)"}),
    "FaultList": _obj(
        ["items", "x-medkit"], items={"type": "array", "items": ref("FaultListItem")},
        X_medkit={**_obj(["count"], count=INT, muted_count=INT, cluster_count=INT, entity_id=STR, source_id=STR,
                         aggregation_level={"enum": ["component", "function"]},
                         aggregated={"type": "boolean", "description": "true on a component's or function's"},
                         app_count=INT, host_count=INT, aggregation_sources=STR_LIST),
                  "description": "entity_id on an entity's list; source_id on an app's; aggregation_* on a "
                                 "component's or function's"}),
    "FaultDetail": _obj(
        ["item", "environment_data", "x-medkit"],
        item=_obj(["code", "severity", "status"], code=STR, fault_name=STR,
                  severity={**INT, "minimum": 0, "maximum": 3},
                  status=_obj(["aggregatedStatus", "testFailed", "confirmedDTC", "pendingDTC"],
                              aggregatedStatus={"enum": ["active", "passive", "cleared"]},
                              testFailed={"enum": ["0", "1"]}, confirmedDTC={"enum": ["0", "1"]},
                              pendingDTC={"enum": ["0", "1"]})),
        environment_data=_obj(
            ["extended_data_records", "snapshots"],
            extended_data_records=_obj(["first_occurrence", "last_occurrence"],
                                       first_occurrence={**STR, "format": "date-time"},
                                       last_occurrence={**STR, "format": "date-time"}),
            snapshots={"type": "array", "maxItems": 8, "items": _obj(
                ["type", "name", "data", "x-medkit"], type={"const": "freeze_frame"}, name=STR,
                data={"description": "the status's values (name: value), or a topic's message (its primary "
                                     "field for the common std_msgs/sensor_msgs types)"},
                X_medkit=_obj(["topic", "message_type"], topic=STR, message_type=STR, full_data={},
                              captured_at={**STR, "format": "date-time"}, parse_error=STR,
                              truncated_bytes=INT, error=STR))}),
        X_medkit=_obj(["occurrence_count", "severity_label", "status_raw"], occurrence_count=INT,
                      reporting_sources=STR_LIST, severity_label={"enum": ["INFO", "WARN", "ERROR", "CRITICAL"]},
                      status_raw=FAULT_STATUS)),
})
SCHEMAS["HealthStatus"]["required"].append("x-medkit-faults")
SCHEMAS["HealthStatus"]["properties"]["x-medkit-faults"] = {
    **_obj(["active", "confirmed", "store_size", "max_faults", "last_write_error"],
           active=INT, confirmed=INT, store_size=INT, max_faults=INT, refused=INT,
           active_by_severity={"type": "object", "additionalProperties": INT},
           store_enabled={"type": "boolean"}, store_writes=INT, store_write_errors=INT, store_pending=INT,
           last_write_error=STR, moved_aside={**STR, "description": "where a corrupt store was moved at start"},
           diagnostics_arrays=INT,
           left_by_absent_nodes={**INT, "description": "active faults loaded from the store at start whose "
                                 "reporting nodes are not on the graph (an earlier run's, another robot's, or "
                                 "their nodes died): nobody reports them again"},
           absent_nodes={**STR_LIST, "description": "the reporting nodes of those faults (at most 16)"}),
    "description": "the fault manager (rosworker/faults/manager.py) and its SQLite store; zeros before the ROS worker "
                   "first answers"}
_FAULT_QUERY = {"name": "status", "in": "query", "required": False,
                "schema": {"enum": ["pending", "confirmed", "cleared", "healed", "all"]},
                "description": "pending (PREFAILED), confirmed, healed (HEALED, PREPASSED), cleared (CLEARED "
                               "and what healed holds), all; without it pending and confirmed (medkit's)"}
_FAULT_ERRORS = {
    "400": ("Invalid entity ID, a `status` other than pending, confirmed, cleared, healed or all "
            "(`invalid-parameter`, `Invalid status parameter value`, parameters `allowed_values`, "
            "`parameter`, `value`), or a fault code not 1-256 characters (`Invalid fault code`)"),
    "401": "An API token is configured and the request has none (`unauthorized`)",
    "403": ("Clearing faults is off (`forbidden`: --allow-fault-clear not given), or the API token is "
            "wrong (`forbidden`)"),
    "404": ("Unknown entity (`entity-not-found`), or fault (`resource-not-found`, `Fault not found`, "
            "parameters `details`, `fault_code`): unknown, or reported by a node outside the entity "
            "(medkit's all-sources scope)"),
}


def _fault_errors(*statuses: str) -> list[tuple[str, str]]:
    return [(s, _FAULT_ERRORS[s]) for s in statuses]


def _fault_clear(op_id: str, summary: str, *errors: Any, params: list[dict[str, Any]]) -> dict[str, Any]:
    op = _op(op_id, "Faults", summary, None, *errors, "503", "504", security=[{"bearerAuth": []}, {}],
             parameters=params)
    op["responses"] = {"204": {"description": "Cleared (or nothing to clear)"}, **op["responses"]}
    return op


def _fault_paths(collection: str | None) -> dict[str, Any]:
    """medkit's faults: the gateway's (``collection`` None) or an app's, component's or function's."""
    if collection is None:
        stream = {"description": "text/event-stream: `id: <n>`, `event: fault_confirmed | fault_updated | "
                                 "fault_cleared`, `data: {\"event_type\", \"fault\" (a FaultListItem), "
                                 "\"timestamp\"}`; `:` keep-alives. `Last-Event-ID` replays what was missed",
                  "content": {"text/event-stream": {"schema": STR}}}
        full = ("503", "At max_fault_streams open streams of this HTTP worker (`service-unavailable`, `Maximum "
                       "number of SSE clients reached`); retry after `Retry-After` seconds")
        return {
            "/faults": {
                "get": _op("listAllFaults", "Faults", "Every fault of the robot (its /diagnostics)",
                           _ok("FaultList"), *_fault_errors("400"), "503", "504", parameters=[_FAULT_QUERY]),
                "delete": _fault_clear("clearAllFaults", "Clear every fault with the `status` asked (a write: "
                                       "allow_fault_clear and the token)", *_fault_errors("400", "401", "403"),
                                       params=[_FAULT_QUERY]),
            },
            "/faults/stream": {"get": _op("streamFaults", "Faults", "Fault events as they happen (SSE)", stream,
                                          full, parameters=[{"name": "Last-Event-ID", "in": "header",
                                                             "required": False, "schema": STR}])},
        }
    title = _title(collection)
    base = f"/{collection}/{{{PARAM_NAMES[collection]}}}/faults"
    params = [_id_param(collection)]
    code = {"name": "fault_code", "in": "path", "required": True, "schema": {**STR, "maxLength": 256}}
    return {
        base: {
            "get": _op(f"list{title}Faults", "Faults", f"The faults every source of which is one of the "
                       f"{collection[:-1]}'s nodes", _ok("FaultList"), *_fault_errors("400", "404"), "503",
                       "504", parameters=params + [_FAULT_QUERY]),
            "delete": _fault_clear(f"clearAll{title}Faults", f"Clear the {collection[:-1]}'s faults with the "
                                   "`status` asked", *_fault_errors("400", "401", "403", "404"),
                                   params=params + [_FAULT_QUERY]),
        },
        base + "/{fault_code}": {
            "get": _op(f"get{title}Fault", "Faults", "One fault: SOVD status bits, first and last occurrence, "
                       "freeze frames", _ok("FaultDetail"), *_fault_errors("400", "404"), "503", "504",
                       parameters=params + [code]),
            "delete": _fault_clear(f"clear{title}Fault", "Clear one fault (it is CLEARED until it fails again)",
                                   *_fault_errors("400", "401", "403", "404"), params=params + [code]),
        },
    }


@lru_cache(maxsize=1)
def _document() -> dict[str, Any]:
    paths: dict[str, Any] = {
        "/": {"get": _op("getRoot", "Server", "Gateway overview", _ok("RootOverview"))},
        "/version-info": {"get": _op("getVersionInfo", "Server", "SOVD version information",
                                     _ok("VersionInfo"))},
        "/health": {"get": _op("getHealth", "Server", "Liveness and ROS worker counters; always 200, "
                                                      "never waits on ROS work; never rate-limited",
                               _ok("HealthStatus"), limited=False)},
        "/docs": {"get": _op("getDocs", "Server", "This OpenAPI document", DOC)},
    }
    for collection in COLLECTIONS:
        paths.update(_entity_paths(collection))
    paths.update(_relation_paths())
    for collection in ("apps", "components", "functions"):
        paths.update(_subscription_paths(collection))
    paths.update(_docs_paths())
    paths.update({k: v for c in ("apps", "components", "functions") for k, v in _configuration_paths(c).items()})
    for collection in ("apps", "components", "functions"):  # triggers (app/triggers/routes.py)
        paths.update(_trigger_paths(collection))
    paths.update(_not_implemented_paths())
    paths.update(_status_paths())  # GET .../status (the transitions are 501: _not_implemented_paths)
    for collection in ("apps", "components", "functions"):  # logs (issue 22)
        paths.update(_logs_paths(collection))
    paths["/metrics"] = {"get": METRICS_OP}
    for collection in ("apps", "components", "functions"):  # operations: services and actions
        paths.update(_operation_paths(collection))
    for collection in (None, "apps", "components", "functions"):  # faults (issue 22)
        paths.update(_fault_paths(collection))
    return {
        "openapi": "3.1.0",
        "info": {"title": "sovd-gateway", "version": "1.0.0", "x-sovd-version": SOVD_VERSION,
                 "description": "SOVD REST gateway for ROS 2: discovery and live topic data."},
        "jsonSchemaDialect": "https://json-schema.org/draft/2020-12/schema",
        "servers": [{"url": API_BASE}],
        "tags": [{"name": "Server", "description": "Gateway health, metadata, version info and docs"},
                 {"name": "Discovery", "description": "Entity discovery and hierarchy navigation"},
                 {"name": "Data", "description": "Read and write ROS 2 topic data"},
                 {"name": "Subscriptions", "description": "Cyclic subscriptions: live data over SSE"},
                 {"name": "Operations", "description": "ROS 2 services and actions (operations: services "
                                                       "and actions)"},
                 {"name": "Configuration", "description": "ROS 2 parameters of the nodes (configurations)"},
                 {"name": "Logs", "description": "The robot's /rosout, per entity (issue 22)"},
                 {"name": "Triggers", "description": "Condition triggers: events over SSE"},
                 {"name": "Faults", "description": "The robot's /diagnostics as SOVD faults (issue 22)"},
                 *({"name": f.tag, "description": LIFECYCLE_TAG if f.tag == "Lifecycle"
                    else f"Not implemented: 501 ({f.message})"}
                   for f in unimplemented.FEATURES.values())],
        "paths": paths,
        "components": {
            "schemas": SCHEMAS, "responses": {"GenericError": GENERIC_ERROR},
            "securitySchemes": {"bearerAuth": {"type": "http", "scheme": "bearer",
                                               "description": "required for PUT when an API token is set"}},
        },
    }


def document() -> dict[str, Any]:
    return _document()


def scoped_document(collection: str, entity_id: str | None = None, *, data: bool = False,
                    data_ids: list[str] | tuple[str, ...] = ()) -> dict[str, Any]:
    """The document narrowed to one part of the tree, as medkit's ``docs`` capability serves it.

    ``/{collection}/docs``: the paths under ``/{collection}`` as templates.
    ``/{collection}/{id}/docs``: the paths under that entity, with its id filled
    in (and its path parameter gone).  ``/{collection}/{id}/data/docs``: only
    its data paths; ``data_ids`` (the entity's topics) become examples of
    ``{data_id}``.  The caller checks that the entity exists.
    """
    full = _document()
    root = f"/{collection}"
    template = f"{root}/{{{PARAM_NAMES[collection]}}}"
    prefix = template + "/data" if data else (template if entity_id is not None else root)
    paths: dict[str, Any] = {}
    for path, ops in full["paths"].items():
        if path != prefix and not path.startswith(prefix + "/"):
            continue
        if entity_id is None:
            paths[path] = ops
            continue
        paths[f"{root}/{entity_id}" + path[len(template):]] = {
            method: _bind(op, PARAM_NAMES[collection], data_ids) for method, op in ops.items()}
    scope = prefix if entity_id is None else prefix.replace(template, f"{root}/{entity_id}")
    return {**full, "info": {**full["info"], "title": f"sovd-gateway - {scope.lstrip('/')}"},
            "paths": paths}


def _bind(op: dict[str, Any], id_name: str, data_ids: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """``op`` without its entity-id path parameter; topics as examples of ``data_id``."""
    params = []
    for param in op.get("parameters", []):
        if param["name"] == id_name and param["in"] == "path":
            continue
        if param["name"] == "data_id" and data_ids:
            param = {**param, "examples": {t: {"summary": f"topic {t}", "value": t.lstrip("/")}
                                           for t in data_ids}}
        params.append(param)
    out = {k: v for k, v in op.items() if k != "parameters"}
    if params:
        out["parameters"] = params
    return out


def endpoint_list() -> list[str]:
    """``"GET /api/v1/health"`` ... for every documented operation (``GET /metrics`` is outside the base)."""
    out = []
    for path, ops in _document()["paths"].items():
        for method, op in ops.items():
            base = op["servers"][0]["url"].rstrip("/") if op.get("servers") else API_BASE
            out.append(f"{method.upper()} {base}{path}")
    return out
