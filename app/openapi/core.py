"""The core's part of the OpenAPI document: the server's routes, discovery, the scoped documents, the routes
medkit serves and this gateway does not (501), ``/metrics``; and the schemas they name."""

from __future__ import annotations

import re
from typing import Any

from ..core import unimplemented
from ..core.entities import API_BASE, COLLECTIONS, KINDS, PARAM_NAMES, RELATIONS
from . import build as oa

LINKS = {"type": "object", "required": ["self"], "properties": {"self": oa.STR},
         "additionalProperties": oa.STR, "description": "HATEOAS links: `self` and the owning entity"}
CAPABILITIES = {"type": "array", "items": oa.obj(["name", "href"], name=oa.STR, href=oa.STR)}
X_MEDKIT_ENTITY = {
    "areas": oa.obj([], source=oa.STR),
    "components": oa.obj(["source"], source={"enum": ["runtime"]},
                       capabilities={**CAPABILITIES, "description": "detail only: the capabilities again"}),
    "apps": oa.obj(["source", "is_online", "component_id", "ros2"], source={"enum": ["heuristic"]},
                 is_online={"type": "boolean"}, component_id=oa.ENTITY_ID, ros2=oa.ref("XMedkitRos2")),
    "functions": oa.obj(["source"], source={"enum": ["runtime"]},
                      hosts={**oa.STR_LIST, "description": "detail only: the ids of the apps it hosts"}),
}
# Detail URIs of what the gateway serves, per collection: (required, optional).
DETAIL_URIS = {
    "areas": (["subareas", "components", "contains", "data"], []),
    "components": (["status", "data", "subcomponents", "hosts"], []),
    "apps": (["status", "data"], ["is-located-on", "belongs-to"]),
    "functions": (["hosts", "data"], []),
}
# Entity details link the resources (medkit's detail URIs): operations, configurations, faults, logs, triggers.
for _collection in ("components", "apps", "functions"):
    DETAIL_URIS[_collection][0].extend(("operations", "configurations", "faults", "logs", "triggers"))


def _entity_schemas() -> dict[str, Any]:
    """``XMedkit<Kind>``, ``<Kind>ListItem``, ``<Kind>List`` and ``<Kind>Detail`` per collection."""
    out: dict[str, Any] = {
        "XMedkitRos2": oa.obj(["node"], node={**oa.STR, "description": "fully qualified ROS node name"}),
        "XMedkitCollection": oa.obj(["total_count"], total_count=oa.INT),
    }
    for collection in COLLECTIONS:
        kind, name = KINDS[collection][0], oa.schema_name(collection)
        out[f"XMedkit{name}"] = X_MEDKIT_ENTITY[collection]
        item = oa.obj(["id", "name", "href", "type", "x-medkit"], id=oa.ENTITY_ID, name=oa.STR,
                    href={"type": "string", "pattern": f"^{API_BASE}/{collection}/"},
                    type={"const": kind}, description=oa.STR, X_medkit=oa.ref(f"XMedkit{name}"))
        if collection == "functions":
            item["properties"]["hosts"] = {**oa.STR_LIST, "description": "the ids of the apps it hosts"}
        out[f"{name}ListItem"] = item
        out[f"{name}List"] = oa.obj(["items", "x-medkit"], items={"type": "array", "items": oa.ref(f"{name}ListItem")},
                                  X_medkit=oa.ref("XMedkitCollection"), _links=LINKS)
        required, optional = DETAIL_URIS[collection]
        uris = {key: {"type": "string", "pattern": f"^{API_BASE}/"} for key in required + optional}
        detail = oa.obj(["id", "name", "type", *required, "capabilities", "_links", "x-medkit"],
                      id=oa.ENTITY_ID, name=oa.STR, type={"const": kind}, description=oa.STR,
                      capabilities=CAPABILITIES,
                      _links={**LINKS, "required": ["self", "collection"]},
                      X_medkit=oa.ref(f"XMedkit{name}"))
        detail["properties"].update(uris)
        out[f"{name}Detail"] = detail
    return out



HEALTH_STATUS = oa.obj(
    ["status", "timestamp", "discovery", "x-medkit-subscription-executor", "x-medkit-streams"],
    status={"enum": ["healthy", "degraded", "unhealthy"],
            "description": "unhealthy: the ROS worker is down or not answering; degraded: one of "
                           "its tasks ran past the watchdog threshold"},
    timestamp=oa.INT, discovery=oa.obj(["mode", "strategy"], mode=oa.STR, strategy=oa.STR),
    X_medkit__subscription__executor=oa.counters_schema(
        "executor", "While the ROS worker is down: worker_alive false, the last counters received (or zeros)"),
    X_medkit__streams=oa.counters_schema(
        "streams", "cyclic subscriptions and triggers held, and the SSE streams of every HTTP worker, faults' "
                   "too (summed at each request)"))
SCHEMAS: dict[str, Any] = {
    "GenericError": {
        **oa.obj(["error_code", "message"], error_code=oa.STR,
               vendor_code={"type": "string", "pattern": "^x-medkit-"}, message=oa.STR,
               parameters={"type": "object", "minProperties": 1}),
        "additionalProperties": False,
        "description": "SOVD GenericError. `vendor_code` is present when `error_code` is `vendor-error`.",
    },
    **_entity_schemas(),
    "HealthStatus": HEALTH_STATUS,
    "RootOverview": oa.obj(
        ["name", "version", "api_base", "endpoints", "capabilities"], name=oa.STR,
        version={"type": "string", "pattern": r"^\d+\.\d+\.\d+"}, api_base={"const": API_BASE},
        endpoints={"type": "array", "items": {"type": "string",
                                              "pattern": f"^(GET|PUT|POST|DELETE) ({API_BASE}/|/metrics$)"}},
        capabilities={**oa.obj(["discovery", "data_access", "publishing"]),
                      "additionalProperties": {"type": "boolean"}},
    ),
    "VersionInfo": oa.obj(["items"], items={"type": "array", "minItems": 1, "items": oa.obj(
        ["version", "base_uri", "vendor_info"], version=oa.STR, base_uri={"const": API_BASE},
        vendor_info=oa.obj(["name", "version"], name=oa.STR, version=oa.STR))}),
}

LIFECYCLE_TAG = ("GET .../status: ready or notReady; the transitions (PUT .../status/{transition}) are not "
                 "implemented: 501 (Lifecycle control not available for this entity)")


# medkit's operationIds of the relation collections.
RELATION_OPS = {
    ("areas", "components"): ("listAreaComponents", "Components in an area"),
    ("areas", "contains"): ("listAreaContains", "Components contained in an area and its subareas"),
    ("areas", "subareas"): ("listSubareas", "Subareas of an area"),
    ("components", "subcomponents"): ("listSubcomponents", "Subcomponents of a component"),
    ("components", "hosts"): ("listComponentHosts", "Apps hosted on a component"),
    ("components", "depends-on"): ("listComponentDependencies", "Components a component depends on"),
    ("apps", "is-located-on"): ("getAppHost", "The component an app runs on"),
    ("apps", "belongs-to"): ("getAppArea", "The area of the app's host component"),
    ("apps", "depends-on"): ("listAppDependencies", "Apps an app depends on"),
    ("functions", "hosts"): ("listFunctionHosts", "Apps that host a function"),
}


def _relation_paths() -> dict[str, Any]:
    paths: dict[str, Any] = {}
    for (collection, relation), (target, _) in RELATIONS.items():
        op_id, summary = RELATION_OPS[(collection, relation)]
        title, param = oa.schema_name(collection), PARAM_NAMES[collection]
        if collection == "apps":  # medkit checks these like an entity detail
            errors: tuple = ("400", "404")
        else:
            errors = (("400", f"Invalid {title.lower()} ID (`invalid-parameter`, parameters `details`, "
                              f"`{param}`)"),
                      ("404", f"{title} not found (`entity-not-found`, parameters `{param}`); an id of "
                              f"another entity type is not found here either"))
        paths[f"/{collection}/{{{param}}}/{relation}"] = {"get": oa.op(
            op_id, "Discovery", summary, oa.ok(f"{oa.schema_name(target)}List"), *errors, "503", "504",
            parameters=[oa.id_param(collection)])}
    return paths


def _docs_paths() -> dict[str, Any]:
    """The scoped documents (``/docs`` itself is with the server routes)."""
    doc = oa.DOC
    no_doc = ("404", "No such entity (`resource-not-found`, `No capability description available for "
                     "the requested path`)")
    paths: dict[str, Any] = {}
    for collection in COLLECTIONS:
        title, param = oa.schema_name(collection), PARAM_NAMES[collection]
        paths[f"/{collection}/docs"] = {"get": oa.op(
            f"get{title}sDocs", "Server", f"This document narrowed to /{collection}", doc)}
        paths[f"/{collection}/{{{param}}}/docs"] = {"get": oa.op(
            f"get{title}Docs", "Server", f"This document narrowed to one {collection[:-1]}", doc, no_doc,
            "503", "504", parameters=[oa.id_param(collection)])}
        paths[f"/{collection}/{{{param}}}/data/docs"] = {"get": oa.op(
            f"get{title}DataDocs", "Server", f"This document narrowed to the data of one {collection[:-1]}",
            doc, no_doc, "503", "504", parameters=[oa.id_param(collection)])}
    return paths


METRICS_OP = oa.op(
    "getMetrics", "Server", "Prometheus metrics (text exposition format); beside the API, at /metrics",
    {"description": "The gateway's metrics in Prometheus' text format: HTTP requests by route template, "
                    "latency, streams, rate limiting (sovd_http_*); the ROS worker's counters "
                    "(sovd_ros_*; sovd_ros_worker_up 0 while it does not answer); ROS-worker restarts "
                    "(sovd_supervisor_*). Never rate-limited.",
     "content": {"text/plain": {"schema": oa.STR}}},
    limited=False, servers=[{"url": "/", "description": "outside the API base: GET /metrics"}])


def _not_implemented_paths() -> dict[str, Any]:
    """medkit's routes this gateway does not serve (``app/core/unimplemented.py``): each answers 501."""
    out: dict[str, Any] = {}
    for route, path, collection in unimplemented.paths():
        params = [{"name": name, "in": "path", "required": True,
                   "schema": oa.ENTITY_ID if collection and name == PARAM_NAMES[collection] else oa.STR}
                  for name in re.findall(r"\{([^}]+)\}", path)]
        feature = unimplemented.FEATURES[route.feature]
        op_id = route.op.replace("{Kind}", unimplemented.KINDS[collection] if collection else "")
        out.setdefault(path, {})[route.method.lower()] = oa.op(
            op_id, feature.tag, route.summary + " (not implemented)",
            {"description": "medkit's answer; never sent by this gateway, which answers 501",
             "content": {"application/json": {"schema": oa.OBJ}}},
            ("501", f"Not implemented on this gateway (`not-implemented`, \"{feature.message}\", parameters "
                    f"`feature`: `{route.feature}`), whatever the ids"),
            parameters=params)
    return out


def paths() -> dict[str, Any]:
    """The core's first paths: the server's, the entities', their relations' (the families' come next)."""
    out: dict[str, Any] = {
        "/": {"get": oa.op("getRoot", "Server", "Gateway overview", oa.ok("RootOverview"))},
        "/version-info": {"get": oa.op("getVersionInfo", "Server", "SOVD version information", oa.ok("VersionInfo"))},
        "/health": {"get": oa.op("getHealth", "Server", "Liveness and ROS worker counters; always 200, "
                                                     "never waits on ROS work; never rate-limited",
                              oa.ok("HealthStatus"), limited=False)},
        "/docs": {"get": oa.op("getDocs", "Server", "This OpenAPI document", oa.DOC)},
    }
    for collection in COLLECTIONS:
        name, kind, param = oa.schema_name(collection), collection[:-1], oa.id_param(collection)
        out[f"/{collection}"] = {"get": oa.op(f"list{name}s", "Discovery", f"List {collection}", oa.ok(f"{name}List"),
                                           "503", "504")}
        out[f"/{collection}/{{{PARAM_NAMES[collection]}}}"] = {"get": oa.op(
            f"get{name}", "Discovery", f"Get one {kind}", oa.ok(f"{name}Detail"), "400", "404", "503", "504",
            parameters=[param])}
    out.update(_relation_paths())
    return out


def last_paths() -> dict[str, Any]:
    """The core's last paths, after the families': the scoped documents', the 501s', ``/metrics``."""
    out = _docs_paths()
    out.update(_not_implemented_paths())
    out["/metrics"] = {"get": METRICS_OP}
    return out


TAGS = ({"name": "Server", "description": "Gateway health, metadata, version info and docs"},
        {"name": "Discovery", "description": "Entity discovery and hierarchy navigation"})
UNIMPLEMENTED_TAGS = tuple({"name": f.tag, "description": LIFECYCLE_TAG if f.tag == "Lifecycle"
                            else f"Not implemented: 501 ({f.message})"} for f in unimplemented.FEATURES.values())
