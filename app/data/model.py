"""One sample as the HTTP side answers it: the body of ``GET .../data/{topic}``, or its error.

Shared by the data route (``app/data/routes.py``) and the cyclic-subscription
streams (``app/subscriptions/hub.py``), whose frames carry exactly that body.  The ROS
worker sends the message already encoded as JSON (``data_json``); the body
is assembled around those bytes without decoding them.
"""

from __future__ import annotations

import time
from typing import Any

import orjson

from ipc.errors import IpcError

from ..core.errors import ApiError


def body_parts(topic: str, result: dict[str, Any], entity_id: str,
               type_info: bytes | None = None) -> tuple[bytes, bytes, bytes]:
    """``(head, data, tail)`` of the sample body; joined, they are the JSON document.

    ``type_info``: the type's ``{schema, default_value}`` already encoded as JSON
    (``RosClient.type_info_json``), spliced in as ``x-medkit.type_info``.
    """
    data = result.get("data_json")
    if not isinstance(data, bytes) or not data:
        data = b"{}"
    status = result.get("status") if result.get("status") in ("data", "metadata_only") else "metadata_only"
    ros2: dict[str, Any] = {"topic": topic}
    if isinstance(result.get("type"), str):
        ros2["type"] = result["type"]
    ext: dict[str, Any] = {
        "entity_id": entity_id,
        "timestamp": result.get("timestamp") if isinstance(result.get("timestamp"), int) else time.time_ns(),
        "ros2": ros2,
        "publisher_count": result.get("publisher_count", 0),
        "subscriber_count": result.get("subscriber_count", 0),
        "status": status,
    }
    if status == "metadata_only":
        if result.get("reason"):
            ext["reason"] = result["reason"]
        data = b"{}"
    head = b'{"id":' + orjson.dumps(topic) + b',"data":'
    ext_json = orjson.dumps(ext)
    if type_info:
        ext_json = ext_json[:-1] + b',"type_info":' + type_info + b"}"
    tail = b',"x-medkit":' + ext_json + b"}"
    return head, data, tail


def error(exc: IpcError, entity_id: str, topic: str, data_id: str, cold_wait_cap: int) -> ApiError:
    """The HTTP error a read of ``topic`` answers for a ROS-worker error."""
    params = {"entity_id": entity_id, "topic_name": data_id[:300]}
    if exc.code == "cold-wait-cap-exceeded":
        cap = exc.params.get("cold_wait_cap", cold_wait_cap)
        return ApiError.from_ipc(
            exc, {"topic": topic, "cold_wait_cap": cap, **params},
            message=f"Too many requests are already waiting for the first message of cold topics "
                    f"(cap {cap}); retry with backoff",
        )
    return ApiError.from_ipc(exc, params)
