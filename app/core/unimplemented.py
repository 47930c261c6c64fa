"""Routes of medkit's contract that this gateway does not serve: 501 ``not-implemented``.

medkit answers some of these with 501 when the provider behind them is not
there (no update plugin, no scripts backend, no lifecycle provider for the
transitions), and its handlers say so before they look at the entity.  It answers the same way
whatever the entity id: a client tells "not served here" (501) from "no such entity or route"
(404).  Locks (``app/locks/``, issue 31) and bulk data (``app/bulk_data/``, issue 32) are served.

:data:`ROUTES` is the one table: the blueprint, the OpenAPI document
(``app/openapi/__init__.py``) and the capabilities of ``GET /api/v1/``
(``app/core/root.py``) are all made from it.  Nothing here talks to the ROS
worker.  Operations, configurations, faults, logs, triggers, locks (``app/locks/``) and the
lifecycle status (``GET .../status``, ``app/operations/status.py``) have routes of their own;
medkit has no ``modes`` routes, so neither has this table.
"""

from __future__ import annotations

from typing import NamedTuple

from flask import Blueprint

from .entities import API_BASE, PARAM_NAMES
from .errors import ApiError


class Feature(NamedTuple):
    capability: str     # its flag in the capabilities of GET /api/v1/ (medkit's name where it has one)
    tag: str            # medkit's OpenAPI tag
    message: str        # medkit's 501 message where it has one


FEATURES = {
    "scripts": Feature("scripts", "Scripts", "Scripts backend not configured"),
    "lifecycle": Feature("lifecycle", "Lifecycle", "Lifecycle control not available for this entity"),
    "updates": Feature("updates", "Updates", "Software updates not available"),
}


class Route(NamedTuple):
    feature: str
    method: str
    path: str               # under the entity (``/locks/{lock_id}``), or under the API base
    collections: tuple[str, ...]  # the entity collections it exists on; () for a server-level route
    op: str                 # medkit's operationId; ``{Kind}`` is the entity kind (``App``)
    summary: str


_APPS_COMPONENTS = ("apps", "components")
_TRANSITIONS = ("start", "restart", "force-restart", "shutdown", "force-shutdown")

ROUTES: tuple[Route, ...] = (
    Route("scripts", "POST", "/scripts", _APPS_COMPONENTS, "upload{Kind}Script", "Upload a diagnostic script"),
    Route("scripts", "GET", "/scripts", _APPS_COMPONENTS, "list{Kind}Scripts", "List diagnostic scripts"),
    Route("scripts", "GET", "/scripts/{script_id}", _APPS_COMPONENTS, "get{Kind}Script", "One script"),
    Route("scripts", "DELETE", "/scripts/{script_id}", _APPS_COMPONENTS, "delete{Kind}Script", "Delete a script"),
    Route("scripts", "POST", "/scripts/{script_id}/executions", _APPS_COMPONENTS, "start{Kind}ScriptExecution",
          "Run a script"),
    Route("scripts", "GET", "/scripts/{script_id}/executions/{execution_id}", _APPS_COMPONENTS,
          "get{Kind}ScriptExecution", "A script execution's status"),
    Route("scripts", "PUT", "/scripts/{script_id}/executions/{execution_id}", _APPS_COMPONENTS,
          "control{Kind}ScriptExecution", "Terminate a script execution"),
    Route("scripts", "DELETE", "/scripts/{script_id}/executions/{execution_id}", _APPS_COMPONENTS,
          "remove{Kind}ScriptExecution", "Remove a finished script execution"),
    *(Route("lifecycle", "PUT", f"/status/{t}", _APPS_COMPONENTS,
            "put{Kind}Status" + t.title().replace("-", ""), f"Request the lifecycle transition '{t}'")
      for t in _TRANSITIONS),
    Route("updates", "GET", "/updates", (), "listUpdates", "List software updates"),
    Route("updates", "POST", "/updates", (), "registerUpdate", "Register a software update"),
    Route("updates", "GET", "/updates/{update_id}", (), "getUpdate", "One software update"),
    Route("updates", "DELETE", "/updates/{update_id}", (), "deleteUpdate", "Delete a software update"),
    Route("updates", "GET", "/updates/{update_id}/status", (), "getUpdateStatus", "A software update's status"),
    Route("updates", "PUT", "/updates/{update_id}/prepare", (), "prepareUpdate", "Prepare a software update"),
    Route("updates", "PUT", "/updates/{update_id}/execute", (), "executeUpdate", "Execute a software update"),
    Route("updates", "PUT", "/updates/{update_id}/automated", (), "automateUpdate",
          "Prepare and execute a software update"),
)

KINDS = {"areas": "Area", "components": "Component", "apps": "App", "functions": "Function"}


def paths() -> list[tuple[Route, str, str | None]]:
    """``(route, OpenAPI path under the API base, collection or None)`` for every route of the table."""
    out = []
    for route in ROUTES:
        if not route.collections:
            out.append((route, route.path, None))
        for collection in route.collections:
            out.append((route, f"/{collection}/{{{PARAM_NAMES[collection]}}}" + route.path, collection))
    return out


def capabilities() -> dict[str, bool]:
    """Each feature of the table: not served (``False``), for the capabilities of ``GET /api/v1/``."""
    return {feature.capability: False for feature in FEATURES.values()}


bp = Blueprint("unimplemented", __name__, url_prefix=API_BASE)


def _view(feature: str):
    def view(**_ids: str):
        raise ApiError(501, "not-implemented", FEATURES[feature].message, {"feature": feature})

    return view


def _rule(path: str) -> str:
    """``/apps/{app_id}/locks/{lock_id}`` -> ``/apps/<app_id>/locks/<lock_id>`` (any id, checked by nobody)."""
    return path.replace("{", "<").replace("}", ">")


for _i, (_route, _path, _collection) in enumerate(paths()):
    bp.add_url_rule(_rule(_path), endpoint=f"not_implemented_{_i}", view_func=_view(_route.feature),
                    methods=[_route.method])
