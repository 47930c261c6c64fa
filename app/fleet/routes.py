"""The fleet gateway's API (``fleet_aggregate``): medkit's aggregation contract over the fleet's robots.

The HTTP workers hold no tree and no Zenoh session: every answer comes from the fleet link
(``supervisor/fleet/``) over IPC, within a deadline.  What each route does (medkit's
``docs/config/aggregation.rst``):

- ``GET /api/v1/{areas,components,apps,functions}``: the merged tree (``supervisor/fleet/merge.py``):
  components and areas merged by id, colliding app ids renamed ``<fleet_id>__<id>``,
  ``x-medkit.contributors`` on every entity.
- ``/api/v1/{collection}/{id}[/...]``, any method: an entity that one robot owns (every app, a
  component, a function or area only one robot offers) is forwarded to that robot, under its own id
  there, and answered as the robot answered (medkit forwards verbatim).  A robot that is away or
  silent past ``fleet_timeout`` is ``504 not-responding``.  Writes pass only with ``fleet_allow_writes``
  (and the robot's own), carrying the caller's ``Authorization`` and ``X-Client-Id``.
- A function or area several robots offer is served here: its detail and ``hosts`` from the merged
  tree, its ``data``, ``operations``, ``faults``, ``configurations`` and ``logs`` collections fanned out
  to those robots (``x-medkit.partial`` and ``failed_peers`` when some did not answer in time).  An
  item under it names no single robot: ``400``, address it through the app that owns it.
- ``GET /api/v1/faults``: fanned out to every connected robot; ``GET /api/v1/faults/stream``: every
  robot's fault events (``app/fleet/stream.py``).
- ``/health``: the robots (``peers``: link state, latency) and medkit's ``warnings``.
- ``/fleet/<fleet_id>/api/v1/...`` (outside medkit's contract, beside ``/ui``): one robot's own API
  through the fleet, under its own ids, forwarded as the entity routes are; with
  ``/fleet/<fleet_id>/ui/`` the dashboard shows that robot (its robot picker, ``app/ui/js/fleet.js``).

Every route that shows what the robots hold asks for a valid identity first (``app/core/auth.py``):
the fleet gateway's tree and events are the robots' data, and each robot checks the forwarded
identity again itself.
"""

from __future__ import annotations

import time
from typing import Any
from urllib.parse import quote

from flask import Blueprint, current_app, redirect, request

from common.process import DISTRIBUTION, package_version
from ipc import counters, fleet

from .. import openapi
from ..core import requestid, ui, unimplemented
from ..core import root as root_routes
from ..core.auth import authorize_change
from ..core.common import check_entity_id, config, json_response
from ..core.entities import API_BASE, KINDS, RELATIONS, Entity
from ..core.errors import ApiError
from . import link, stream

bp = Blueprint("fleet", __name__, url_prefix=API_BASE)

METHODS = ["GET", "PUT", "POST", "DELETE", "PATCH"]
FANOUT = ("data", "operations", "faults", "configurations", "logs")  # medkit's fan-out collections
MARGIN_S = 0.5           # the IPC deadline beyond fleet_timeout (the link bounds the robots by it)
STATUS_TIMEOUT_S = 0.5
WARNING_SCHEMA_VERSION = 2   # medkit's /health warnings contract


def _json(body: bytes, status: int = 200):
    return current_app.response_class(body, status=status, mimetype="application/json")


def _timeout() -> float:
    return config().fleet_timeout + MARGIN_S


def _headers() -> dict[str, str]:
    out = {name: request.headers[name] for name in fleet.REQUEST_HEADERS if name in request.headers}
    rid = requestid.current()
    if rid:
        out["X-Request-Id"] = rid
    return out


# ---- the gateway itself -------------------------------------------------------------------------------
@bp.get("/")
def root():
    writes = bool(config().fleet_allow_writes)
    return json_response({
        "name": DISTRIBUTION, "version": package_version(), "api_base": API_BASE,
        "endpoints": openapi.endpoint_list(),
        "capabilities": {
            "discovery": True, "data_access": True, "publishing": writes, "authentication": True, "docs": True,
            "cyclic_subscriptions": False,  # streams are not carried through the fleet (docs/fleet.md)
            "operations": True, "async_actions": True, "operation_execution": writes,
            "configurations": True, "faults": True, "logs": True, "triggers": True,
            "configuration_writes": writes,
            **unimplemented.capabilities(),
            "aggregation": True,
        },
    })


bp.add_url_rule("/version-info", view_func=root_routes.version_info, methods=["GET"])
bp.add_url_rule("/docs", view_func=root_routes.docs, methods=["GET"])


def fleet_section(stats: dict[str, Any] | None) -> dict[str, Any]:
    """``/health``'s ``x-medkit-fleet``: the link's counters (zeros, and the settings, until it answers)."""
    section: dict[str, Any] = counters.health_defaults("fleet", config())
    if stats and isinstance(stats.get("fleet"), dict):
        section.update(stats["fleet"])
    return section


@bp.get("/health")
def health():
    """The fleet gateway's liveness, its robots (medkit's ``peers``) and ``warnings``; never waits long."""
    fleet_link = link.get()
    alive, status = fleet_link.status(STATUS_TIMEOUT_S)
    _, stats = fleet_link.stats()
    status = status or {}
    return json_response({
        "status": "healthy" if alive else "unhealthy",
        "timestamp": time.time_ns(),
        "discovery": {"mode": "aggregation", "strategy": "fleet"},
        "peers": status.get("peers") or [],
        "warnings": status.get("warnings") or [],
        "warning_schema_version": WARNING_SCHEMA_VERSION,
        # the fleet link stands where a robot's ROS worker stands (the dashboard reads its state here)
        "x-medkit-subscription-executor": {"worker_alive": alive, "degraded": False},
        "x-medkit-fleet": {**fleet_section(stats), "link_alive": alive,
                           "session_error": status.get("session_error", "")},
    })


# ---- the merged tree ------------------------------------------------------------------------------------
@bp.get("/<collection:collection>")
def listing(collection: str):
    authorize_change()
    return _json(link.get().call("fleet_list", {"collection": collection})["body"])


@bp.route("/<collection:collection>/<entity_id>", methods=METHODS)
def entity(collection: str, entity_id: str):
    return _entity(collection, entity_id, "")


@bp.route("/<collection:collection>/<entity_id>/<data_id:rest>", methods=METHODS)
def entity_part(collection: str, entity_id: str, rest: str):
    return _entity(collection, entity_id, rest)


def _entity(collection: str, entity_id: str, rest: str):
    authorize_change()
    if fleet.is_write(request.method) and not config().fleet_allow_writes:
        raise ApiError(403, "forbidden", "Writes through the fleet are disabled on this fleet gateway",
                       {"details": "start it with --fleet-allow-writes (and each robot's gateway too)"})
    check_entity_id(entity_id)
    found = link.get().call("fleet_entity", {"collection": collection, "id": entity_id})
    if not found.get("found"):
        expected = KINDS[collection][1]
        if found.get("elsewhere"):
            raise ApiError(400, "invalid-parameter",
                           f"Invalid entity type for route: expected {expected}, got {found['elsewhere']}",
                           {"entity_id": entity_id, "expected_type": expected, "actual_type": found["elsewhere"]})
        raise ApiError(404, "entity-not-found", "Entity not found", {"entity_id": entity_id})
    if found.get("route"):
        robot, original = found["route"]
        return _forward(robot, f"{API_BASE}/{collection}/{original}{_raw_tail(collection, entity_id, rest)}")
    return _served_here(collection, entity_id, rest, found)


def _raw_path() -> str:
    """The request's path as the client sent it (still percent-encoded), from ``/api/v1`` on."""
    raw = (request.environ.get("RAW_URI") or request.environ.get("REQUEST_URI") or "").split("?", 1)[0]
    at = raw.find(API_BASE + "/")
    if at < 0:
        raw, at = quote(request.path, safe="/:@!$&'()*+,;=-._~"), request.path.find(API_BASE + "/")
    return raw[at:] if at >= 0 else raw


def _raw_tail(collection: str, entity_id: str, rest: str) -> str:
    """What follows the entity in the path as the client sent it."""
    raw = _raw_path()
    head = f"{API_BASE}/{collection}/{entity_id}"
    return raw[len(head):] if raw.startswith(head) else ("/" + quote(rest, safe="/:@!$&'()*+,;=-._~") if rest else "")


def _forward(robot: str, path: str):
    answer = link.get().call("fleet_forward", {
        "robot": robot, "method": request.method, "path": path,
        "query": request.query_string.decode("latin-1"), "headers": _headers(),
        "body": request.get_data(cache=False) if fleet.is_write(request.method) else b""}, _timeout())
    headers = {k: v for k, v in (answer.get("headers") or {}).items() if k in fleet.REPLY_HEADERS}
    status = answer["status"]
    body = answer.get("body") or b""
    return current_app.response_class(body if status != 204 else None, status=status, headers=headers)


def _served_here(collection: str, entity_id: str, rest: str, found: dict[str, Any]):
    """A function or area several robots offer: its detail and relations here, its collections fanned out."""
    item = found["item"]
    part = rest.strip("/")
    if request.method == "GET" and not part:
        ext = dict(item.get("x-medkit") or {})
        hosts = item.get("hosts") if collection == "functions" else None
        return json_response(Entity(collection, entity_id, item.get("name", entity_id), ext,
                                    description=item.get("description"), hosts=hosts).detail())
    if request.method == "GET" and (collection, part) in RELATIONS:
        href = f"{API_BASE}/{collection}/{entity_id}"
        items = found.get("hosts") or [] if part == "hosts" else []
        return json_response({"items": items, "x-medkit": {"total_count": len(items)},
                              "_links": {"self": f"{href}/{part}", RELATIONS[(collection, part)][1]: href}})
    if request.method == "GET" and part in FANOUT:
        if part == "faults":
            stream.check({"entity_id": entity_id})   # medkit's 400 for a bad ?status= (nothing sent)
        return _json(_fanout(found.get("contributors") or [], entity_id))
    robots = ", ".join(found.get("contributors") or [])
    raise ApiError(400, "invalid-request", f"{KINDS[collection][1]} '{entity_id}' spans several robots ({robots}); "
                   "address the item through the app or component that owns it",
                   {"entity_id": entity_id, "peers": found.get("contributors") or []})


def _fanout(targets: list[str] | None, entity_id: str | None = None) -> bytes:
    return link.get().call("fleet_fanout", {
        "path": _raw_path(), "query": request.query_string.decode("latin-1"), "headers": _headers(),
        "targets": targets, "entity_id": entity_id}, _timeout())["body"]


# ---- faults ---------------------------------------------------------------------------------------------
@bp.get("/faults")
def faults():
    authorize_change()
    stream.check()   # medkit's 400 for a bad ?status=, before any robot is asked
    return _json(_fanout(None))


@bp.get("/faults/stream")
def fault_stream():
    authorize_change()
    return stream.response()


# ---- one robot's own API, and the dashboard on it (the robot picker) -------------------------------------
robot_bp = Blueprint("fleet_robot", __name__, url_prefix="/fleet/<fleet_id>")


@robot_bp.after_request
def _ui_headers(response):
    """The dashboard's security headers (``app/core/ui.py``) on its files here too."""
    return ui._security_headers(response) if "/ui" in request.path else response


def _robot_name(fleet_id: str) -> str:
    if not fleet.valid_fleet_id(fleet_id):
        raise ApiError(404, "resource-not-found", "Resource not found", {"path": request.path})
    return fleet_id


@robot_bp.get("/")
def robot_root(fleet_id: str):
    _robot_name(fleet_id)
    return redirect("ui/", 302)


@robot_bp.get("/ui/")
def robot_ui(fleet_id: str):
    _robot_name(fleet_id)
    return ui.index()


@robot_bp.get("/ui/<path:name>")
def robot_ui_asset(fleet_id: str, name: str):
    _robot_name(fleet_id)
    return ui.asset(name)


@robot_bp.route("/api/v1/", methods=METHODS, defaults={"rest": ""})
@robot_bp.route("/api/v1/<data_id:rest>", methods=METHODS)
def robot_api(fleet_id: str, rest: str):
    robot = _robot_name(fleet_id)
    authorize_change()
    if fleet.is_write(request.method) and not config().fleet_allow_writes:
        raise ApiError(403, "forbidden", "Writes through the fleet are disabled on this fleet gateway",
                       {"details": "start it with --fleet-allow-writes (and each robot's gateway too)"})
    raw = _raw_path()
    return _forward(robot, raw if raw.startswith(API_BASE + "/") else f"{API_BASE}/{quote(rest)}")
