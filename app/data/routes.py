"""``{entity}/data``: the entity's data items, one sample of a topic, publishing one message.

Reading a sample is the hot path: the ROS worker sends the message already
encoded as JSON (``data_json``), and the body is assembled around those bytes
without decoding them.
"""

from __future__ import annotations

import time
from typing import Any

from flask import Blueprint, current_app

from ipc.errors import IpcError

from ..core import rosclient
from ..core.auth import authorize_publish
from ..core.common import check_entity_id, config, json_response, lookup
from ..core.entities import API_BASE, data_items
from ..core.errors import ApiError
from . import model as samples
from .checks import bytes_mode, publish_body, topic_from_data_id

bp = Blueprint("data", __name__, url_prefix=API_BASE)

# The IPC deadline of a sample is the sample timeout plus this margin.
SAMPLE_IPC_MARGIN_S = 1.5
# Sample bodies larger than this are sent as three writes instead of one joined copy.
SPLICE_COPY_LIMIT = 64 * 1024
ENTITY = "/<collection:collection>/<entity_id>"


@bp.get(ENTITY + "/data")
def listing(collection: str, entity_id: str):
    entity = lookup(collection, entity_id)
    ros = rosclient.get()
    types = sorted({t.type for t in entity.topics.values() if t.type})
    infos: dict[str, dict[str, Any] | None] = {}
    # type_info is a nicety: bounded by one IPC timeout overall, left out on trouble.
    deadline = time.monotonic() + config().ipc_timeout
    for type_name in types:
        remaining = deadline - time.monotonic()
        if remaining <= 0.01:
            break
        try:
            infos[type_name] = ros.type_info(type_name, timeout=remaining)
        except IpcError as exc:
            if exc.code in ("unavailable", "shutdown"):
                raise
            current_app.logger.info("type_info %s: %s", type_name, exc.message)
            break
    return json_response(data_items(entity, infos))


@bp.get(ENTITY + "/data/<data_id:data_id>")
def read(collection: str, entity_id: str, data_id: str):
    check_entity_id(entity_id)
    topic = topic_from_data_id(data_id)
    mode = bytes_mode()
    entity = lookup(collection, entity_id)
    timeout = config().sample_timeout
    args: dict[str, Any] = {"topic": topic, "timeout_ms": int(round(timeout * 1000))}
    if mode != "array":
        args["bytes"] = mode
    try:
        result = rosclient.get().call("sample", args, timeout + SAMPLE_IPC_MARGIN_S)
    except IpcError as exc:
        raise samples.error(exc, entity.id, topic, data_id, config().cold_wait_cap) from None
    head, data, tail = samples.body_parts(topic, result, entity.id, _type_info(result.get("type")))
    if len(data) > SPLICE_COPY_LIMIT:
        # A large message (an image is ~3 MB of JSON) is not copied once more: the three
        # parts are written one after the other (Werkzeug adds their Content-Length).
        return current_app.response_class([head, data, tail], mimetype="application/json")
    return current_app.response_class(b"".join((head, data, tail)), mimetype="application/json")


def _type_info(type_name: Any) -> bytes | None:
    """``x-medkit.type_info`` of a read, as medkit sends it; from the per-process cache the
    listing fills, so only the first read of a type in this process asks the ROS worker.
    Left out on trouble, as in the listing."""
    if not isinstance(type_name, str):
        return None
    try:
        return rosclient.get().type_info_json(type_name, timeout=config().ipc_timeout)
    except IpcError as exc:
        current_app.logger.info("type_info %s: %s", type_name, exc.message)
        return None


@bp.put(ENTITY + "/data/<data_id:data_id>")
def write(collection: str, entity_id: str, data_id: str):
    # medkit's order: authentication (its pre-routing middleware; here with the gateway-wide
    # publish switch), then the entity, so that a wrong route is named whatever the body,
    # then the body.  The path's own syntax (entity id, topic name) is checked before the
    # entity is looked up, as a read does: it needs no ROS worker.
    authorize_publish()
    check_entity_id(entity_id)
    topic = topic_from_data_id(data_id)
    entity = lookup(collection, entity_id)
    type_name, data = publish_body()
    timeout = config().ipc_timeout
    try:
        # Not idempotent: sent once, never again after a timeout.
        result = rosclient.get().call("publish", {"topic": topic, "type": type_name, "data": data}, timeout)
    except IpcError as exc:
        params = {"entity_id": entity.id, "topic_name": data_id[:300]}
        if exc.code == "deadline-exceeded":
            raise ApiError.from_ipc(exc, params, message=(
                f"The ROS worker did not confirm the publish within {timeout:g} s; "
                "the message may or may not have been published")) from None
        raise ApiError.from_ipc(exc, params) from None
    ext: dict[str, Any] = {"ros2": {"topic": topic, "type": type_name}, "entity_id": entity.id,
                           "status": "published"}
    for key in ("subscriber_count", "unmatched_subscriber_count"):
        value = result.get(key)
        ext[key] = value if isinstance(value, int) and not isinstance(value, bool) else 0
    if ext["unmatched_subscriber_count"]:
        ext["warning"] = (f"{ext['unmatched_subscriber_count']} subscriber(s) of {topic} did not receive "
                          "the message: their QoS or message-type version does not match, or they "
                          "were not discovered in time")
    return json_response({"id": topic, "data": data, "x-medkit": ext})


@bp.get(ENTITY + "/data-categories")
def data_categories(collection: str, entity_id: str):
    raise ApiError(501, "not-implemented", "Data categories are not implemented for ROS 2",
                   {"feature": "data-categories"})


@bp.get(ENTITY + "/data-groups")
def data_groups(collection: str, entity_id: str):
    raise ApiError(501, "not-implemented", "Data groups are not implemented for ROS 2",
                   {"feature": "data-groups"})
