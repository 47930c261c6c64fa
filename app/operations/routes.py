"""``{entity}/operations``: the entity's ROS 2 services and actions, and their executions.

The contract is medkit's (``operation_handlers.cpp``).  Every client and goal
lives in the ROS worker (``rosworker/operations/commands.py``); this module finds the
operations of an entity (``op_list`` over the nodes of its apps), names them by
medkit's id rules, and forwards calls, goals and cancels.  Executing and
cancelling are writes: ``allow_operations`` (and the role and locks every write passes).

Ids (medkit's): a short name only one member exposes is used bare; when several
members of a component or function expose it, ``<member_id>:<name>``; when one
member exposes it at two paths, the path without its leading slash.  An id that
names more than one operation is 400, never "whichever came first".
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

from flask import Blueprint, request

from ipc.errors import IpcError

from ..core import rosclient
from ..core.auth import authorize_feature
from ..core.bodies import json_object
from ..core.common import check_entity_id, config, json_response, lookup, member_nodes
from ..core.entities import API_BASE, Entity
from ..core.errors import ApiError
from ..core.roscall import ros_call

bp = Blueprint("operations", __name__, url_prefix=API_BASE)

ENTITY = "/<any(components,apps,functions):collection>/<entity_id>"
OPERATION = ENTITY + "/operations/<path:op_id>"
EXECUTION = OPERATION + "/executions/<exec_id>"
# The IPC deadline of a call, goal or cancel: the service call timeout plus this margin.
CALL_IPC_MARGIN_S = 2.0
EXECUTION_ID_MAX = 64
SOURCE = "ros2_medkit_gateway"
# Resolving an id to run it uses a node's operations at most this old (a new service is seen
# within it; the listing and the detail always ask the ROS worker).
OP_LIST_TTL_S = 1.0
OP_CACHE_MAX = 256
_OP_CACHE: dict[tuple[str, ...], tuple[float, dict[str, Any]]] = {}


@dataclass
class Operation:
    member: str          # the app whose node serves it
    kind: str            # "service" or "action"
    path: str
    name: str
    type: str
    type_info: Any
    id: str = ""

    @property
    def path_id(self) -> str:
        return self.path.lstrip("/")

    def item(self, entity: Entity) -> dict[str, Any]:
        ext: dict[str, Any] = {"ros2": {self.kind: self.path, "type": self.type, "kind": self.kind},
                               "entity_id": entity.id, "source": SOURCE}
        if self.type_info is not None:
            ext["type_info"] = self.type_info
        if entity.aggregated:
            ext["member_ids"] = [self.member]
        return {"id": self.id, "name": self.name, "proximity_proof_required": False,
                "asynchronous_execution": self.kind == "action", "x-medkit": ext}


def authorize_operations() -> None:
    """403 unless operations are on; with an API token, 401 without it and 403 with a wrong one."""
    authorize_feature(config().allow_operations, "Operations", "--allow-operations",
                      "call services and run actions")




def _op_list(nodes: list[str], with_info: bool) -> dict[str, Any]:
    """``op_list``; without ``type_info`` (resolving an id to run it) from a per-process cache of
    at most ``OP_LIST_TTL_S``, so a warm call costs one round trip to the ROS worker, not two."""
    key = tuple(nodes)
    if not with_info:
        hit = _OP_CACHE.get(key)
        if hit is not None and time.monotonic() - hit[0] < OP_LIST_TTL_S:
            return hit[1]
    answer = rosclient.get().call("op_list", {"nodes": nodes, "type_info": with_info})
    by_node = answer.get("nodes") if isinstance(answer.get("nodes"), dict) else {}
    if not with_info:
        if len(_OP_CACHE) >= OP_CACHE_MAX:
            _OP_CACHE.clear()
        _OP_CACHE[key] = (time.monotonic(), by_node)
    return by_node


def operations_of(entity: Entity, with_info: bool = True) -> list[Operation]:
    members = member_nodes(entity)
    by_node = _op_list([fqn for _, fqn in members], with_info)
    ops: list[Operation] = []
    for member, fqn in members:
        for op in by_node.get(fqn) or []:
            ops.append(Operation(member, op["kind"], op["path"], op["name"], op["type"], op.get("type_info")))
    # medkit's ids: a member that exposes a short name at two paths names them by path;
    # a short name several members expose is qualified by the member (components, functions).
    per_member = Counter((o.member, o.name) for o in ops)
    providers = Counter(o.name for o in ops)
    for o in ops:
        if per_member[(o.member, o.name)] > 1:
            o.id = o.path_id
        elif entity.aggregated and providers[o.name] > 1:
            o.id = f"{o.member}:{o.name}"
        else:
            o.id = o.name
    return ops


def resolve(entity: Entity, op_id: str, with_info: bool = True) -> Operation:
    """The one operation ``op_id`` names, or medkit's 404 / 400 (ambiguous)."""
    ops = operations_of(entity, with_info)
    member, item = None, op_id
    if entity.aggregated and ":" in op_id:
        member, _, item = op_id.partition(":")
        if member not in {m for m, _ in member_nodes(entity)}:
            raise ApiError(404, "resource-not-found", "Member not found in entity",
                           {"entity_id": entity.id, "operation_id": op_id, "member_id": member})
    matches = [o for o in ops if item in (o.name, o.path_id) and (member is None or o.member == member)]
    if not matches:
        raise ApiError(404, "operation-not-found", "Operation not found",
                       {"entity_id": entity.id, "operation_id": op_id})
    if len(matches) > 1:
        members = sorted({o.member for o in matches})
        params: dict[str, Any] = {"entity_id": entity.id, "operation_id": op_id,
                                  "ros2_paths": [o.path for o in matches], "operation_ids": [o.id for o in matches]}
        if entity.aggregated:
            params["member_ids"] = members
        if entity.aggregated and len(members) > 1:
            params["details"] = "Use format 'member_id:operation_id' to name the member that runs it"
            raise ApiError(400, "invalid-request", "Ambiguous operation id: more than one member provides it",
                           params)
        params["details"] = ("One provider exposes this short name at more than one ROS path; address the "
                             "one you mean by that path, without its leading slash")
        raise ApiError(400, "invalid-request", "Ambiguous operation id: it names more than one operation",
                       params)
    return matches[0]


def _params(entity: Entity, op_id: str, exec_id: str | None = None) -> dict[str, Any]:
    out = {"entity_id": entity.id, "operation_id": op_id}
    if exec_id is not None:
        out["execution_id"] = exec_id
    return out


def _call_timeout() -> float:
    return config().service_call_timeout + CALL_IPC_MARGIN_S


@bp.get(ENTITY + "/operations")
def listing(collection: str, entity_id: str):
    entity = lookup(collection, entity_id)
    items = [o.item(entity) for o in operations_of(entity)]
    return json_response({"items": items, "x-medkit": {"total_count": len(items)}})


@bp.get(OPERATION)
def detail(collection: str, entity_id: str, op_id: str):
    entity = lookup(collection, entity_id)
    return json_response({"item": resolve(entity, op_id).item(entity)})


@bp.post(OPERATION + "/executions")
def execute(collection: str, entity_id: str, op_id: str):
    authorize_operations()
    entity = lookup(collection, entity_id)
    op = resolve(entity, op_id, with_info=False)
    body = json_object('{"parameters": {...}}')
    params = _params(entity, op_id)
    data = next((body[k] for k in ("parameters", "request", "goal") if k in body), {})
    if not isinstance(data, dict):
        raise ApiError(400, "invalid-parameter", "parameters: must be an object",
                       {**params, "details": "send {\"parameters\": {...}} with the fields of the "
                                             + ("request" if op.kind == "service" else "goal")})
    type_name = body.get("type", op.type)
    if not isinstance(type_name, str):
        raise ApiError(400, "invalid-parameter", "type: must be a string", params)
    if op.kind == "service":
        result = ros_call("op_call", {"service": op.path, "type": type_name, "parameters": data}, _call_timeout(),
                          params=params, write=True)
        return json_response({"parameters": result.get("response")})
    result = ros_call("op_goal", {"action": op.path, "type": type_name, "parameters": data,
                                  "entity_id": entity.id}, _call_timeout(), params=params, write=True)
    location = f"{request.path.rstrip('/')}/{result['id']}"
    return json_response({"id": result["id"], "status": "running"}, 202, {"Location": location})


@bp.get(OPERATION + "/executions")
def executions(collection: str, entity_id: str, op_id: str):
    entity = lookup(collection, entity_id)
    op = resolve(entity, op_id, with_info=False)
    if op.kind != "action":
        return json_response({"items": []})
    goals = ros_call("op_goals", {"action": op.path}, params=_params(entity, op_id))["items"]
    return json_response({"items": [{"id": g["id"]} for g in goals]})


def goal_of(entity_id: str, op_id: str, exec_id: str) -> tuple[dict[str, Any], dict[str, Any]]:
    check_entity_id(entity_id)
    params = {"entity_id": entity_id, "operation_id": op_id, "execution_id": exec_id[:EXECUTION_ID_MAX]}
    if not exec_id or len(exec_id) > EXECUTION_ID_MAX:
        raise ApiError(404, "resource-not-found", "Execution not found", params)
    return ros_call("op_exec", {"id": exec_id}, params=params), params


def execution_body(goal: dict[str, Any]) -> dict[str, Any]:
    body: dict[str, Any] = {"status": goal["status"], "capability": "execute"}
    if goal.get("result") is not None:
        body["parameters"] = goal["result"]
    elif goal.get("feedback") is not None:
        body["parameters"] = goal["feedback"]
    ext: dict[str, Any] = {"goal_id": goal["id"], "ros2_status": goal["ros2_status"],
                           "ros2": {"action": goal["action"], "type": goal["type"]}}
    if goal.get("feedback") is not None:
        ext["feedback"] = goal["feedback"]
    if goal.get("result") is not None:
        ext["result"] = goal["result"]
    if goal.get("message"):
        ext["message"] = goal["message"]
    body["x-medkit"] = ext
    return body


@bp.get(EXECUTION)
def execution(collection: str, entity_id: str, op_id: str, exec_id: str):
    goal, _ = goal_of(entity_id, op_id, exec_id)
    return json_response(execution_body(goal))


def _cancel(entity_id: str, op_id: str, exec_id: str, verb: str, extra: dict[str, Any]) -> dict[str, Any]:
    goal, params = goal_of(entity_id, op_id, exec_id)
    params.update(extra)
    try:
        return rosclient.get().call("op_cancel", {"id": goal["id"]}, _call_timeout())
    except IpcError as exc:
        if exc.code == "deadline-exceeded":
            raise ApiError(504, "not-responding", f"{verb} outcome unknown: the ROS worker did not answer in "
                                                  "time", params) from None
        err = ApiError.from_ipc(exc, {**params, **({"return_code": exc.params["return_code"]}
                                                   if "return_code" in exc.params else {})})
        if exc.code == "not-responding":
            err.message = f"{verb} {exc.message}"
        raise err from None


@bp.delete(EXECUTION)
def cancel(collection: str, entity_id: str, op_id: str, exec_id: str):
    authorize_operations()
    _cancel(entity_id, op_id, exec_id, "Cancel", {})
    return "", 204


@bp.put(EXECUTION)
def update(collection: str, entity_id: str, op_id: str, exec_id: str):
    authorize_operations()
    check_entity_id(entity_id)
    body = json_object('{"capability": "stop"}')
    capability = body.get("capability")
    params = {"entity_id": entity_id, "operation_id": op_id, "execution_id": exec_id[:EXECUTION_ID_MAX],
              "capability": capability if isinstance(capability, str) else str(capability)[:100]}
    if capability == "stop":
        result = _cancel(entity_id, op_id, exec_id, "Stop", {"capability": "stop"})
        return json_response({"id": result.get("id", exec_id), "status": result.get("status", "running")}, 202,
                             {"Location": request.path})
    goal, _ = goal_of(entity_id, op_id, exec_id)
    if capability == "execute":
        raise ApiError(409, "precondition-not-fulfilled",
                       "Cannot re-execute while operation is running. Cancel first, then start new execution.",
                       params)
    message = ("Capability not supported for ROS 2 actions" if capability in ("freeze", "reset")
               else "Unknown capability")
    raise ApiError(400, "invalid-parameter", message, {**params, "supported_capabilities": ["stop"]})
