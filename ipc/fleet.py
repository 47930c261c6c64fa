"""The fleet's wire (issue 34): over Zenoh between the links, and the fleet link's IPC sockets.

Both sides use it: the fleet-link process (``supervisor/fleet/``) and the HTTP workers
(``app/fleet/``), which speak to the link over the IPC wire (``ipc/PROTOCOL.md``) with the commands
of :data:`COMMANDS` on :func:`endpoint` (``supervisor/fleet/PROTOCOL.md``).

Zenoh
Keys (``supervisor/fleet/PROTOCOL.md`` has the whole account):

- ``sovd/<fleet_id>/alive``: the robot's liveliness token (the fleet learns its robots from these);
- ``sovd/<fleet_id>/read/<family>``, ``sovd/<fleet_id>/write/<family>``: the robot's queryables; a
  query carries one SOVD request (:func:`request`), its reply one answer (:func:`reply`).  The family
  in the key must be the request path's (:func:`family_of`), so an access-control rule on keys is a
  rule on what may be asked (``sovd/*/read/**`` for a read-only fleet);
- ``sovd/<fleet_id>/events/faults``, ``.../events/triggers/<trigger id>``, ``.../events/tree``: what a
  robot publishes (JSON).

Zenoh envelopes are msgpack maps (``v`` is :data:`VERSION`): the request ``{m, p, q, h, b, t}`` (method,
path under ``/api/v1/``, query string, the forwarded headers, body, budget in ms, and ``after`` for
the events family), the reply ``{s, h, b}`` (status, headers, body).  Plain data, standard library and
msgpack only.
"""

from __future__ import annotations

import os
import re
from typing import Any

import msgpack

VERSION = 1
ROOT = "sovd"
API = "/api/v1"
SEPARATOR = "__"                   # medkit's EntityMerger::SEPARATOR: <fleet_id>__<app id>
MAX_BODY = 8 * 1024 * 1024         # an answer larger than this does not cross the fleet (502)
MAX_REQUEST = 2 * 1024 * 1024      # nor does a request
FLEET_ID = re.compile(r"^[A-Za-z0-9-]+(?:_[A-Za-z0-9-]+)*$")
FLEET_ID_MAX = 64

# Headers a request carries to the robot, and those of its answer that come back.
REQUEST_HEADERS = ("Authorization", "X-Client-Id", "X-Request-Id", "Content-Type", "Accept")
REPLY_HEADERS = ("Content-Type", "Location", "Retry-After", "WWW-Authenticate")
# Set by the robot's link on every request it makes to its own gateway: the gateway then asks for a
# valid identity even on a read (app/fleet/robotside.py).
MARK = "X-Sovd-Fleet"

COLLECTIONS = ("areas", "components", "apps", "functions")
RELATIONS = ("hosts", "subcomponents", "depends-on", "is-located-on", "belongs-to", "subareas",
             "components", "contains")
SUB_FAMILIES = {"data": "data", "data-categories": "data", "data-groups": "data", "faults": "faults",
                "logs": "logs", "configurations": "configurations", "operations": "operations",
                "triggers": "triggers", "cyclic-subscriptions": "subscriptions", "docs": "server"}
# Families a request path may have; "tree", "events" and "ping" are the link's own reads.
FAMILIES = ("discovery", "data", "faults", "logs", "configurations", "operations", "triggers",
            "subscriptions", "server", "other", "tree", "events", "ping")
# Answered by the robot's link itself (after its gateway accepted the caller's identity).
LINK_FAMILIES = ("tree", "events", "ping")


# The fleet link's IPC (supervisor/fleet/server.py, channel.py), in the gateway's runtime dir.
SOCKET_NAME = "fleetlink.sock"
CONTROL_SOCKET_NAME = "fleetlink-ctl.sock"
EVENTS_SOCKET_NAME = "fleetlink-events.sock"
LOCK_NAME = "fleetlink.lock"
COMMANDS = ("fleet_status", "fleet_list", "fleet_entity", "fleet_forward", "fleet_fanout", "fleet_events")


def endpoint(runtime_dir: str) -> str:
    return "ipc://" + os.path.join(runtime_dir, SOCKET_NAME)


def events_endpoint(runtime_dir: str) -> str:
    return "ipc://" + os.path.join(runtime_dir, EVENTS_SOCKET_NAME)


class WireError(ValueError):
    """A frame that is not one of ours; the message says why."""


def valid_fleet_id(name: Any) -> bool:
    return isinstance(name, str) and 0 < len(name) <= FLEET_ID_MAX and FLEET_ID.match(name) is not None


def alive_key(fleet_id: str) -> str:
    return f"{ROOT}/{fleet_id}/alive"


ALIVE_ALL = f"{ROOT}/*/alive"


def query_key(fleet_id: str, family: str, write: bool = False) -> str:
    """``sovd/<id>/read/<family>`` (``*`` for every robot)."""
    return f"{ROOT}/{fleet_id}/{'write' if write else 'read'}/{family}"


def queryable_keys(fleet_id: str) -> tuple[str, str]:
    return f"{ROOT}/{fleet_id}/read/**", f"{ROOT}/{fleet_id}/write/**"


def event_key(fleet_id: str, kind: str, name: str | None = None) -> str:
    return f"{ROOT}/{fleet_id}/events/{kind}" + (f"/{name}" if name else "")


FAULT_EVENTS_ALL = f"{ROOT}/*/events/faults"
TREE_EVENTS_ALL = f"{ROOT}/*/events/tree"


def parse_key(key: str) -> tuple[str, str, str] | None:
    """``sovd/<id>/<kind>/<rest>`` → ``(id, kind, rest)``; None for anything else."""
    parts = str(key).split("/", 3)
    if len(parts) < 3 or parts[0] != ROOT or not valid_fleet_id(parts[1]):
        return None
    return parts[1], parts[2], parts[3] if len(parts) > 3 else ""


def query_parts(key: str) -> tuple[str, str]:
    """``sovd/<id or *>/<read|write>/<family>`` → ``(kind, family)``; ``("", "")`` for anything else."""
    parts = str(key).split("/")
    if len(parts) != 4 or parts[0] != ROOT:
        return "", ""
    return parts[2], parts[3]


def family_of(path: str) -> str:
    """The family of an API path (``/api/v1/apps/x/data/t`` → ``data``); ``other`` when unknown."""
    if not path.startswith(API + "/") and path != API:
        return "other"
    parts = path[len(API) + 1:].split("/")
    head = parts[0]
    if head in COLLECTIONS:
        if len(parts) <= 2:
            return "discovery"
        sub = parts[2]
        if sub in SUB_FAMILIES:
            return SUB_FAMILIES[sub]
        return "discovery" if sub in RELATIONS else "other"
    if head == "faults":
        return "faults"
    if head in ("", "health", "version-info", "docs"):
        return "server"
    return "other"


def is_write(method: str) -> bool:
    return method not in ("GET", "HEAD")


def pack(obj: dict[str, Any]) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def unpack(frame: bytes, limit: int = MAX_BODY + 65536) -> dict[str, Any]:
    if len(frame) > limit:
        raise WireError(f"frame of {len(frame)} bytes exceeds {limit}")
    try:
        obj = msgpack.unpackb(frame, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types
        raise WireError(f"not a msgpack frame: {type(exc).__name__}") from None
    if not isinstance(obj, dict) or obj.get("v") != VERSION:
        raise WireError(f"not a fleet envelope of version {VERSION}")
    return obj


def request(method: str, path: str, query: str = "", headers: dict[str, str] | None = None,
            body: bytes = b"", budget_ms: int = 2000, **extra: Any) -> bytes:
    """One SOVD request as a query payload (only :data:`REQUEST_HEADERS` go along)."""
    kept = {k: v for k, v in (headers or {}).items() if k in REQUEST_HEADERS and isinstance(v, str)}
    return pack({"v": VERSION, "m": method, "p": path, "q": query, "h": kept, "b": body,
                 "t": int(budget_ms), **extra})


def read_request(frame: bytes) -> dict[str, Any]:
    """A query payload, checked: method, path under ``/api/v1``, headers, body and budget."""
    req = unpack(frame, MAX_REQUEST + 65536)
    method, path, query = req.get("m"), req.get("p"), req.get("q", "")
    headers, body, budget = req.get("h", {}), req.get("b", b""), req.get("t", 2000)
    if method not in ("GET", "HEAD", "POST", "PUT", "DELETE", "PATCH"):
        raise WireError(f"method {str(method)[:16]!r} is not one the fleet carries")
    if not isinstance(path, str) or not (path == API or path.startswith(API + "/")) or len(path) > 4096:
        raise WireError("path: expected an API path under /api/v1 of at most 4096 characters")
    if any(segment in (".", "..") for segment in path.split("/")):
        raise WireError("path: no . or .. segments")
    if any(c in path for c in "\r\n\0?#") or not isinstance(query, str) or len(query) > 4096 \
            or any(c in query for c in "\r\n\0#"):
        raise WireError("path or query string: control characters, '?' or '#' where they do not belong")
    if not isinstance(headers, dict) or not all(
            k in REQUEST_HEADERS and isinstance(v, str) and "\n" not in v and "\r" not in v
            and len(v) <= 8192 for k, v in headers.items()):
        raise WireError("headers: only " + ", ".join(REQUEST_HEADERS) + " as single-line strings")
    if not isinstance(body, bytes) or len(body) > MAX_REQUEST:
        raise WireError(f"body: at most {MAX_REQUEST} bytes")
    if isinstance(budget, bool) or not isinstance(budget, int) or not 1 <= budget <= 600000:
        raise WireError("t: the budget in ms, 1 to 600000")
    return req


def reply(status: int, body: bytes = b"", headers: dict[str, str] | None = None) -> bytes:
    kept = {k: v for k, v in (headers or {}).items() if k in REPLY_HEADERS and isinstance(v, str)}
    return pack({"v": VERSION, "s": int(status), "h": kept, "b": body})


def read_reply(frame: bytes) -> tuple[int, dict[str, str], bytes]:
    rep = unpack(frame)
    status, headers, body = rep.get("s"), rep.get("h", {}), rep.get("b", b"")
    if isinstance(status, bool) or not isinstance(status, int) or not 100 <= status <= 599:
        raise WireError("s: an HTTP status")
    if not isinstance(headers, dict) or not isinstance(body, bytes):
        raise WireError("h and b: a map and bytes")
    return status, {k: v for k, v in headers.items() if k in REPLY_HEADERS and isinstance(v, str)}, body


def error_body(status: int, error_code: str, message: str, **parameters: Any) -> bytes:
    """The contract's JSON error, for answers the link makes itself."""
    import orjson

    body: dict[str, Any] = {"error_code": error_code, "message": message}
    if parameters:
        body["parameters"] = parameters
    return orjson.dumps(body)


def error_reply(status: int, error_code: str, message: str, **parameters: Any) -> bytes:
    return reply(status, error_body(status, error_code, message, **parameters),
                 {"Content-Type": "application/json"})
