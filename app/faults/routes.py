"""``/faults``: the robot's ``/diagnostics`` as SOVD faults (medkit's fault handlers).

The ROS worker keeps the faults (``rosworker/faults/manager.py``, stored in SQLite);
these routes ask it for them and apply medkit's rules here:

- ``?status=`` as medkit's transport asks its fault manager
  (``ros2_fault_service_transport.cpp``, ``parse_fault_status_param``):
  ``pending`` is PREFAILED, ``confirmed`` CONFIRMED, ``healed`` HEALED and
  PREPASSED, ``cleared`` CLEARED with what ``healed`` holds (SOVD's "cleared"),
  ``all`` every status; without it pending and confirmed (PREFAILED,
  CONFIRMED); anything else is 400 ``invalid-parameter``.
- Entity scope (medkit's all-sources rule, ``fault_scope.cpp``): a fault belongs
  to an app, component or function when *every* one of its reporting sources is
  one of the entity's nodes (or below one: ``/a/b`` is below ``/a``).  A fault
  out of scope is "not found" there.
- Clearing (DELETE) is a write: ``allow_fault_clear`` (and the role and locks every write passes).
- ``GET /api/v1/faults/stream``: Server-Sent Events (``hub.py``).
"""

from __future__ import annotations

import json
from typing import Any

from flask import Blueprint, current_app, request

from ..core.common import config, in_scope, json_response, lookup, node_names
from ..core.entities import API_BASE, PARAM_NAMES, Entity
from ..core.errors import ApiError
from ..core.roscall import ros_call
from ..sse.stream import rfc3339
from . import hub

bp = Blueprint("faults", __name__, url_prefix=API_BASE)

ENTITY = "/<collection:collection>/<entity_id>"
CODE_MAX = 256
STATUS_FILTERS = {
    "pending": ("PREFAILED",),
    "confirmed": ("CONFIRMED",),
    "cleared": ("CLEARED", "HEALED", "PREPASSED"),
    "healed": ("HEALED", "PREPASSED"),
    "all": ("PREFAILED", "CONFIRMED", "CLEARED", "HEALED", "PREPASSED"),
}
DEFAULT_STATUSES = ("PREFAILED", "CONFIRMED")  # medkit's include_pending and include_confirmed
OUT_OF_SCOPE = ("Fault is not in scope for this entity: every reporting source must be one of the entity's "
                "owned apps, and a mixed-source fault that includes any out-of-entity reporter is rejected "
                "to prevent cross-entity disclosure")
# medkit's extract_primary_value: the field a snapshot's ``data`` shows for these types
PRIMARY_FIELDS = {
    "std_msgs/msg/Float64": "data", "std_msgs/msg/Float32": "data", "std_msgs/msg/Int32": "data",
    "std_msgs/msg/Int64": "data", "std_msgs/msg/Bool": "data", "std_msgs/msg/String": "data",
    "sensor_msgs/msg/Temperature": "temperature", "sensor_msgs/msg/BatteryState": "percentage",
    "sensor_msgs/msg/FluidPressure": "fluid_pressure", "sensor_msgs/msg/Range": "range",
    "geometry_msgs/msg/Twist": "linear", "nav_msgs/msg/Odometry": "pose",
}


# ---- helpers ----------------------------------------------------------------------------------------
def status_filter(extra: dict[str, Any] | None = None) -> tuple[str, ...]:
    if "status" not in request.args:
        return DEFAULT_STATUSES
    value = request.args.get("status", "")
    if value not in STATUS_FILTERS:
        raise ApiError(400, "invalid-parameter", "Invalid status parameter value",
                       {"allowed_values": "pending, confirmed, cleared, healed, all", "parameter": "status",
                        "value": value[:300], **(extra or {})})
    return STATUS_FILTERS[value]


def _call(cmd: str, args: dict[str, Any], params: dict[str, Any] | None = None) -> dict[str, Any]:
    return ros_call(cmd, args, config().ipc_timeout, params=params)


def _list(statuses: tuple[str, ...]) -> list[dict[str, Any]]:
    return _call("fault_list", {"statuses": list(statuses)}).get("items") or []


def _check_code(code: str) -> None:
    if not code or len(code) > CODE_MAX:
        raise ApiError(400, "invalid-parameter", "Invalid fault code",
                       {"details": f"Fault code must be between 1 and {CODE_MAX} characters"})


def _authorize_clear() -> None:
    if not config().allow_fault_clear:
        raise ApiError(403, "forbidden", "Clearing faults is disabled on this gateway",
                       {"details": "start the gateway with --allow-fault-clear to enable DELETE .../faults"})


def _scoped_fault(collection: str, entity: Entity, code: str) -> dict[str, Any]:
    """``fault_get`` of ``code``, 404 when there is none or it is out of the entity's scope."""
    params = {PARAM_NAMES[collection]: entity.id, "fault_code": code}
    answer = ros_call("fault_get", {"code": code}, config().ipc_timeout, params=params, not_found={
        "no-such-fault": ("Fault not found", {"details": f"Fault not found: {code}", **params})})
    if not in_scope(answer.get("fault") or {}, node_names(entity)):
        raise ApiError(404, "resource-not-found", "Fault not found", {"details": OUT_OF_SCOPE, **params})
    return answer


def _status_object(status: str) -> dict[str, str]:
    """medkit's ``build_status_object``: the DTC status bits of a fault's status."""
    aggregated, failed, confirmed, pending = "cleared", False, False, False
    if status == "CONFIRMED":
        aggregated, failed, confirmed = "active", True, True
    elif status == "PREFAILED":
        aggregated, failed, pending = "passive", True, True
    elif status == "PREPASSED":
        aggregated, pending = "passive", True
    return {"aggregatedStatus": aggregated, "testFailed": "1" if failed else "0",
            "confirmedDTC": "1" if confirmed else "0", "pendingDTC": "1" if pending else "0"}


def _recording(frame: dict[str, Any], entity_path: str) -> dict[str, Any]:
    """A fault recording (rosworker/bulk_data/) as medkit's rosbag snapshot, its URI under the entity asked."""
    out: dict[str, Any] = {"type": "rosbag", "name": frame.get("name", ""),
                           "bulk_data_uri": f"{entity_path}/bulk-data/rosbags/{frame.get('bulk_data_id', '')}",
                           "size_bytes": frame.get("size_bytes", 0), "duration_sec": frame.get("duration_sec", 0.0),
                           "format": frame.get("format", "mcap")}
    ext: dict[str, Any] = {"topics": frame.get("topics") or [], "messages": frame.get("messages", 0)}
    if frame.get("captured_at_ns"):
        ext["captured_at"] = rfc3339(int(frame["captured_at_ns"])).decode()
    out["x-medkit"] = ext
    return out


def _snapshot(frame: dict[str, Any]) -> dict[str, Any]:
    topic, message_type = frame.get("topic", ""), frame.get("message_type", "")
    out: dict[str, Any] = {"type": frame.get("type", "freeze_frame"), "name": frame.get("name", "")}
    ext: dict[str, Any] = {"topic": topic, "message_type": message_type}
    try:
        full = json.loads(frame.get("data", ""))
        field = PRIMARY_FIELDS.get(message_type)
        out["data"] = full[field] if field and isinstance(full, dict) and field in full else full
        ext.update(full_data=full, captured_at=rfc3339(int(frame.get("captured_at_ns", 0))).decode())
    except (ValueError, TypeError) as exc:
        out["data"] = frame.get("data", "")
        ext["parse_error"] = str(exc)[:200]
    if frame.get("truncated"):
        ext["truncated_bytes"] = frame["truncated"]
    if frame.get("error"):
        ext["error"] = frame["error"]
    out["x-medkit"] = ext
    return out


def detail(answer: dict[str, Any], entity_path: str = "") -> dict[str, Any]:
    """medkit's ``build_sovd_fault_response``; ``entity_path`` (``/apps/x``) leads its recordings' URIs."""
    fault = answer["fault"]
    item: dict[str, Any] = {"code": fault["fault_code"]}
    if fault.get("description"):
        item["fault_name"] = fault["description"]
    item["severity"] = fault["severity"]
    item["status"] = _status_object(fault["status"])
    ext: dict[str, Any] = {"occurrence_count": fault["occurrence_count"]}
    if fault.get("reporting_sources"):
        ext["reporting_sources"] = fault["reporting_sources"]
    ext.update(severity_label=fault["severity_label"], status_raw=fault["status"])
    return {"item": item,
            "environment_data": {
                "extended_data_records": {"first_occurrence": rfc3339(answer["first_ns"]).decode(),
                                          "last_occurrence": rfc3339(answer["last_ns"]).decode()},
                "snapshots": [_recording(s, entity_path) if s.get("type") == "rosbag" else _snapshot(s)
                              for s in answer.get("snapshots") or [] if isinstance(s, dict)]},
            "x-medkit": ext}


def _no_content():
    return current_app.response_class(status=204)


# ---- the gateway's faults -------------------------------------------------------------------------------
@bp.get("/faults")
def list_all():
    items = _list(status_filter())
    return json_response({"items": items, "x-medkit": {"count": len(items), "muted_count": 0,
                                                         "cluster_count": 0}})


@bp.delete("/faults")
def clear_all_global():
    _authorize_clear()
    statuses = status_filter()
    codes = [f["fault_code"] for f in _list(statuses)]
    if codes:
        _call("fault_clear", {"codes": codes})
    return _no_content()


@bp.get("/faults/stream")
def stream():
    cfg = config()
    return hub.response(hub.NAME, cfg.max_fault_streams)


# ---- an entity's faults ---------------------------------------------------------------------------------
@bp.get(ENTITY + "/faults")
def list_entity(collection: str, entity_id: str):
    entity = lookup(collection, entity_id)
    statuses = status_filter({PARAM_NAMES[collection]: entity.id})
    fqns = node_names(entity)
    items = [f for f in _list(statuses) if in_scope(f, fqns)]
    if collection == "apps":
        ext: dict[str, Any] = {"entity_id": entity.id, "source_id": fqns[0] if fqns else "",
                               "count": len(items), "muted_count": 0, "cluster_count": 0}
    else:
        is_function = collection == "functions"
        ext = {"entity_id": entity.id, "aggregation_level": "function" if is_function else "component",
               "aggregated": True, ("host_count" if is_function else "app_count"): len(fqns)}
        if fqns:
            ext["aggregation_sources"] = fqns
        ext["count"] = len(items)
    return json_response({"items": items, "x-medkit": ext})


@bp.delete(ENTITY + "/faults")
def clear_entity(collection: str, entity_id: str):
    _authorize_clear()
    entity = lookup(collection, entity_id)
    statuses = status_filter({PARAM_NAMES[collection]: entity.id})
    fqns = node_names(entity)
    codes = [f["fault_code"] for f in _list(statuses) if in_scope(f, fqns)]
    if codes:
        _call("fault_clear", {"codes": codes}, {PARAM_NAMES[collection]: entity.id})
    return _no_content()


@bp.get(ENTITY + "/faults/<fault_code>")
def get_one(collection: str, entity_id: str, fault_code: str):
    entity = lookup(collection, entity_id)
    _check_code(fault_code)
    return json_response(detail(_scoped_fault(collection, entity, fault_code), f"/{collection}/{entity.id}"))


@bp.delete(ENTITY + "/faults/<fault_code>")
def clear_one(collection: str, entity_id: str, fault_code: str):
    _authorize_clear()
    entity = lookup(collection, entity_id)
    _check_code(fault_code)
    _scoped_fault(collection, entity, fault_code)
    _call("fault_clear", {"codes": [fault_code]}, {PARAM_NAMES[collection]: entity.id, "fault_code": fault_code})
    return _no_content()
