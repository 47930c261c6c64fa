"""The faults family's part of the OpenAPI document: the robot's faults, their stream, an entity's faults."""

from __future__ import annotations

from typing import Any

from ..core.entities import PARAM_NAMES
from ..openapi import build as oa

FAULT_STATUS = {"enum": ["PREFAILED", "CONFIRMED", "PREPASSED", "HEALED", "CLEARED"]}
SCHEMAS: dict[str, Any] = {
    "FaultListItem": oa.obj(
        ["fault_code", "severity", "severity_label", "description", "first_occurred", "last_occurred",
         "occurrence_count", "status", "reporting_sources"],
        fault_code={**oa.STR, "maxLength": 256, "description": "the status name, upper-cased, each run of "
                                                             "non-alphanumerics `_` (or `fault_codes`)"},
        severity={**oa.INT, "minimum": 0, "maximum": 3, "description": "0 INFO, 1 WARN, 2 ERROR, 3 CRITICAL"},
        severity_label={"enum": ["INFO", "WARN", "ERROR", "CRITICAL"]}, description=oa.STR,
        first_occurred={"type": "number", "description": "Unix time, seconds"},
        last_occurred={"type": "number", "description": "Unix time, seconds"},
        last_passed={"type": "number", "description": "Unix time, seconds; once the status passed"},
        occurrence_count={**oa.INT, "minimum": 1, "description": "episodes: a new failure after passing counts one"},
        status=FAULT_STATUS,
        reporting_sources={**oa.STR_LIST, "description": "the nodes that reported it (fully qualified)"}),
    "FaultList": oa.obj(
        ["items", "x-medkit"], items={"type": "array", "items": oa.ref("FaultListItem")},
        X_medkit={**oa.obj(["count"], count=oa.INT, muted_count=oa.INT, cluster_count=oa.INT,
                           entity_id=oa.STR, source_id=oa.STR,
                         aggregation_level={"enum": ["component", "function"]},
                         aggregated={"type": "boolean", "description": "true on a component's or function's"},
                         app_count=oa.INT, host_count=oa.INT, aggregation_sources=oa.STR_LIST),
                  "description": "entity_id on an entity's list; source_id on an app's; aggregation_* on a "
                                 "component's or function's"}),
    "FaultDetail": oa.obj(
        ["item", "environment_data", "x-medkit"],
        item=oa.obj(["code", "severity", "status"], code=oa.STR, fault_name=oa.STR,
                  severity={**oa.INT, "minimum": 0, "maximum": 3},
                  status=oa.obj(["aggregatedStatus", "testFailed", "confirmedDTC", "pendingDTC"],
                              aggregatedStatus={"enum": ["active", "passive", "cleared"]},
                              testFailed={"enum": ["0", "1"]}, confirmedDTC={"enum": ["0", "1"]},
                              pendingDTC={"enum": ["0", "1"]})),
        environment_data=oa.obj(
            ["extended_data_records", "snapshots"],
            extended_data_records=oa.obj(["first_occurrence", "last_occurrence"],
                                       first_occurrence={**oa.STR, "format": "date-time"},
                                       last_occurrence={**oa.STR, "format": "date-time"}),
            snapshots={"type": "array", "description": "at most 8 freeze frames, then the fault's recordings "
                                                       "(newest first, fault_rosbag_max_bags_per_fault)",
                       "items": {"oneOf": [oa.obj(
                           ["type", "name", "data", "x-medkit"], type={"const": "freeze_frame"}, name=oa.STR,
                           data={"description": "the status's values (name: value), or a topic's message (its "
                                                "primary field for the common std_msgs/sensor_msgs types)"},
                           X_medkit=oa.obj(["topic", "message_type"], topic=oa.STR, message_type=oa.STR, full_data={},
                                           captured_at={**oa.STR, "format": "date-time"}, parse_error=oa.STR,
                                           truncated_bytes=oa.INT, error=oa.STR)),
                           # a recording (the bulk-data family's, added through the fault_snapshots extension)
                           oa.obj(["type", "name", "bulk_data_uri", "size_bytes", "duration_sec", "format"],
                                  type={"const": "rosbag"}, name=oa.STR,
                                  bulk_data_uri={**oa.STR, "description": "the recording under the entity asked "
                                                                          "(`/apps/x/bulk-data/rosbags/<id>`, no "
                                                                          "API base)"},
                                  size_bytes=oa.INT, duration_sec={"type": "number"}, format={"const": "mcap"},
                                  X_medkit=oa.obj([], captured_at={**oa.STR, "format": "date-time"},
                                                  topics=oa.STR_LIST, messages=oa.INT))]}}),
        X_medkit=oa.obj(["occurrence_count", "severity_label", "status_raw"], occurrence_count=oa.INT,
                      reporting_sources=oa.STR_LIST, severity_label={"enum": ["INFO", "WARN", "ERROR", "CRITICAL"]},
                      status_raw=FAULT_STATUS)),
}
HEALTH_SCHEMA = {
    **oa.obj(["active", "confirmed", "store_size", "max_faults", "last_write_error"],
           active=oa.INT, confirmed=oa.INT, store_size=oa.INT, max_faults=oa.INT, refused=oa.INT,
           active_by_severity={"type": "object", "additionalProperties": oa.INT},
           store_enabled={"type": "boolean"}, store_writes=oa.INT, store_write_errors=oa.INT, store_pending=oa.INT,
           last_write_error=oa.STR, moved_aside={**oa.STR, "description": "where a corrupt store was moved at start"},
           diagnostics_arrays=oa.INT,
           left_by_absent_nodes={**oa.INT, "description": "active faults loaded from the store at start whose "
                                 "reporting nodes are not on the graph (an earlier run's, another robot's, or "
                                 "their nodes died): nobody reports them again"},
           absent_nodes={**oa.STR_LIST, "description": "the reporting nodes of those faults (at most 16)"}),
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
    operation = oa.op(op_id, "Faults", summary, None, *errors, "503", "504", security=[{"bearerAuth": []}, {}],
                   parameters=params)
    return oa.with_status(operation, "204", {"description": "Cleared (or nothing to clear)"})


def _fault_paths(collection: str | None) -> dict[str, Any]:
    """medkit's faults: the gateway's (``collection`` None) or an app's, component's or function's."""
    if collection is None:
        stream = {"description": "text/event-stream: `id: <n>`, `event: fault_confirmed | fault_updated | "
                                 "fault_cleared`, `data: {\"event_type\", \"fault\" (a FaultListItem), "
                                 "\"timestamp\"}`; `:` keep-alives. `Last-Event-ID` replays what was missed",
                  "content": {"text/event-stream": {"schema": oa.STR}}}
        full = ("503", "At max_fault_streams open streams of this HTTP worker (`service-unavailable`, `Maximum "
                       "number of SSE clients reached`); retry after `Retry-After` seconds")
        return {
            "/faults": {
                "get": oa.op("listAllFaults", "Faults", "Every fault of the robot (its /diagnostics)",
                           oa.ok("FaultList"), *_fault_errors("400"), "503", "504", parameters=[_FAULT_QUERY]),
                "delete": _fault_clear("clearAllFaults", "Clear every fault with the `status` asked (a write: "
                                       "allow_fault_clear and the token)", *_fault_errors("400", "401", "403"),
                                       params=[_FAULT_QUERY]),
            },
            "/faults/stream": {"get": oa.op("streamFaults", "Faults", "Fault events as they happen (SSE)", stream,
                                          full, parameters=[{"name": "Last-Event-ID", "in": "header",
                                                             "required": False, "schema": oa.STR}])},
        }
    title = oa.schema_name(collection)
    base = f"/{collection}/{{{PARAM_NAMES[collection]}}}/faults"
    params = [oa.id_param(collection)]
    code = {"name": "fault_code", "in": "path", "required": True, "schema": {**oa.STR, "maxLength": 256}}
    return {
        base: {
            "get": oa.op(f"list{title}Faults", "Faults", f"The faults every source of which is one of the "
                       f"{collection[:-1]}'s nodes", oa.ok("FaultList"), *_fault_errors("400", "404"), "503",
                       "504", parameters=params + [_FAULT_QUERY]),
            "delete": _fault_clear(f"clearAll{title}Faults", f"Clear the {collection[:-1]}'s faults with the "
                                   "`status` asked", *_fault_errors("400", "401", "403", "404"),
                                   params=params + [_FAULT_QUERY]),
        },
        base + "/{fault_code}": {
            "get": oa.op(f"get{title}Fault", "Faults", "One fault: SOVD status bits, first and last occurrence, "
                       "freeze frames", oa.ok("FaultDetail"), *_fault_errors("400", "404"), "503", "504",
                       parameters=params + [code]),
            "delete": _fault_clear(f"clear{title}Fault", "Clear one fault (it is CLEARED until it fails again)",
                                   *_fault_errors("400", "401", "403", "404"), params=params + [code]),
        },
    }


SPEC = oa.Spec(paths=lambda: {k: v for c in (None, *oa.RESOURCE_COLLECTIONS) for k, v in _fault_paths(c).items()},
            schemas=SCHEMAS, tags=({"name": "Faults", "description": "The robot's /diagnostics as SOVD faults"},))
