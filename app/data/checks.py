"""Checks on what a data request carries, done before anything reaches the ROS worker.

- the topic addressed by ``{data_id}`` (three spellings, one topic);
- the ``bytes`` query parameter;
- for ``PUT``: the body (read and parsed by ``bodies.json_object``, as every JSON body
  is).  Who may publish is ``auth.py``'s.
"""

from __future__ import annotations

from typing import Any
from urllib.parse import unquote_to_bytes, urlsplit

from flask import request

from ipc import protocol
from ipc.protocol import BYTES_MODES
from ipc.topics import InvalidTopic, normalize_topic, valid_message_type

from ..core.bodies import json_object
from ..core.common import BAD_PERCENT
from ..core.errors import ApiError

# Room left in one IPC frame for the envelope around a published message.
FRAME_SLACK = 64 * 1024


def _invalid_topic(details: str, data_id: str) -> ApiError:
    return ApiError(400, "invalid-parameter", "Invalid topic name",
                    {"details": details, "data_id": data_id[:300]})


def topic_from_data_id(data_id: str) -> str:
    """The ROS topic that ``{data_id}`` names, or a 400 ``invalid-parameter``.

    The server has already percent-decoded the path before routing, so
    ``a%2Fb``, ``a/b`` and ``/a/b`` (from ``data//a/b``) all arrive here as a
    path; a missing leading ``/`` is added.  What decoding hides is checked on
    the raw request URI when the server provides it (gunicorn and Werkzeug
    do): a ``%`` not followed by two hex digits, or bytes that are not UTF-8.
    """
    raw = request.environ.get("RAW_URI") or request.environ.get("REQUEST_URI")
    if raw:
        path = urlsplit(raw).path
        if BAD_PERCENT.search(path):
            raise _invalid_topic("the request path contains an invalid percent-encoding", data_id)
        try:
            unquote_to_bytes(path).decode("utf-8")
        except UnicodeDecodeError:
            raise _invalid_topic("the request path does not decode to UTF-8", data_id) from None
    if "\x00" in data_id:
        raise _invalid_topic("the topic name contains a NUL byte", data_id)
    try:
        return normalize_topic(data_id)
    except InvalidTopic as exc:
        raise _invalid_topic(str(exc), data_id) from None


def bytes_mode() -> str:
    """``array`` (default) or ``base64`` from ``?bytes=``."""
    if not request.environ.get("QUERY_STRING"):
        return "array"  # the common case, without parsing a query string
    mode = request.args.get("bytes", "array")
    if mode not in BYTES_MODES:
        raise ApiError(400, "invalid-parameter", "Invalid value of query parameter 'bytes'",
                       {"details": "expected 'array' or 'base64'", "bytes": mode[:100]})
    return mode


def _field_error(message: str, field: str) -> ApiError:
    return ApiError(400, "invalid-request", message, {"field": field})


def publish_body() -> tuple[str, dict[str, Any]]:
    """``(type, data)`` of a PUT body, or the contract's 415/413/400 (``bodies.json_object``)."""
    body = json_object('{"type": "pkg/msg/Name", "data": {...}}')
    if "type" not in body:
        raise _field_error("type: missing required field", "type")
    if not isinstance(body["type"], str):
        raise _field_error("type: must be a string", "type")
    if "data" not in body:
        raise _field_error("data: missing required field", "data")
    if not isinstance(body["data"], dict):
        raise _field_error("data: must be an object", "data")
    type_name = body["type"]
    if not valid_message_type(type_name):
        raise ApiError(400, "invalid-parameter", "Invalid message type format",
                       {"details": "Message type should be in format: package/msg/Type",
                        "type": type_name[:300]})
    data = body["data"]
    try:
        size = len(protocol.pack(data))
    except (ValueError, TypeError, OverflowError) as exc:
        raise ApiError(400, "invalid-request", "data: cannot be sent to ROS",
                       {"details": str(exc)[:300]}) from None
    if size > protocol.MAX_FRAME - FRAME_SLACK:
        raise ApiError(413, "payload-too-large", "Message too large to publish",
                       {"details": f"the encoded message is {size} bytes; the limit is "
                                   f"{protocol.MAX_FRAME - FRAME_SLACK}"})
    return type_name, data
