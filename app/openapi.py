"""The OpenAPI 3.1 document of every implemented route (``GET /api/v1/docs``).

It is also the single list the root overview (``GET /api/v1/``) takes its
``endpoints`` from, so the two cannot disagree.  Schemas are JSON Schema
2020-12 (OpenAPI 3.1), and the test suite validates real responses against them.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

from .entities import API_BASE, COLLECTIONS

ENTITY_ID = {"type": "string", "pattern": "^[A-Za-z0-9_-]{1,256}$"}
PARAM_NAMES = {"areas": "area_id", "components": "component_id", "apps": "app_id",
               "functions": "function_id"}
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


SCHEMAS: dict[str, Any] = {
    "Error": {
        **_obj(["error_code", "message"], error_code=STR,
               vendor_code={"type": "string", "pattern": "^x-medkit-"}, message=STR,
               parameters={"type": "object", "minProperties": 1}),
        "additionalProperties": False,
        "description": "SOVD GenericError. `vendor_code` is present when `error_code` is `vendor-error`.",
    },
    "EntityItem": _obj(
        ["id", "name", "href", "type", "x-medkit"], id=ENTITY_ID, name=STR,
        href={"type": "string", "pattern": f"^{API_BASE}/(areas|components|apps|functions)/"},
        type={"enum": ["area", "component", "app", "function"]}, description=STR,
        hosts={**STR_LIST, "description": "functions: the ids of the apps they host"},
        X_medkit=_obj(["source"], source={"enum": ["runtime", "heuristic"]}, is_online={"type": "boolean"},
                      component_id=ENTITY_ID, ros2=_obj(["node"], node=STR)),
    ),
    "EntityListing": _obj(["items", "x-medkit"], items={"type": "array", "items": ref("EntityItem")},
                          X_medkit=_obj(["total_count"], total_count=INT)),
    "EntityDetail": _obj(
        ["id", "name", "type", "data", "capabilities", "_links", "x-medkit"],
        id=ENTITY_ID, name=STR, type={"enum": ["area", "component", "app", "function"]},
        description=STR, data={**STR, "description": "URI of the entity's data items"},
        is__located__on={**STR, "description": "apps: URI of the host component"},
        hosts=STR_LIST,
        capabilities={"type": "array", "items": _obj(["name", "href"], name=STR, href=STR)},
        _links=_obj(["self", "collection"], self=STR, collection=STR, is__located__on=STR),
        X_medkit=OBJ,
    ),
    "IsLocatedOn": _obj(["items"], items={"type": "array", "items": ref("EntityItem"),
                                          "minItems": 1, "maxItems": 1}),
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
    "DataListing": _obj(
        ["items", "x-medkit"], items={"type": "array", "items": ref("DataItem")},
        X_medkit=_obj(["entity_id", "total_count"], entity_id=ENTITY_ID, total_count=INT,
                      aggregated={"const": True}, aggregation_sources=STR_LIST,
                      aggregation_level={"enum": ["component", "function", "area"]}),
    ),
    "DataSample": _obj(
        ["id", "data", "x-medkit"], id=STR,
        data={**OBJ, "description": "the message, fields with their ROS names and real types; "
                                    "{} without data.  A float that is NaN or +-inf is the string "
                                    '"NaN", "Infinity" or "-Infinity" (as in the proto3 JSON mapping); '
                                    "the type's schema in the data listing says so"},
        X_medkit=_obj(
            ["entity_id", "timestamp", "ros2", "publisher_count", "subscriber_count", "status"],
            entity_id=ENTITY_ID,
            timestamp={**INT, "description": "ns since the epoch when the gateway received it (now without data)"},
            ros2=_obj(["topic"], topic=STR, type=STR), publisher_count=INT, subscriber_count=INT,
            status={"enum": ["data", "metadata_only"]},
            reason={"enum": ["not-in-graph", "no-publishers", "timeout", "unsupported-type",
                             "evicted", "shutdown"], "description": "only with metadata_only"},
        ),
    ),
    "PublishRequest": _obj(["type", "data"],
                           type={"type": "string", "pattern": "^[A-Za-z][A-Za-z0-9_]*/msg/[A-Za-z][A-Za-z0-9_]*$",
                                 "examples": ["std_msgs/msg/Float32"]},
                           data={**OBJ, "examples": [{"data": 50.0}, {"range_max": "Infinity"}],
                                 "description": "the message's fields (left out: default).  Float fields "
                                                'take a number, "NaN", "Infinity" or "-Infinity"; null '
                                                "is read as NaN"}),
    "PublishResponse": _obj(
        ["id", "data", "x-medkit"], id=STR, data=OBJ,
        X_medkit=_obj(["ros2", "entity_id", "status"], ros2=_obj(["topic", "type"], topic=STR, type=STR),
                      entity_id=ENTITY_ID, status={"const": "published"}),
    ),
    "Health": _obj(
        ["status", "timestamp", "discovery", "x-medkit-data-provider", "x-medkit-subscription-executor"],
        status={"enum": ["healthy", "degraded", "unhealthy"],
                "description": "unhealthy: the ROS worker is down or not answering; degraded: one of "
                               "its tasks ran past the watchdog threshold"},
        timestamp=INT, discovery=_obj(["mode", "strategy"], mode=STR, strategy=STR),
        X_medkit__data__provider=_obj(
            ["pool_size", "pool_cap", "pool_hits", "pool_misses", "evictions_total", "type_change_events",
             "graph_events_received", "concurrent_cold_waits", "cold_wait_cap", "unsupported_type_count"],
            **{k: INT for k in ("pool_size", "pool_cap", "pool_hits", "pool_misses", "evictions_total",
                                "type_change_events", "graph_events_received", "concurrent_cold_waits",
                                "cold_wait_cap", "unsupported_type_count")}),
        X_medkit__subscription__executor={
            **_obj(["worker_alive", "degraded", "queue_depth", "queue_max_depth_observed", "queue_dropped",
                    "tasks_completed", "tasks_failed", "last_task_latency_us", "max_task_latency_us",
                    "current_task_age_ms", "watchdog_trips", "graph_events_received"],
                   worker_alive={"type": "boolean"}, degraded={"type": "boolean"},
                   **{k: INT for k in ("queue_depth", "queue_max_depth_observed", "queue_dropped",
                                       "tasks_completed", "tasks_failed", "last_task_latency_us",
                                       "max_task_latency_us", "current_task_age_ms", "watchdog_trips",
                                       "graph_events_received")}),
            "description": "While the ROS worker is down: worker_alive false, the last counters received "
                           "(or zeros)"},
    ),
    "RootOverview": _obj(
        ["name", "version", "api_base", "endpoints", "capabilities"], name=STR,
        version={"type": "string", "pattern": r"^\d+\.\d+\.\d+"}, api_base={"const": API_BASE},
        endpoints={"type": "array", "items": {"type": "string", "pattern": f"^(GET|PUT) {API_BASE}/"}},
        capabilities={**_obj(["discovery", "data_access", "publishing"]),
                      "additionalProperties": {"type": "boolean"}},
    ),
    "VersionInfo": _obj(["items"], items={"type": "array", "minItems": 1, "items": _obj(
        ["version", "base_uri", "vendor_info"], version=STR, base_uri={"const": API_BASE},
        vendor_info=_obj(["name", "version"], name=STR, version=STR))}),
}

RETRY_AFTER = {"Retry-After": {"description": "seconds to wait before retrying", "schema": INT}}
RESPONSES: dict[str, Any] = {
    "BadRequest": ("Invalid entity ID (`invalid-parameter`, parameters `details`, `entity_id`), an id of "
                   "another entity type (`expected_type`, `actual_type`), an invalid topic name or "
                   "query parameter (`invalid-parameter`), or an invalid body (`invalid-request`)"),
    "NotFound": "Unknown entity (`entity-not-found`, parameters `entity_id`)",
    "Unavailable": ("The ROS worker is down or restarting (`vendor-error`, "
                    "`x-medkit-ros-worker-unavailable`), busy (`x-medkit-ros-worker-backpressure`), "
                    "shutting down (`x-medkit-gateway-shutdown`) or too many callers wait on cold topics "
                    "(`x-medkit-cold-wait-cap-exceeded`, parameters `topic`, `cold_wait_cap`, `entity_id`, "
                    "`topic_name`); retry after `Retry-After` seconds"),
    "NotResponding": "The ROS worker did not answer in time (`not-responding`)",
    "Error": "Error (`internal-error`, or `vendor-error` with a `vendor_code`)",
}


def _error(description: str, headers: dict | None = None) -> dict[str, Any]:
    out: dict[str, Any] = {"description": description,
                           "content": {"application/json": {"schema": ref("Error")}}}
    if headers:
        out["headers"] = headers
    return out


def _ok(schema: str, description: str = "OK") -> dict[str, Any]:
    return {"description": description, "content": {"application/json": {"schema": ref(schema)}}}


def _resp(name: str) -> dict[str, str]:
    return {"$ref": f"#/components/responses/{name}"}


def _op(op_id: str, summary: str, ok: dict, *errors: str, **extra: Any) -> dict[str, Any]:
    responses = {"200": ok}
    for status in errors:
        responses[status] = _resp({"400": "BadRequest", "404": "NotFound", "503": "Unavailable",
                                   "504": "NotResponding"}.get(status, "Error"))
    responses["default"] = _resp("Error")
    return {"operationId": op_id, "summary": summary, "responses": responses, **extra}


def _entity_paths(collection: str) -> dict[str, Any]:
    name = PARAM_NAMES[collection]
    kind = collection[:-1]
    base = f"/{collection}/{{{name}}}"
    id_param = {"name": name, "in": "path", "required": True, "schema": ENTITY_ID}
    data_param = {"name": "data_id", "in": "path", "required": True, "schema": STR,
                  "description": ("ROS topic. May span several path segments and be percent-encoded: "
                                  "`powertrain%2Fengine%2Ftemperature`, `powertrain/engine/temperature` "
                                  "and `/powertrain/engine/temperature` (written `data//powertrain/...`) "
                                  "all name `/powertrain/engine/temperature`.")}
    bytes_param = {"name": "bytes", "in": "query", "required": False,
                   "schema": {"enum": ["array", "base64"], "default": "array"},
                   "description": "how byte and uint8 arrays are sent: arrays of integers (default) "
                                  "or base64 strings"}
    not_impl = {"description": "Not implemented for ROS 2 (`not-implemented`)",
                "content": {"application/json": {"schema": ref("Error")}}}
    put_errors = {
        "401": _error("An API token is configured and the request has none (`unauthorized`)",
                      {"WWW-Authenticate": {"schema": STR}}),
        "403": _error("Publishing is disabled (`--allow-publish` not given) or the token is wrong "
                      "(`forbidden`)"),
        "413": _error("Request body larger than `max_body_bytes` (`payload-too-large`)"),
    }
    put_op = _op(f"put_{kind}_data_item", f"Publish one message to a topic through a {kind}",
                 _ok("PublishResponse", "Published"), "400", "404", "500", "503", "504",
                 parameters=[id_param, data_param],
                 requestBody={"required": True,
                              "content": {"application/json": {"schema": ref("PublishRequest")}}},
                 security=[{"bearerAuth": []}, {}])
    put_op["responses"].update(put_errors)
    return {
        f"/{collection}": {"get": _op(f"list_{collection}", f"List {collection}", _ok("EntityListing"),
                                      "503", "504")},
        base: {"get": _op(f"get_{kind}", f"Get one {kind}", _ok("EntityDetail"), "400", "404", "503", "504",
                          parameters=[id_param])},
        base + "/data": {"get": _op(f"list_{kind}_data", f"Data items of a {kind} (metadata only)",
                                    _ok("DataListing"), "400", "404", "503", "504", parameters=[id_param])},
        base + "/data/{data_id}": {
            "get": _op(f"get_{kind}_data_item", f"Read one sample of a topic through a {kind}",
                       _ok("DataSample"), "400", "404", "503", "504",
                       parameters=[id_param, data_param, bytes_param]),
            "put": put_op,
        },
        base + "/data-categories": {"get": _op(f"get_{kind}_data_categories", "Data categories",
                                               not_impl, parameters=[id_param])},
        base + "/data-groups": {"get": _op(f"get_{kind}_data_groups", "Data groups", not_impl,
                                           parameters=[id_param])},
    }


@lru_cache(maxsize=1)
def _document() -> dict[str, Any]:
    paths: dict[str, Any] = {
        "/": {"get": _op("get_root", "Gateway overview", _ok("RootOverview"))},
        "/version-info": {"get": _op("get_version_info", "SOVD version information", _ok("VersionInfo"))},
        "/health": {"get": _op("get_health", "Liveness and ROS worker counters; always 200, never "
                                             "waits on ROS work", _ok("Health"))},
        "/docs": {"get": _op("get_docs", "This OpenAPI document",
                             {"description": "OpenAPI 3.1 document",
                              "content": {"application/json": {"schema": OBJ}}})},
    }
    for collection in COLLECTIONS:
        paths.update(_entity_paths(collection))
    paths["/apps/{app_id}/is-located-on"] = {"get": _op(
        "get_app_is_located_on", "The component an app runs on", _ok("IsLocatedOn"), "400", "404", "503",
        "504", parameters=[{"name": "app_id", "in": "path", "required": True, "schema": ENTITY_ID}])}
    responses = {name: _error(text, RETRY_AFTER if name == "Unavailable" else None)
                 for name, text in RESPONSES.items()}
    return {
        "openapi": "3.1.0",
        "info": {"title": "sovd-gateway", "version": "1.0.0",
                 "description": "SOVD REST gateway for ROS 2: discovery and live topic data."},
        "jsonSchemaDialect": "https://json-schema.org/draft/2020-12/schema",
        "servers": [{"url": API_BASE}],
        "paths": paths,
        "components": {
            "schemas": SCHEMAS, "responses": responses,
            "securitySchemes": {"bearerAuth": {"type": "http", "scheme": "bearer",
                                               "description": "required for PUT when an API token is set"}},
        },
    }


def document() -> dict[str, Any]:
    return _document()


def endpoint_list() -> list[str]:
    """``"GET /api/v1/health"`` ... for every documented operation."""
    out = []
    for path, ops in _document()["paths"].items():
        for method in ops:
            out.append(f"{method.upper()} {API_BASE}{path}")
    return out
