"""The operations family's part of the OpenAPI document: services, actions, their executions, and the
lifecycle status of apps and components (``GET .../status``)."""

from __future__ import annotations

from typing import Any

from ..core.entities import PARAM_NAMES
from ..openapi import build as oa

_ROS2_OP = oa.obj(["type", "kind"], service=oa.STR, action=oa.STR, type=oa.STR, kind={"enum": ["service", "action"]})
SCHEMAS: dict[str, Any] = {
    "OperationItem": oa.obj(
        ["id", "name", "proximity_proof_required", "asynchronous_execution", "x-medkit"],
        id={**oa.STR, "description": "the short name; `<member_id>:<name>` when several members of a "
                                  "component or function expose it; the ROS path without its leading "
                                  "slash when one member exposes it at two paths"},
        name=oa.STR, proximity_proof_required={"type": "boolean"}, asynchronous_execution={"type": "boolean"},
        X_medkit=oa.obj(["ros2", "entity_id", "source"], ros2=_ROS2_OP, entity_id=oa.STR, source=oa.STR,
                      member_ids=oa.STR_LIST,
                      type_info={**oa.OBJ, "description": "JSON schemas of request and response (service) "
                                                       "or goal, result and feedback (action), and "
                                                       "their `default_value`s"})),
    "OperationList": oa.obj(["items"], items={"type": "array", "items": oa.ref("OperationItem")},
                          X_medkit=oa.obj([], total_count=oa.INT)),
    "OperationDetail": oa.obj(["item"], item=oa.ref("OperationItem")),
    "ExecutionRequest": oa.obj([], parameters={**oa.OBJ, "description": "the request (service) or goal "
                                                                   "(action); `request` and `goal` are "
                                                                   "accepted too"},
                             type={**oa.STR, "description": "override of the interface type"}),
    "OperationExecutionResult": oa.obj(["parameters"], parameters={**oa.OBJ, "description": "the response"}),
    "ExecutionStarted": oa.obj(["id", "status"], id={**oa.STR, "pattern": "^[0-9a-f]{32}$"},
                             status={"enum": ["pending", "running", "completed", "failed"]}),
    "ExecutionList": oa.obj(["items"], items={"type": "array", "items": oa.obj(["id"], id=oa.STR)}),
    "OperationExecution": oa.obj(
        ["status", "capability", "x-medkit"],
        status={"enum": ["pending", "running", "completed", "failed"]}, capability=oa.STR,
        parameters={**oa.OBJ, "description": "the result once the goal is done, else its latest feedback"},
        X_medkit=oa.obj(["goal_id", "ros2_status", "ros2"], goal_id=oa.STR,
                      ros2_status={"enum": ["accepted", "executing", "canceling", "succeeded", "canceled",
                                            "aborted", "unknown"]},
                      ros2=oa.obj(["action", "type"], action=oa.STR, type=oa.STR), feedback=oa.OBJ, result=oa.OBJ,
                      message={**oa.STR, "description": "why a goal reads `unknown` (the ROS worker "
                                                     "restarted, or the action server left)"})),
    "ExecutionUpdateRequest": oa.obj(["capability"], capability={**oa.STR, "description": "only `stop`"}),
}
HEALTH_SCHEMA = oa.counters_schema("operations", "service and action clients, calls in flight, goals, timeouts")
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
    title, param = oa.schema_name(collection), PARAM_NAMES[collection]
    base = f"/{collection}/{{{param}}}/operations"
    op_param = {"name": "operation_id", "in": "path", "required": True, "schema": oa.STR}
    exec_param = {"name": "execution_id", "in": "path", "required": True, "schema": oa.STR}
    errs = [(k, v) for k, v in _OP_ERRORS.items()]
    reads = [e for e in errs if e[0] in ("400", "404", "503", "504")]
    writes = [e for e in errs if e[0] != "409"]
    secured = {"security": [{"bearerAuth": []}, {}]}

    def body(schema: str) -> dict[str, Any]:
        return {"required": True, "content": {"application/json": {"schema": oa.ref(schema)}}}

    started = {"description": "Goal accepted (action); `Location` names the execution",
               "headers": {"Location": {"schema": oa.STR}},
               "content": {"application/json": {"schema": oa.ref("ExecutionStarted")}}}
    create = oa.op(f"create{title}Execution", "Operations", "Call a service (200) or send an action goal "
                 "(202)", oa.ok("OperationExecutionResult", "Service response"), *writes, *oa.BODY_ERRORS,
                 parameters=[oa.id_param(collection), op_param], requestBody=body("ExecutionRequest"), **secured)
    create["responses"] = {"202": started, **create["responses"]}
    update = oa.op(f"update{title}Execution", "Operations", "Stop a goal (`capability: stop`)", None,
                 *errs, *oa.BODY_ERRORS, parameters=[oa.id_param(collection), op_param, exec_param],
                 requestBody=body("ExecutionUpdateRequest"), **secured)
    update["responses"] = {"202": {**started, "description": "Cancel accepted"}, **update["responses"]}
    cancel = oa.op(f"cancel{title}Execution", "Operations", "Cancel a goal", None, *writes,
                 parameters=[oa.id_param(collection), op_param, exec_param], **secured)
    cancel["responses"] = {"204": {"description": "Cancel accepted"}, **cancel["responses"]}
    return {
        base: {"get": oa.op(f"list{title}Operations", "Operations", "Services and actions",
                          oa.ok("OperationList"), *reads, parameters=[oa.id_param(collection)])},
        base + "/{operation_id}": {"get": oa.op(f"get{title}Operation", "Operations", "One operation",
                                              oa.ok("OperationDetail"), *reads,
                                              parameters=[oa.id_param(collection), op_param])},
        base + "/{operation_id}/executions": {
            "get": oa.op(f"list{title}Executions", "Operations", "An action's goals, newest first",
                       oa.ok("ExecutionList"), *reads, parameters=[oa.id_param(collection), op_param]),
            "post": create},
        base + "/{operation_id}/executions/{execution_id}": {
            "get": oa.op(f"get{title}Execution", "Operations", "A goal's status, feedback and result",
                       oa.ok("OperationExecution"), *reads, parameters=[oa.id_param(collection), op_param,
                                                                        exec_param]),
            "put": update, "delete": cancel},
    }


# GET .../status (app/operations/status.py): medkit's LifecycleStatusResponse; its default path sends the status only.
SCHEMAS["LifecycleStatusResponse"] = oa.obj(
    ["status"], status={"enum": ["ready", "notReady"], "description": "ready: in the graph, and a managed "
                        "(lifecycle) node in the state active"},
    start=oa.STR, restart=oa.STR, force__restart=oa.STR, shutdown=oa.STR, force__shutdown=oa.STR)




def _status_paths() -> dict[str, Any]:
    return {f"/{collection}/{{{PARAM_NAMES[collection]}}}/status": {"get": oa.op(
        f"get{oa.schema_name(collection)}Status", "Lifecycle", f"Whether the {collection[:-1]} is ready: a managed "
        "(lifecycle) node read through its get_state service", oa.ok("LifecycleStatusResponse"), "400", "404",
        "503", "504", parameters=[oa.id_param(collection)])} for collection in ("apps", "components")}


def _paths() -> dict[str, Any]:
    paths = {k: v for c in oa.RESOURCE_COLLECTIONS for k, v in _operation_paths(c).items()}
    paths.update(_status_paths())  # GET .../status (the transitions are 501: core/unimplemented.py)
    return paths


SPEC = oa.Spec(paths=_paths, schemas=SCHEMAS, tags=(
    {"name": "Operations", "description": "ROS 2 services and actions (operations: services and actions)"},))
