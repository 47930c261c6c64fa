"""The OpenAPI 3.1 document of every implemented route (``GET /api/v1/docs``).

It is also the single list the root overview (``GET /api/v1/``) takes its
``endpoints`` from, so the two cannot disagree.  Schemas are JSON Schema
2020-12 (OpenAPI 3.1), and the test suite validates real responses against them.

The document is put together from parts: the core's (``core.py``: the server,
discovery, the scoped documents, the 501s, ``/metrics``) and each family's
(``app/<family>/spec.py``, its ``FAMILY.spec``: paths, schemas, tags; its
``/health`` section's schema is its ``FAMILY.health``).  This module knows no
family by name.  :func:`scoped_document` narrows the document to one part of the
tree (``GET /{collection}/docs`` and below, medkit's ``docs`` capability).
"""

from __future__ import annotations

from copy import deepcopy
from functools import lru_cache
from typing import Any

from ..audit import doc as audit_doc
from ..auth import doc as auth_doc
from ..core.entities import API_BASE, PARAM_NAMES
from ..core.family import discover
from ..core.target import LOCK_SCOPES
from . import core
from .build import GENERIC_ERROR

SOVD_VERSION = "1.0.0"


@lru_cache(maxsize=1)
def _document() -> dict[str, Any]:
    paths = core.paths()
    schemas = dict(core.SCHEMAS)
    health = {**core.HEALTH_STATUS, "required": list(core.HEALTH_STATUS["required"]),
              "properties": dict(core.HEALTH_STATUS["properties"])}
    schemas["HealthStatus"] = health
    tags = list(core.TAGS)
    for family in discover():
        if family.spec is not None:
            paths.update(family.spec.paths())
            schemas.update(family.spec.schemas)
            tags.extend(family.spec.tags)
        for section in family.health:
            if section.schema is not None:
                health["properties"][section.key] = section.schema
                if section.required:
                    health["required"].append(section.key)
    paths.update(core.last_paths())
    # who is acting (issue 31, app/auth/ and app/audit/, on every request): their own parts, then what the
    # token, role and lock checks add to every operation
    schemas["RootOverview"] = deepcopy(schemas["RootOverview"])
    for part in (auth_doc, audit_doc):
        paths.update(part.paths())
        schemas.update(part.SCHEMAS)
    auth_doc.amend(schemas)
    auth_doc.secure(paths, LOCK_SCOPES)
    return {
        "openapi": "3.1.0",
        "info": {"title": "sovd-gateway", "version": "1.0.0", "x-sovd-version": SOVD_VERSION,
                 "description": "SOVD REST gateway for ROS 2: discovery and live topic data."},
        "jsonSchemaDialect": "https://json-schema.org/draft/2020-12/schema",
        "servers": [{"url": API_BASE}],
        "tags": [*tags, *core.UNIMPLEMENTED_TAGS, auth_doc.TAG, audit_doc.TAG],
        "paths": paths,
        "components": {
            "schemas": schemas, "responses": {"GenericError": GENERIC_ERROR},
            "securitySchemes": {"bearerAuth": {"type": "http", "scheme": "bearer", "bearerFormat": "JWT",
                                               "description": "an access token of POST /auth/authorize (or the "
                                                              "legacy api_token): for writes under "
                                                              "require_auth_for=write, for every request under all"}},
        },
    }


def document() -> dict[str, Any]:
    return _document()


def scoped_document(collection: str, entity_id: str | None = None, *, data: bool = False,
                    data_ids: list[str] | tuple[str, ...] = ()) -> dict[str, Any]:
    """The document narrowed to one part of the tree, as medkit's ``docs`` capability serves it.

    ``/{collection}/docs``: the paths under ``/{collection}`` as templates.
    ``/{collection}/{id}/docs``: the paths under that entity, with its id filled
    in (and its path parameter gone).  ``/{collection}/{id}/data/docs``: only
    its data paths; ``data_ids`` (the entity's topics) become examples of
    ``{data_id}``.  The caller checks that the entity exists.
    """
    full = _document()
    root = f"/{collection}"
    template = f"{root}/{{{PARAM_NAMES[collection]}}}"
    prefix = template + "/data" if data else (template if entity_id is not None else root)
    paths: dict[str, Any] = {}
    for path, ops in full["paths"].items():
        if path != prefix and not path.startswith(prefix + "/"):
            continue
        if entity_id is None:
            paths[path] = ops
            continue
        paths[f"{root}/{entity_id}" + path[len(template):]] = {
            method: _bind(op, PARAM_NAMES[collection], data_ids) for method, op in ops.items()}
    scope = prefix if entity_id is None else prefix.replace(template, f"{root}/{entity_id}")
    return {**full, "info": {**full["info"], "title": f"sovd-gateway - {scope.lstrip('/')}"},
            "paths": paths}


def _bind(op: dict[str, Any], id_name: str, data_ids: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """``op`` without its entity-id path parameter; topics as examples of ``data_id``."""
    params = []
    for param in op.get("parameters", []):
        if param["name"] == id_name and param["in"] == "path":
            continue
        if param["name"] == "data_id" and data_ids:
            param = {**param, "examples": {t: {"summary": f"topic {t}", "value": t.lstrip("/")}
                                           for t in data_ids}}
        params.append(param)
    out = {k: v for k, v in op.items() if k != "parameters"}
    if params:
        out["parameters"] = params
    return out


def endpoint_list() -> list[str]:
    """``"GET /api/v1/health"`` ... for every documented operation (``GET /metrics`` is outside the base)."""
    out = []
    for path, ops in _document()["paths"].items():
        for method, op in ops.items():
            base = op["servers"][0]["url"].rstrip("/") if op.get("servers") else API_BASE
            out.append(f"{method.upper()} {base}{path}")
    return out
