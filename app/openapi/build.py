"""The OpenAPI document's building blocks: what every part of it (the core's, each family's ``spec.py``) uses.

Names that generated clients see are medkit's (its published spec): the tags,
the ``operationId``s, the schema names and one error response,
``components.responses.GenericError``, that every error status refers to (each
with its own description, :data:`ERRORS` or the family's own).  A family's part
is a :class:`Spec`: its paths, its schemas, its tags (``app/openapi/__init__.py``
puts the parts together).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from ipc import counters

from ..core.entities import KINDS, PARAM_NAMES

ENTITY_ID = {"type": "string", "pattern": "^[A-Za-z0-9_-]{1,256}$"}
STR = {"type": "string"}
INT = {"type": "integer"}
OBJ = {"type": "object"}
STR_LIST = {"type": "array", "items": STR}


def ref(name: str) -> dict[str, str]:
    return {"$ref": f"#/components/schemas/{name}"}


def obj(required: list[str], **props: Any) -> dict[str, Any]:
    """An object schema; keyword names spell JSON names: ``__`` is ``-``, a leading ``X_`` is ``x-``."""
    return {"type": "object", "required": required,
            "properties": {k.replace("__", "-").replace("X_", "x-"): v for k, v in props.items()}}




def schema_name(collection: str) -> str:
    """``Component`` for ``components``: medkit's schema-name stem."""
    return KINDS[collection][1]


def counter_props(section: str) -> dict[str, Any]:
    """The properties of a /health section: its declared counters (ipc/counters.py), typed."""
    return {c.name: {"type": "boolean"} if c.kind == counters.FLAG else INT for c in counters.section(section)}


def counters_schema(section: str, description: str, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """A /health section made of one section of the stats answer: its counters, typed and required."""
    return {**obj(list(counters.health_keys(section)), **counter_props(section), **(extra or {})),
            "description": description}


RESOURCE_COLLECTIONS = ("apps", "components", "functions")  # the entities that have resources (operations ...)
UNAUTHORIZED = ("401", "An API token is configured and the request has none (`unauthorized`)")
FORBIDDEN = ("403", "An API token is configured and the request's is wrong (`forbidden`)")
TOKEN = {"security": [{"bearerAuth": []}, {}]}


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


def error(description: str) -> dict[str, Any]:
    """An error response: ``components.responses.GenericError`` with its own description."""
    return {"$ref": "#/components/responses/GenericError", "description": description}


def ok(schema: str, description: str = "OK") -> dict[str, Any]:
    return {"description": description, "content": {"application/json": {"schema": ref(schema)}}}


def op(op_id: str, tag: str, summary: str, ok_: dict | None, *errors: str | tuple[str, str],
        limited: bool = True, **extra: Any) -> dict[str, Any]:
    """One operation; ``errors`` are statuses (described from :data:`ERRORS`) or (status, description).

    ``limited``: the route is subject to rate limiting (everything but health and metrics), so
    it documents 429.
    """
    responses: dict[str, Any] = {"200": ok_} if ok_ is not None else {}
    for err in errors:
        status, text = err if isinstance(err, tuple) else (err, ERRORS[err])
        responses[status] = error(text)
    if limited:
        responses["429"] = error(ERRORS["429"])
    responses["default"] = error(ERRORS["default"])
    return {"operationId": op_id, "tags": [tag], "summary": summary, "responses": responses, **extra}


def id_param(collection: str) -> dict[str, Any]:
    return {"name": PARAM_NAMES[collection], "in": "path", "required": True, "schema": ENTITY_ID}


def with_status(operation: dict[str, Any], status: str, answer: dict[str, Any]) -> dict[str, Any]:
    """``operation`` whose first answer is ``status`` (201, 202, 204, 207 ...)."""
    operation["responses"] = {status: answer, **operation["responses"]}
    return operation


DOC = {"description": "OpenAPI 3.1 document", "content": {"application/json": {"schema": OBJ}}}


@dataclass(frozen=True)
class Spec:
    """A family's part of the document: ``paths()`` (called once, when the document is made), its
    ``schemas`` (``components.schemas``) and its ``tags``."""

    paths: Callable[[], dict[str, Any]]
    schemas: dict[str, Any] = field(default_factory=dict)
    tags: tuple[dict[str, str], ...] = ()
