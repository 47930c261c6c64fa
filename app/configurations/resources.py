"""A parameter as cyclic subscriptions stream it (``core/resources.py``).

``…/configurations/{param_id}`` is checked as a GET of it would be (an unknown
parameter is the same 404; a malformed path is 400
``x-medkit-invalid-resource-uri``) and becomes the ROS worker's ``parameter``
subscription (``rosworker/configurations/feed.py``); each frame is the body a
GET of the parameter answers (its value as the node reports it), or the error
body such a GET would answer.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any
from urllib.parse import unquote

import orjson
from flask import Flask

from ipc.errors import IpcError

from ..core import resources
from ..core.entities import Entity
from ..core.errors import IPC_ANSWERS, ApiError
from ..core.resources import Resource
from .routes import WORKER_ERRORS, node_error, parameter_nodes, read_value, ros_param

PARAMETER_PATH = "/api/v1/{apps|components|functions}/{id}/configurations/{param_id}"


def subscribed(resource: Resource, entity: Entity) -> dict[str, Any]:
    rest = resource.rest
    param_id = unquote(rest[1:]) if rest.startswith("/") else ""
    if not param_id or "/" in rest[1:]:
        raise resource.invalid(f"a parameter is streamed as {PARAMETER_PATH}")
    nodes, app_id, name = parameter_nodes(entity, param_id)
    if app_id is not None:
        fqn = dict(nodes)[app_id]
        ros_param("param_get", {"node": fqn, "name": name}, "Failed to get parameter", entity.id, param_id)
        target = {"node": fqn, "name": name, "id": param_id, "source_app": app_id}
        return {"kind": "parameter", "target": target}
    for app, fqn in nodes:  # a bare id: the first node that has it, as a GET answers
        try:
            ros_param("param_get", {"node": fqn, "name": name}, "Failed to get parameter", entity.id, param_id)
        except ApiError as exc:
            if exc.status == 404 and len(nodes) > 1:
                continue
            raise
        target = {"node": fqn, "name": name, "id": name, "source_app": app if len(nodes) > 1 else None}
        return {"kind": "parameter", "target": target}
    raise ApiError(404, "resource-not-found", "Parameter not found", {"entity_id": entity.id, "id": param_id})


def payload(stream: Any, meta: dict[str, Any], data: bytes) -> bytes:
    wire = orjson.loads(data)
    return orjson.dumps(read_value(SimpleNamespace(id=stream.entity_id), wire["node"], wire["id"],
                                   wire.get("source_app"), wire["parameter"]))


def error(stream: Any, exc: IpcError) -> bytes:
    param_id = stream.target.get("id")
    if exc.code in IPC_ANSWERS and exc.code not in WORKER_ERRORS:
        return orjson.dumps(node_error(exc, "Failed to get parameter", stream.entity_id, param_id).to_dict())
    return orjson.dumps(ApiError.from_ipc(exc, {"entity_id": stream.entity_id, "id": param_id}).to_dict())


def setup(app: Flask) -> None:
    resources.streamable(app, resources.Streamable("configurations", ("parameter",), subscribed, payload, error))
