"""An action's execution as cyclic subscriptions stream it (``core/resources.py``).

``…/operations/{op_id}/executions/{exec_id}`` is checked as a GET of it would be
(an unknown operation or execution is the same 404; a malformed path is 400
``x-medkit-invalid-resource-uri``) and becomes the ROS worker's ``execution``
subscription (``rosworker/operations/feed.py``); each frame is the body a GET of
the execution answers: status, feedback, and at the end the result.
"""

from __future__ import annotations

from typing import Any
from urllib.parse import unquote

import orjson
from flask import Flask

from ipc.errors import IpcError

from ..core import resources
from ..core.entities import Entity
from ..core.errors import ApiError
from ..core.resources import Resource
from .routes import EXECUTION_ID_MAX, execution_body, goal_of, resolve

EXECUTION_PATH = "/api/v1/{apps|components|functions}/{id}/operations/{op_id}/executions/{exec_id}"


def subscribed(resource: Resource, entity: Entity) -> dict[str, Any]:
    head, sep, exec_raw = resource.rest.rpartition("/executions/")
    if not sep or not head.startswith("/") or len(head) < 2 or not exec_raw or "/" in exec_raw:
        raise resource.invalid(f"an execution is streamed as {EXECUTION_PATH}")
    op_id, exec_id = unquote(head[1:]), unquote(exec_raw)
    op = resolve(entity, op_id, with_info=False)
    params = {"entity_id": entity.id, "operation_id": op_id, "execution_id": exec_id[:EXECUTION_ID_MAX]}
    if op.kind != "action":  # a service call has no execution to follow
        raise ApiError(404, "resource-not-found", "Execution not found", params)
    goal, _ = goal_of(entity.id, op_id, exec_id)
    if goal.get("action") != op.path:
        raise ApiError(404, "resource-not-found", "Execution not found", params)
    return {"kind": "execution", "target": {"goal": goal["id"], "operation_id": op_id}}


def payload(stream: Any, meta: dict[str, Any], data: bytes) -> bytes:
    return orjson.dumps(execution_body(orjson.loads(data)))


def error(stream: Any, exc: IpcError) -> bytes:
    params = {"entity_id": stream.entity_id, "operation_id": stream.target.get("operation_id"),
              "execution_id": stream.target.get("goal")}
    return orjson.dumps(ApiError.from_ipc(exc, params).to_dict())


def setup(app: Flask) -> None:
    resources.streamable(app, resources.Streamable("operations", ("execution",), subscribed, payload, error))
