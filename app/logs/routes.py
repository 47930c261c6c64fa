"""``{entity}/logs`` and ``{entity}/logs/configuration``: the robot's ``/rosout``, as medkit serves it.

The lines are held by the ROS worker (``rosworker/logs/book.py``: a ring buffer per
node, memory only); so is each entity's configuration, so every HTTP worker
answers the same.  The rules are medkit's (``log_handlers.cpp``,
``log_manager.cpp``):

- an app's lines are its node's; a component's and a function's are those of
  the apps they host, with ``x-medkit`` ``aggregation_level``, ``aggregated``
  and (when some app resolves) ``app_count``/``host_count`` and
  ``aggregation_sources`` (the nodes' FQNs);
- ``?severity=`` (debug, info, warning, error, fatal) is a minimum, applied
  with the entity's ``severity_filter`` (the stricter wins); ``?context=`` is
  a substring of the logger name, at most 256 characters; anything else is
  400 ``invalid-parameter``; the entity is checked first;
- entries oldest first, the newest ``max_entries`` of them;
- ``PUT …/logs/configuration`` (both fields optional) answers 204.  It
  changes what the gateway shows, not the robot: no ``allow_*`` switch, only
  what every write passes (the role of ``app/auth/``, the locks of ``app/locks/``).
"""

from __future__ import annotations

import time
from typing import Any

from flask import Blueprint, current_app, request

from ..core import rosclient
from ..core.bodies import json_object
from ..core.common import config, json_response, lookup, node_names
from ..core.entities import API_BASE
from ..core.errors import ApiError

bp = Blueprint("logs", __name__, url_prefix=API_BASE)

ENTITY = "/<collection:collection>/<entity_id>"
SEVERITIES = ("debug", "info", "warning", "error", "fatal")
LEVELS = {10: "debug", 20: "info", 30: "warning", 40: "error", 50: "fatal"}
MAX_CONTEXT = 256
MAX_ENTRIES = 10000
LOGS_IPC_MARGIN_S = 1.0   # a query of 10,000 lines may take longer than a plain command


def timestamp(sec: int, nanosec: int) -> str:
    """ISO 8601 UTC with nanoseconds, as medkit writes it (``2026-01-15T10:30:00.123456789Z``)."""
    whole = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(sec))
    return f"{whole}.{min(nanosec, 999_999_999):09d}Z"


def item(row: list[Any]) -> dict[str, Any]:
    """One entry of the ROS worker's rows ([id, sec, nanosec, level, name, msg, file, function, line])."""
    id_, sec, nanosec, level, name, msg, file, function, line = row
    context: dict[str, Any] = {"node": name}
    if function:
        context["function"] = function
    if file:
        context["file"] = file
    if line:
        context["line"] = line
    return {"id": f"log_{id_}", "timestamp": timestamp(sec, nanosec), "severity": LEVELS.get(level, "debug"),
            "message": msg, "context": context}


def _query() -> tuple[str, str]:
    severity = request.args.get("severity", "")
    context = request.args.get("context", "")
    if severity and severity not in SEVERITIES:
        raise ApiError(400, "invalid-parameter",
                       "Invalid severity value: must be one of debug, info, warning, error, fatal",
                       {"parameter": "severity", "value": severity[:100]})
    size = len(context.encode("utf-8", "surrogateescape"))  # medkit counts bytes
    if size > MAX_CONTEXT:
        raise ApiError(400, "invalid-parameter", f"context filter exceeds maximum length of {MAX_CONTEXT}",
                       {"parameter": "context", "length": size})
    return severity, context


@bp.get(ENTITY + "/logs")
def logs(collection: str, entity_id: str):
    entity = lookup(collection, entity_id)
    severity, context = _query()
    ros = rosclient.get()
    fqns = node_names(entity, ros.entities())
    result = ros.call("logs", {"entity_id": entity.id, "nodes": fqns, "severity": severity, "context": context},
                      config().ipc_timeout + LOGS_IPC_MARGIN_S)
    rows = result.get("rows")
    body: dict[str, Any] = {"items": [item(r) for r in rows if isinstance(r, list) and len(r) == 9]
                            if isinstance(rows, list) else []}
    if entity.collection != "apps":
        ext: dict[str, Any] = {"entity_id": entity.id, "aggregation_level": entity.type, "aggregated": True}
        if fqns:
            ext["host_count" if entity.collection == "functions" else "app_count"] = len(fqns)
            ext["aggregation_sources"] = fqns
        body["x-medkit"] = ext
    return json_response(body)


@bp.get(ENTITY + "/logs/configuration")
def get_configuration(collection: str, entity_id: str):
    entity = lookup(collection, entity_id)
    result = rosclient.get().call("log_config_get", {"entity_id": entity.id}, config().ipc_timeout)
    return json_response({"severity_filter": result.get("severity_filter"),
                          "max_entries": result.get("max_entries")})


@bp.put(ENTITY + "/logs/configuration")
def put_configuration(collection: str, entity_id: str):
    entity = lookup(collection, entity_id)
    body = json_object('{"severity_filter": "debug|info|warning|error|fatal", "max_entries": 1-10000}')
    args: dict[str, Any] = {"entity_id": entity.id}
    severity = body.get("severity_filter")
    if severity is not None:
        if not isinstance(severity, str) or severity not in SEVERITIES:
            raise ApiError(400, "invalid-parameter",
                           f"Invalid severity_filter '{str(severity)[:100]}'. "
                           "Must be one of: debug, info, warning, error, fatal",
                           {"parameter": "severity_filter"})
        args["severity_filter"] = severity
    entries = body.get("max_entries")
    if entries is not None:
        if isinstance(entries, bool) or not isinstance(entries, int):
            raise ApiError(400, "invalid-parameter", "max_entries must be an integer",
                           {"parameter": "max_entries"})
        if entries <= 0:
            raise ApiError(400, "invalid-parameter", "max_entries must be greater than 0",
                           {"parameter": "max_entries"})
        if entries > MAX_ENTRIES:
            raise ApiError(400, "invalid-parameter",
                           f"max_entries exceeds maximum allowed value of {MAX_ENTRIES}",
                           {"parameter": "max_entries"})
        args["max_entries"] = entries
    rosclient.get().call("log_config_set", args, config().ipc_timeout)
    return current_app.response_class(status=204)
