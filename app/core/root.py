"""``GET /api/v1/``, ``/version-info``, ``/health`` and ``/docs`` (whole, or scoped to a part of the tree)."""

from __future__ import annotations

import time

from flask import Blueprint, current_app

from common.process import DISTRIBUTION, package_version

from .. import openapi
from . import metrics, rosclient, unimplemented
from .common import config, entity_id_problem, json_response
from .entities import API_BASE
from .errors import ApiError
from .family import counters_section, plugged

bp = Blueprint("root", __name__, url_prefix=API_BASE)

NAME = DISTRIBUTION
SOVD_VERSION = openapi.SOVD_VERSION


@bp.get("/")
def root():
    cfg = config()
    capabilities = {"discovery": True,
                    "authentication": bool(cfg.auth_enabled or cfg.api_token),  # app/auth/ (the legacy api_token too)
                    "tls": bool(cfg.tls_cert),  # app/gunicorn_conf.py
                    "docs": True}
    for family in plugged(current_app):   # what each family serves (app/<family>/__init__.py)
        capabilities.update(family.capabilities(cfg))
    # medkit's features not served here: their routes answer 501 (core/unimplemented.py)
    capabilities.update(unimplemented.capabilities())
    capabilities["aggregation"] = False  # the fleet gateway's is true (app/fleet/routes.py)
    overview = {
        "name": NAME,
        "version": package_version(),
        "api_base": API_BASE,
        "endpoints": openapi.endpoint_list(),
        "capabilities": capabilities,
    }
    if cfg.auth_enabled:  # medkit's: only when authentication is on
        overview["auth"] = {"enabled": True, "algorithm": cfg.jwt_algorithm, "require_auth_for": cfg.require_auth_for}
    if cfg.tls_cert:
        overview["tls"] = {"enabled": True, "min_version": cfg.tls_min_version}
    return json_response(overview)


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
    answer (then the counters are the last ones received, or zeros).  Each family
    adds its section (its ``Health``: ``app/<family>/__init__.py``).
    """
    cfg = config()
    alive, stats = rosclient.get().stats()
    executor = counters_section("executor")(stats, cfg)
    executor["worker_alive"] = alive
    # the cyclic subscriptions and triggers held (the ROS worker's), and the streams of every HTTP
    # worker, summed from their metrics (core/metrics.py), whatever the ROS worker does
    streams = counters_section("streams")(stats, cfg)
    streams.update({key: value for key, value in metrics.stream_totals().items() if key in streams})
    if not alive:
        status = "unhealthy"
    elif executor.get("degraded"):
        status = "degraded"
    else:
        status = "healthy"
    body = {"status": status, "timestamp": time.time_ns(), "discovery": {"mode": "runtime_only", "strategy": "runtime"},
            "x-medkit-subscription-executor": executor, "x-medkit-streams": streams}
    for family in plugged(current_app):
        for section in family.health:
            body[section.key] = section.build(stats, cfg)
    for name, section in current_app.extensions.get(HEALTH_SECTIONS, {}).items():
        body[name] = section()   # a section added outside the families (the fleet link's: app/fleet/)
    return json_response(body)


# app.extensions[HEALTH_SECTIONS]: name -> callable, /health sections added outside the families (app/fleet/)
HEALTH_SECTIONS = "sovd_health_sections"
