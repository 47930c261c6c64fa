"""The HTTP side of cyclic subscriptions on an execution or a parameter (``rosworker/configurations/feed.py``).

- :func:`target`: what a subscription's resource names, checked as a GET of it
  would be (an unknown operation, execution or parameter is the same 404; a
  malformed path is 400 ``x-medkit-invalid-resource-uri``): the ``kind`` and
  ``target`` that ``sub_create`` takes.
- :func:`frame`: the SSE event of a feed's frame, whose payload is the body a
  GET of the resource answers at that moment (an execution: status, feedback,
  and at the end the result; a parameter: its value as the node reports it),
  or whose ``error`` is the error body such a GET would answer.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any
from urllib.parse import unquote

import orjson

from ipc.errors import IpcError

from ..core.entities import Entity
from ..core.errors import IPC_ANSWERS, ApiError

COLLECTIONS = ("operations", "configurations")
EXECUTION_PATH = "/api/v1/{apps|components|functions}/{id}/operations/{op_id}/executions/{exec_id}"
PARAMETER_PATH = "/api/v1/{apps|components|functions}/{id}/configurations/{param_id}"


def _invalid(resource: str, why: str) -> ApiError:
    return ApiError(400, "vendor-error", "Invalid resource URI: " + why,
                    {"parameter": "resource", "value": resource[:300]}, vendor_code="x-medkit-invalid-resource-uri")


def target(what: str, rest: str, entity: Entity, resource: str) -> tuple[str, dict[str, Any]]:
    """``(kind, target)`` of ``…/{what}{rest}`` (``rest`` still percent-encoded), or the GET's error."""
    if what == "operations":
        return "execution", _execution(rest, entity, resource)
    return "parameter", _parameter(rest, entity, resource)


def _execution(rest: str, entity: Entity, resource: str) -> dict[str, Any]:
    from ..operations.routes import EXECUTION_ID_MAX, _goal, resolve

    head, sep, exec_raw = rest.rpartition("/executions/")
    if not sep or not head.startswith("/") or len(head) < 2 or not exec_raw or "/" in exec_raw:
        raise _invalid(resource, f"an execution is streamed as {EXECUTION_PATH}")
    op_id, exec_id = unquote(head[1:]), unquote(exec_raw)
    op = resolve(entity, op_id, with_info=False)
    params = {"entity_id": entity.id, "operation_id": op_id, "execution_id": exec_id[:EXECUTION_ID_MAX]}
    if op.kind != "action":  # a service call has no execution to follow
        raise ApiError(404, "resource-not-found", "Execution not found", params)
    goal, _ = _goal(entity.id, op_id, exec_id)
    if goal.get("action") != op.path:
        raise ApiError(404, "resource-not-found", "Execution not found", params)
    return {"goal": goal["id"], "operation_id": op_id}


def _parameter(rest: str, entity: Entity, resource: str) -> dict[str, Any]:
    from ..configurations.routes import _address, _param_id, _ros_call
    from ..core.common import member_nodes

    param_id = unquote(rest[1:]) if rest.startswith("/") else ""
    if not param_id or "/" in rest[1:]:
        raise _invalid(resource, f"a parameter is streamed as {PARAMETER_PATH}")
    _param_id(param_id)
    nodes = member_nodes(entity)
    if not nodes:
        raise ApiError(404, "resource-not-found", "No nodes available", {"entity_id": entity.id, "id": param_id})
    app_id, name = _address(entity, param_id)
    if app_id is not None:
        fqn = dict(nodes)[app_id]
        _ros_call("param_get", {"node": fqn, "name": name}, "Failed to get parameter", entity.id, param_id)
        return {"node": fqn, "name": name, "id": param_id, "source_app": app_id}
    for app, fqn in nodes:  # a bare id: the first node that has it, as a GET answers
        try:
            _ros_call("param_get", {"node": fqn, "name": name}, "Failed to get parameter", entity.id, param_id)
        except ApiError as exc:
            if exc.status == 404 and len(nodes) > 1:
                continue
            raise
        return {"node": fqn, "name": name, "id": name, "source_app": app if len(nodes) > 1 else None}
    raise ApiError(404, "resource-not-found", "Parameter not found", {"entity_id": entity.id, "id": param_id})


def payload(kind: str, entity_id: str, wire: dict[str, Any]) -> bytes:
    """The body a GET of the resource answers, from the ROS worker's frame."""
    if kind == "execution":
        from ..operations.routes import execution_body

        return orjson.dumps(execution_body(wire))
    from ..configurations.routes import _read_value

    return orjson.dumps(_read_value(SimpleNamespace(id=entity_id), wire["node"], wire["id"], wire.get("source_app"),
                                    wire["parameter"]))


def error(kind: str, entity_id: str, target_: dict[str, Any], exc: IpcError) -> bytes:
    """The error body a GET of the resource answers for ``exc``."""
    if kind == "execution":
        params = {"entity_id": entity_id, "operation_id": target_.get("operation_id"),
                  "execution_id": target_.get("goal")}
        return orjson.dumps(ApiError.from_ipc(exc, params).to_dict())
    if exc.code in IPC_ANSWERS and exc.code not in ("unavailable", "shutdown", "backpressure", "deadline-exceeded"):
        from ..configurations.routes import _node_error

        return orjson.dumps(_node_error(exc, "Failed to get parameter", entity_id, target_.get("id")).to_dict())
    return orjson.dumps(ApiError.from_ipc(exc, {"entity_id": entity_id, "id": target_.get("id")}).to_dict())
