"""Protocol constants and framing; the messages themselves are in PROTOCOL.md.

One request → one reply, each a single ZeroMQ frame of msgpack:

    request: {"v": 1, "id": int, "cmd": str, "args": map, "deadline_ms": int, "request_id"?: str}
    reply:   {"v": 1, "id": int, "ok": true,  "result": map}
           | {"v": 1, "id": int, "ok": false, "error": {code, message, status, params}}

``deadline_ms`` is the caller's remaining budget when it sent the request;
the ROS worker does not start work whose budget has run out, and a cold
sample never waits past it.  ``request_id`` (optional) is the HTTP request's
``X-Request-Id``: the ROS worker puts it into the log lines of that command.
"""

from __future__ import annotations

import os
import re
from typing import Any

import msgpack

from . import counters

VERSION = 1
SOCKET_NAME = "rosworker.sock"               # work: every command, served by the ROS thread
CONTROL_SOCKET_NAME = "rosworker-ctl.sock"    # control: ping and stats, never behind ROS work
LOCK_NAME = "rosworker.lock"
MAX_FRAME = 4 * 1024 * 1024          # requests larger than this are dropped unread
MAX_REPLY_FRAME = 256 * 1024 * 1024  # a reply may carry a large sample
# How a sample shows byte arrays (``bytes`` of sample, subscribe and sub_create; ``?bytes=``).
BYTES_MODES = ("array", "base64")
# An HTTP request's id (X-Request-Id) as it may cross the wire and reach a log line.
REQUEST_ID = re.compile(r"^[A-Za-z0-9._-]{1,128}$")

# Every command (``ipc/counters.py``'s table: who serves it, and whether it is a write).
COMMANDS = tuple(c.name for c in counters.COMMANDS)
# Commands answered from counters by the control thread, without queueing behind ROS work;
# clients send them to the control socket.
IMMEDIATE = tuple(c.name for c in counters.COMMANDS if c.family == "control")
# Commands that change something on the robot or in the gateway.  Once one was sent, an answer
# lost with the ROS worker leaves its outcome unknown (``outcome-unknown``, not ``unavailable``):
# a client must look before it tries again (a service call is not idempotent).
WRITES = frozenset(c.name for c in counters.COMMANDS if c.write)


def endpoint(runtime_dir: str) -> str:
    """The work socket of the ROS worker serving ``runtime_dir``."""
    return "ipc://" + os.path.join(runtime_dir, SOCKET_NAME)


def control_endpoint(work_endpoint: str) -> str:
    """The control socket beside a work socket (``.../rosworker.sock`` → ``.../rosworker-ctl.sock``;
    the fleet link's ``.../fleetlink.sock`` → ``.../fleetlink-ctl.sock``)."""
    head, sep, tail = work_endpoint.rpartition("/")
    if sep and tail.endswith(".sock"):
        return f"{head}{sep}{tail[:-len('.sock')]}-ctl.sock"
    return f"{head}{sep}{CONTROL_SOCKET_NAME}" if sep else work_endpoint + "-ctl"


def valid_request_id(value: Any) -> bool:
    """1–128 characters of ``[A-Za-z0-9._-]``: safe in a log line, a header and a grep."""
    return isinstance(value, str) and REQUEST_ID.fullmatch(value) is not None


def pack(message: dict[str, Any]) -> bytes:
    return msgpack.packb(message, use_bin_type=True)


def unpack(frame: bytes | memoryview, max_size: int = MAX_FRAME) -> Any:
    """Decode one frame; raises ValueError on anything that is not a msgpack map."""
    if len(frame) > max_size:
        raise ValueError(f"frame of {len(frame)} bytes exceeds {max_size}")
    try:
        obj = msgpack.unpackb(
            frame, raw=False, strict_map_key=True,
        )
    except Exception as exc:  # msgpack raises several unrelated types
        raise ValueError(f"not a msgpack frame: {type(exc).__name__}") from None
    if not isinstance(obj, dict):
        raise ValueError("frame is not a map")
    return obj
