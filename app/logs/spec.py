"""The logs family's part of the OpenAPI document: an entity's /rosout lines and their configuration."""

from __future__ import annotations

from typing import Any

from ..core.entities import PARAM_NAMES
from ..openapi import build as oa

SEVERITY = {"enum": ["debug", "info", "warning", "error", "fatal"]}
SCHEMAS: dict[str, Any] = {
    "LogEntry": oa.obj(
        ["id", "timestamp", "severity", "message", "context"],
        id={"type": "string", "pattern": "^log_[0-9]+$"},
        timestamp={"type": "string", "description": "ISO 8601 UTC with nanoseconds"}, severity=SEVERITY,
        message=oa.STR, context=oa.obj(["node"], node={**oa.STR, "description": "the logger name (dots)"},
                                  function=oa.STR, file=oa.STR, line=oa.INT)),
    "LogEntryList": oa.obj(
        ["items"], items={"type": "array", "items": oa.ref("LogEntry"), "description": "oldest first"},
        X_medkit={**oa.obj(["entity_id", "aggregation_level", "aggregated"], entity_id=oa.STR,
                         aggregation_level={"enum": ["component", "function"]}, aggregated={"const": True},
                         app_count=oa.INT, host_count=oa.INT, aggregation_sources=oa.STR_LIST),
                  "description": "components and functions only"}),
    "LogConfiguration": oa.obj(["severity_filter", "max_entries"], severity_filter=SEVERITY,
                             max_entries={**oa.INT, "minimum": 1, "maximum": 10000}),
    "LogConfigurationUpdate": oa.obj([], severity_filter=SEVERITY,
                                   max_entries={**oa.INT, "minimum": 1, "maximum": 10000}),
}


def _logs_paths(collection: str) -> dict[str, Any]:
    """medkit's logs of an app (its node's /rosout lines), a component or a function (their apps')."""
    title = oa.schema_name(collection)
    base = f"/{collection}/{{{PARAM_NAMES[collection]}}}/logs"
    params = [oa.id_param(collection)]
    query = [{"name": "severity", "in": "query", "required": False, "schema": {"enum": ["", *SEVERITY["enum"]]},
              "description": "minimum severity (the stricter of this and the entity's severity_filter)"},
             {"name": "context", "in": "query", "required": False, "schema": {**oa.STR, "maxLength": 256},
              "description": "substring of the logger name (at most 256 bytes)"}]
    bad = ("400", "Invalid entity ID, or a bad `severity`, `context`, `severity_filter` or `max_entries` "
                  "(`invalid-parameter`)")
    token = {"security": [{"bearerAuth": []}, {}]}
    put = oa.op(f"update{title}LogConfiguration", "Logs", "Change what the entity's logs show (204)", None, bad,
              ("401", "An API token is configured and the request has none (`unauthorized`)"),
              ("403", "An API token is configured and the request's is wrong (`forbidden`)"), "404",
              *oa.BODY_ERRORS, "503", "504", **token, parameters=params,
              requestBody={"required": True, "content": {"application/json": {
                  "schema": oa.ref("LogConfigurationUpdate")}}})
    put["responses"] = {"204": {"description": "Updated"}, **put["responses"]}
    return {
        base: {"get": oa.op(f"list{title}Logs", "Logs", f"A {collection[:-1]}'s /rosout lines, oldest first",
                          oa.ok("LogEntryList"), bad, "404", "503", "504", parameters=params + query)},
        base + "/configuration": {
            "get": oa.op(f"get{title}LogConfiguration", "Logs", "What the entity's logs show",
                       oa.ok("LogConfiguration"), "400", "404", "503", "504", parameters=params),
            "put": put,
        },
    }


HEALTH_SCHEMA = oa.counters_schema("logs", "/rosout's ring buffers: lines held, taken, pushed out, dropped, lost")
SPEC = oa.Spec(paths=lambda: {k: v for c in oa.RESOURCE_COLLECTIONS for k, v in _logs_paths(c).items()},
            schemas=SCHEMAS, tags=({"name": "Logs", "description": "The robot's /rosout, per entity"},))
