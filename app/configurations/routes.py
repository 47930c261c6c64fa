"""``{entity}/configurations``: the ROS 2 parameters of the entity's nodes (medkit's ``config_handlers.cpp``).

Routes on components, apps and functions: list, read one, set one (PUT), reset
one (DELETE) and reset all (DELETE on the collection: 204, or 207 naming what
was not reset).  On an app the parameter's name is its id; on an entity backed
by more than one node every id is ``<app_id>:<name>``, and PUT and DELETE refuse
a bare id (400 ``invalid-request``), as medkit does.

The ROS worker does the ROS part (``rosworker/configurations/clients.py``): each node's
parameter services, its timeout (503 ``x-medkit-ros2-node-unavailable``
with Retry-After) and the record of each node's first-seen values, which is
what "reset to the default" sets back.  Writes need ``allow_configurations``
(and, like every write, the token and role of ``app/auth/`` and no lock in the way, ``app/locks/``).
"""

from __future__ import annotations

import math
from typing import Any

from flask import Blueprint, Response

from ipc.errors import IpcError

from ..core import rosclient
from ..core.auth import authorize_feature
from ..core.bodies import json_object
from ..core.common import check_entity_id, config, json_response, lookup, member_nodes
from ..core.entities import API_BASE, Entity
from ..core.errors import IPC_ANSWERS, ApiError

bp = Blueprint("configurations", __name__, url_prefix=API_BASE)

ENTITY = "/<any(components, apps, functions):collection>/<entity_id>/configurations"
MAX_PARAM_ID = 512            # medkit's kMaxAggregatedParamIdLength
IPC_MARGIN_S = 1.5            # the IPC deadline is the parameter service timeout plus this
MAX_ARRAY = 100_000           # elements of an array value


def authorize_configure() -> None:
    """403 unless configurations may be changed (``allow_configurations``)."""
    authorize_feature(config().allow_configurations, "Changing configurations", "--allow-configurations",
                      "enable PUT and DELETE on configurations")




def check_id(param_id: str) -> None:
    if not param_id or len(param_id) > MAX_PARAM_ID:
        raise ApiError(400, "invalid-parameter", "Invalid parameter ID",
                       {"details": "Parameter ID is empty or too long"})


def address(entity: Entity, param_id: str) -> tuple[str | None, str]:
    """(app id or None, parameter name): medkit's ``address_parameter``."""
    app_id, colon, name = param_id.partition(":")
    if not colon or not app_id or not name or app_id == entity.id or app_id not in entity.app_ids:
        return None, param_id
    return app_id, name


def _timeout() -> float:
    return config().parameter_service_timeout + IPC_MARGIN_S


def _call(cmd: str, args: dict[str, Any], nodes: int = 1) -> dict[str, Any]:
    """One command; a multi-node one may take a node's time once per ``max_parameter_clients`` nodes (the
    ROS worker queues the nodes past the cap behind those in flight), and once more.  Its error is the
    caller's to answer (a node's failure is not the ROS worker's)."""
    waves = math.ceil(nodes / config().max_parameter_clients)
    return rosclient.get().call(cmd, args, _timeout() * (1 if nodes <= 1 else 1 + waves))


def node_error(error: IpcError, message: str, entity_id: str, param_id: str | None = None) -> ApiError:
    """A node's failure as medkit answers it: its classification, the node's text in ``details``."""
    status, code, vendor, retry = IPC_ANSWERS[error.code]
    retry_after = error.params.get("retry_after_s", retry) if status == 503 else retry
    params: dict[str, Any] = {"details": error.message, "entity_id": entity_id}
    if param_id is not None:
        params["id"] = param_id
    return ApiError(status, code, message, params, vendor_code=vendor,
                    retry_after=retry_after if isinstance(retry_after, int) else retry)


# Errors of the ROS worker itself, not of a node: answered as every route answers them.
WORKER_ERRORS = ("unavailable", "shutdown", "backpressure", "deadline-exceeded")


def ros_param(cmd: str, args: dict[str, Any], message: str, entity_id: str, param_id: str) -> dict[str, Any]:
    """One node's parameter command; a node's failure answered as medkit answers it (:func:`node_error`)."""
    try:
        return _call(cmd, args)
    except IpcError as exc:
        if exc.code in (*WORKER_ERRORS, "outcome-unknown", "bad-request", "unknown-command", "pool-busy"):
            raise ApiError.from_ipc(exc, {"entity_id": entity_id, "id": param_id}) from None
        if exc.code == "no-such-parameter" and message.startswith("Failed to get"):
            message = "Parameter not found"
        raise node_error(exc, message, entity_id, param_id) from None


def read_value(entity: Entity, fqn: str, param_id: str, source_app: str | None,
                parameter: dict[str, Any]) -> dict[str, Any]:
    ext: dict[str, Any] = {"ros2": {"node": fqn}, "entity_id": entity.id, "source": "runtime",
                           "parameter": parameter}
    if source_app is not None:
        ext["source_app"] = source_app
    return {"id": param_id, "data": parameter.get("value"), "x-medkit": ext}


def _target(entity: Entity, nodes: list[tuple[str, str]], param_id: str) -> tuple[str, str, str | None, str]:
    """(app id, fqn, source_app, name) of a write: the prefixed app, the one node, or medkit's 400."""
    if not nodes:
        raise ApiError(404, "resource-not-found", "No nodes available", {"entity_id": entity.id, "id": param_id})
    app_id, name = address(entity, param_id)
    if app_id is not None:
        fqn = dict(nodes).get(app_id)
        if fqn is None:
            raise ApiError(404, "resource-not-found", "Source app not found in entity",
                           {"entity_id": entity.id, "id": param_id, "source_app": app_id})
        return app_id, fqn, app_id, name
    if len(nodes) == 1:
        return nodes[0][0], nodes[0][1], None, name
    raise ApiError(400, "invalid-request", "Aggregated configuration requires app_id prefix",
                   {"details": "Use format 'app_id:param_name' for aggregated configurations",
                    "entity_id": entity.id, "id": param_id})


@bp.get(ENTITY)
def listing(collection: str, entity_id: str):
    entity = lookup(collection, entity_id)
    nodes = member_nodes(entity)
    aggregated = len(nodes) > 1
    ext: dict[str, Any] = {"entity_id": entity.id, "source": "runtime",
                           "aggregation_level": entity.type, "is_aggregated": aggregated}
    items: list[dict[str, Any]] = []
    if nodes:
        result = _call("param_list", {"nodes": [fqn for _, fqn in nodes]}, len(nodes))
        answers = result.get("nodes") or {}
        parameters, queried, unavailable, failed = [], [], [], []
        worst: IpcError | None = None
        for app_id, fqn in nodes:
            answer = answers.get(fqn) or {"ok": False, "error": {"code": "internal", "message": "no answer"}}
            if not answer.get("ok"):
                error = IpcError.from_wire(answer.get("error"))
                if IPC_ANSWERS[error.code][0] == 503:
                    unavailable.append(fqn)
                else:
                    failed.append(fqn)
                if worst is None or IPC_ANSWERS[error.code][0] == 503:
                    worst = error
                continue
            queried.append(fqn)
            for param in answer.get("parameters") or []:
                name = param.get("name")
                item: dict[str, Any] = {"id": f"{app_id}:{name}" if aggregated else name, "name": name,
                                        "type": "parameter"}
                if aggregated:
                    item["x-medkit"] = {"source": app_id}
                items.append(item)
                parameters.append({**param, "x-medkit": {"source": app_id, "node": fqn}})
        if not queried and worst is not None:
            err = node_error(worst, "Failed to list parameters from any node", entity.id)
            if unavailable:
                err.parameters["unavailable_nodes"] = unavailable
            if failed:
                err.parameters["failed_nodes"] = failed
            raise err
        ext["parameters"] = parameters
        ext["source_ids"] = [entity.id] + ([a for a, _ in nodes] if entity.collection != "apps" else [])
        ext["queried_nodes"] = queried
        if unavailable or failed:
            ext["partial"] = True
        if unavailable:
            ext["unavailable_nodes"] = unavailable
        if failed:
            ext["failed_nodes"] = failed
    return json_response({"items": items, "x-medkit": ext})


def parameter_nodes(entity: Entity, param_id: str) -> tuple[list[tuple[str, str]], str | None, str]:
    """``(nodes, app_id, name)`` of one parameter id of ``entity``: its nodes (404 when it has none), and the
    app and parameter name the id addresses (``app_id`` None: a bare name, looked up on each node)."""
    check_id(param_id)
    nodes = member_nodes(entity)
    if not nodes:
        raise ApiError(404, "resource-not-found", "No nodes available", {"entity_id": entity.id, "id": param_id})
    app_id, name = address(entity, param_id)
    return nodes, app_id, name


@bp.get(ENTITY + "/<param_id>")
def read(collection: str, entity_id: str, param_id: str):
    entity = lookup(collection, entity_id)
    nodes, app_id, name = parameter_nodes(entity, param_id)
    if app_id is not None:
        fqn = dict(nodes)[app_id]
        parameter = ros_param("param_get", {"node": fqn, "name": name}, "Failed to get parameter",
                              entity.id, param_id)
        return json_response(read_value(entity, fqn, param_id, app_id, parameter))
    # A bare id on an entity of several nodes: the first node that has it (medkit's order).
    worst: IpcError | None = None
    for app, fqn in nodes:
        try:
            parameter = _call("param_get", {"node": fqn, "name": name})
        except IpcError as exc:
            if exc.code in WORKER_ERRORS:
                raise ApiError.from_ipc(exc, {"entity_id": entity.id, "id": param_id}) from None
            if exc.code != "no-such-parameter" and (worst is None or IPC_ANSWERS[exc.code][0] == 503):
                worst = exc
            continue
        source_app = app if len(nodes) > 1 else None
        return json_response(read_value(entity, fqn, name, source_app, parameter))
    if worst is None:
        raise ApiError(404, "resource-not-found", "Parameter not found", {"entity_id": entity.id, "id": param_id})
    raise node_error(worst, "Failed to get parameter from any node", entity.id, param_id)


@bp.put(ENTITY + "/<param_id>")
def write(collection: str, entity_id: str, param_id: str):
    authorize_configure()
    check_entity_id(entity_id)
    check_id(param_id)
    body = json_object('{"data": <value>}')
    if "data" in body:
        value = body["data"]
    elif "value" in body:  # medkit's legacy alias
        value = body["value"]
    else:
        raise ApiError(400, "invalid-request", "Request body must contain a 'data' field")
    _check_value(value)
    entity = lookup(collection, entity_id)
    _, fqn, source_app, name = _target(entity, member_nodes(entity), param_id)
    result = ros_param("param_set", {"node": fqn, "name": name, "value": value}, "Failed to set parameter",
                       entity.id, param_id)
    return json_response(read_value(entity, fqn, param_id, source_app, result))


def _check_value(value: Any) -> None:
    """A parameter value is a scalar or a flat array of scalars (what ROS 2 parameters hold)."""
    scalar = (bool, int, float, str)
    if isinstance(value, scalar) or (isinstance(value, list) and len(value) <= MAX_ARRAY
                                     and all(isinstance(v, scalar) for v in value)):
        return
    raise ApiError(400, "invalid-parameter", "Invalid parameter value",
                   {"details": "a ROS 2 parameter is a boolean, an integer, a number, a string, or an array "
                               f"of one of those (at most {MAX_ARRAY} elements); got "
                               f"{'null' if value is None else type(value).__name__}"})


@bp.delete(ENTITY + "/<param_id>")
def reset(collection: str, entity_id: str, param_id: str):
    authorize_configure()
    entity = lookup(collection, entity_id)
    check_id(param_id)
    _, fqn, _, name = _target(entity, member_nodes(entity), param_id)
    ros_param("param_reset", {"node": fqn, "name": name}, "Failed to reset parameter", entity.id, param_id)
    return Response(status=204)


@bp.delete(ENTITY)
def reset_all(collection: str, entity_id: str):
    authorize_configure()
    entity = lookup(collection, entity_id)
    nodes = member_nodes(entity)
    if not nodes:
        return Response(status=204)
    result = _call("param_reset_all", {"nodes": [fqn for _, fqn in nodes]}, len(nodes))
    answers = result.get("nodes") or {}
    results, all_reset = [], True
    for app_id, fqn in nodes:
        answer = answers.get(fqn) or {"ok": False, "error": {"code": "internal", "message": "no answer"}}
        entry: dict[str, Any] = {"node": fqn, "app_id": app_id, "success": True}
        if not answer.get("ok"):
            entry["success"] = False
            entry["error"] = IpcError.from_wire(answer.get("error")).message
        else:
            details = answer.get("result") or {}
            failed = details.get("failed") or []
            if failed:
                entry["success"] = False
                entry["error"] = "Not reset: " + "; ".join(f"{f.get('name')}: {f.get('reason')}" for f in failed)
            entry["details"] = details
        all_reset = all_reset and entry["success"]
        results.append(entry)
    if all_reset:
        return Response(status=204)
    return json_response({"entity_id": entity.id, "results": results}, status=207)
