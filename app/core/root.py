"""``GET /api/v1/``, ``/version-info``, ``/health`` and ``/docs`` (whole, or scoped to a part of the tree)."""

from __future__ import annotations

import time
from typing import Any

from flask import Blueprint

from common.process import DISTRIBUTION, package_version
from ipc import counters

from .. import openapi
from . import metrics, rosclient, unimplemented
from .common import config, entity_id_problem, json_response
from .entities import API_BASE
from .errors import ApiError

bp = Blueprint("root", __name__, url_prefix=API_BASE)

NAME = DISTRIBUTION
SOVD_VERSION = openapi.SOVD_VERSION


@bp.get("/")
def root():
    cfg = config()
    return json_response({
        "name": NAME,
        "version": package_version(),
        "api_base": API_BASE,
        "endpoints": openapi.endpoint_list(),
        "capabilities": {
            "discovery": True,
            "data_access": True,
            "publishing": bool(cfg.allow_publish),
            "authentication": bool(cfg.api_token),
            "docs": True,
            "cyclic_subscriptions": True,
            # services and actions (app/operations/routes.py); executing them needs allow_operations
            "operations": True, "async_actions": True, "operation_execution": bool(cfg.allow_operations),
            "configurations": True,  # ROS 2 parameters (app/configurations/routes.py)
            "faults": True,  # /diagnostics (app/faults/routes.py)
            "fault_clear": bool(cfg.allow_fault_clear),  # DELETE …/faults (the dashboard's Clear)
            "logs": True,  # /rosout (app/logs/routes.py)
            "triggers": True,  # condition triggers (app/triggers/routes.py)
            # ui (issue 21): the dashboard's Parameters panel shows its editor when configurations may be changed
            "configuration_writes": bool(cfg.allow_configurations),
            # medkit's features not served here: their routes answer 501 (app/core/unimplemented.py)
            **unimplemented.capabilities(),
        },
    })


@bp.get("/version-info")
def version_info():
    return json_response({"items": [{
        "version": SOVD_VERSION,
        "base_uri": API_BASE,
        "vendor_info": {"name": NAME, "version": package_version()},
    }]})


@bp.get("/docs")
def docs():
    return json_response(openapi.document())


@bp.get("/<collection:collection>/docs")
def collection_docs(collection: str):
    return json_response(openapi.scoped_document(collection))


@bp.get("/<collection:collection>/<entity_id>/docs")
def entity_docs(collection: str, entity_id: str):
    _documented_entity(collection, entity_id)
    return json_response(openapi.scoped_document(collection, entity_id))


@bp.get("/<collection:collection>/<entity_id>/data/docs")
def entity_data_docs(collection: str, entity_id: str):
    entity = _documented_entity(collection, entity_id)
    return json_response(openapi.scoped_document(collection, entity_id, data=True,
                                                 data_ids=sorted(entity.topics)))


def _documented_entity(collection: str, entity_id: str):
    """The entity, or medkit's 404 for a docs path that names none (any bad id included)."""
    if entity_id_problem(entity_id):
        entity = None
    else:
        asked = time.monotonic()
        entity = rosclient.get().entities().get(collection, entity_id) \
            or rosclient.get().entities(checked_since=asked).get(collection, entity_id)
    if entity is None:
        raise ApiError(404, "resource-not-found",
                       "No capability description available for the requested path")
    return entity


@bp.get("/health")
def health():
    """Liveness and the ROS worker's counters; always 200, never waits on ROS work.

    ``status``: ``healthy``; ``degraded`` while a ROS task has run past the
    watchdog threshold; ``unhealthy`` while the ROS worker is down or does not
    answer (then the counters are the last ones received, or zeros).
    """
    alive, stats = rosclient.get().stats()
    provider, executor, streams = _sections(stats)
    executor["worker_alive"] = alive
    if not alive:
        status = "unhealthy"
    elif executor.get("degraded"):
        status = "degraded"
    else:
        status = "healthy"
    return json_response({
        "status": status,
        "timestamp": time.time_ns(),
        "discovery": {"mode": "runtime_only", "strategy": "runtime"},
        "x-medkit-data-provider": provider,
        "x-medkit-subscription-executor": executor,
        "x-medkit-streams": streams,
        # operations: service and action clients, calls in flight, goals, timeouts (ipc/counters.py)
        "x-medkit-operations": {**counters.health_defaults("operations", config()),
                                **((stats or {}).get("operations") or {})},
        # configurations: the parameter clients of the ROS worker (rosworker/configurations/clients.py)
        "x-medkit-configurations": _configurations(stats),
        "x-medkit-faults": faults_health(stats),  # faults (rosworker/faults/manager.py)
        "x-medkit-logs": _logs_section(stats),  # logs (issue 22)
    })


CONFIGURATION_KEYS = ("parameter_clients", "parameter_client_cap", "parameter_calls_in_flight",
                      "parameter_waiting", "parameter_waits", "parameter_calls", "parameter_resends",
                      "parameter_timeouts", "parameter_events")


def _configurations(stats: dict[str, Any] | None) -> dict[str, Any]:
    """/health's x-medkit-configurations: the ROS worker's parameter counters (its ``details``)."""
    details = (stats or {}).get("details")
    details = details if isinstance(details, dict) else {}
    section = {key: details.get(key, 0) for key in CONFIGURATION_KEYS}
    if not details:
        section["parameter_client_cap"] = config().max_parameter_clients
    return section


def _sections(stats: dict[str, Any] | None) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """/health's three sections: the declared counters (ipc/counters.py), zero or the settings they
    show until the ROS worker first answers, then its last answer; the HTTP workers' stream
    counters are summed from their metrics (app/core/metrics.py), whatever the ROS worker does."""
    cfg = config()
    provider, executor, streams = (counters.health_defaults(name, cfg)
                                   for name in ("data_provider", "executor", "streams"))
    provider["evictions"] = {}  # evictions_total by cause, as the ROS worker counts them
    if stats:
        for section, name in ((provider, "data_provider"), (executor, "executor"), (streams, "streams")):
            if isinstance(stats.get(name), dict):
                section.update(stats[name])
        details = stats.get("details")
        if isinstance(details, dict) and isinstance(details.get("evictions"), dict):
            provider["evictions"] = dict(details["evictions"])
    streams.update(metrics.stream_totals())
    return provider, executor, streams


# ---- faults (rosworker/faults/manager.py): /health's x-medkit-faults ------------------------------------------
FAULT_HEALTH_KEYS = ("active", "confirmed", "store_size", "max_faults", "refused", "active_by_severity",
                     "store_enabled", "store_writes", "store_write_errors", "store_pending", "last_write_error",
                     "moved_aside", "diagnostics_arrays", "left_by_absent_nodes", "absent_nodes")


def faults_health(stats: dict[str, Any] | None) -> dict[str, Any]:
    """The fault manager's counters as the ROS worker last sent them (zeros before its first answer)."""
    part = stats.get("faults") if isinstance(stats, dict) else None
    section: dict[str, Any] = {"active": 0, "confirmed": 0, "store_size": 0, "max_faults": config().max_faults,
                               "last_write_error": "", "left_by_absent_nodes": 0, "absent_nodes": []}
    if isinstance(part, dict):
        section.update({k: part[k] for k in FAULT_HEALTH_KEYS if k in part})
    return section


# logs (issue 22): /health's x-medkit-logs, the declared counters as _sections shows the others.
def _logs_section(stats: dict[str, Any] | None) -> dict[str, Any]:
    section = counters.health_defaults("logs", config())
    if stats and isinstance(stats.get("logs"), dict):
        section.update(stats["logs"])
    return section
