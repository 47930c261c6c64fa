"""What every blueprint needs: JSON responses, entity lookup with the contract's id rules."""

from __future__ import annotations

import re
import time
from typing import Any

import orjson
from flask import Response, current_app
from werkzeug.routing import BaseConverter

from . import rosclient
from .entities import COLLECTIONS, ENTITY_ID_MAX, KINDS, PARAM_NAMES, Entity
from .errors import ApiError

_ID_CHAR = re.compile(r"[^A-Za-z0-9_-]")
# A ``%`` not followed by two hex digits: what percent-decoding silently passes through.
BAD_PERCENT = re.compile(r"%(?![0-9A-Fa-f]{2})")


def json_response(obj: Any, status: int = 200, headers: dict[str, str] | None = None) -> Response:
    """``obj`` serialized with orjson, as ``application/json``."""
    return current_app.response_class(orjson.dumps(obj), status=status,
                                      mimetype="application/json", headers=headers)


def config():
    return current_app.config["SOVD"]


class CollectionConverter(BaseConverter):
    """``areas``, ``components``, ``apps`` or ``functions``."""

    regex = "(?:" + "|".join(COLLECTIONS) + ")"


class DataIdConverter(BaseConverter):
    """The rest of the path after ``data/``, slashes included, possibly empty.

    Werkzeug's ``path`` converter does not match a leading ``/`` (so
    ``data//a/b`` would not route) and ``.`` does not match a newline (so an
    encoded ``%0A`` would become a 404 instead of a 400); this one takes
    everything and leaves the checking to :func:`app.data.checks.topic_from_data_id`.
    """

    regex = r"[\s\S]*"
    part_isolating = False
    weight = 200


def entity_id_problem(entity_id: str) -> str | None:
    """Why ``entity_id`` is not 1–256 bytes of ``[A-Za-z0-9_-]``, or None.

    The texts are medkit's (``core/entity_validation.cpp``): it checks the
    UTF-8 bytes of the id, so a non-ASCII character is named by its first byte.
    """
    raw = entity_id.encode("utf-8", "replace")
    if not raw:
        return "Entity ID cannot be empty"
    if len(raw) > ENTITY_ID_MAX:
        return f"Entity ID too long (max {ENTITY_ID_MAX} characters)"
    bad = _ID_CHAR.search(entity_id)
    if bad:
        byte = bad.group().encode("utf-8", "replace")[0]
        shown = chr(byte) if 32 <= byte <= 126 else f"0x{byte:02x}"
        return (f"Entity ID contains invalid character: '{shown}'. "
                "Only alphanumeric, underscore and hyphen are allowed")
    return None


def check_entity_id(entity_id: str) -> None:
    problem = entity_id_problem(entity_id)
    if problem:
        raise ApiError(400, "invalid-parameter", "Invalid entity ID",
                       {"details": problem, "entity_id": entity_id[:300]})


def lookup(collection: str, entity_id: str) -> Entity:
    """The entity, or the contract's 400 (bad id / other type) or 404.

    medkit's ``validate_entity_for_route`` (``handler_context.cpp``): entity
    details, data routes and the app relation routes answer this way.
    """
    check_entity_id(entity_id)
    asked = time.monotonic()
    index = rosclient.get().entities()
    entity = index.get(collection, entity_id)
    if entity is None:
        index = rosclient.get().entities(checked_since=asked)   # a miss is confirmed on a fresh graph
        entity = index.get(collection, entity_id)
    if entity is not None:
        return entity
    other = index.elsewhere(collection, entity_id)
    expected = KINDS[collection][1]
    if other is not None:
        raise ApiError(400, "invalid-parameter",
                       f"Invalid entity type for route: expected {expected}, got {other.type_name}",
                       {"entity_id": entity_id, "expected_type": expected,
                        "actual_type": other.type_name})
    raise ApiError(404, "entity-not-found", "Entity not found", {"entity_id": entity_id})


def member_nodes(entity: Entity) -> list[tuple[str, str]]:
    """``(app id, node fqn)`` of every node behind the entity (an app's own; a component's or function's
    apps, in app order): whose operations and parameters the entity has."""
    if entity.collection == "apps":
        return [(entity.id, entity.x_medkit["ros2"]["node"])]
    index = rosclient.get().entities()
    out = []
    for app_id in entity.app_ids:
        app = index.get("apps", app_id)
        if app is not None:
            out.append((app_id, app.x_medkit["ros2"]["node"]))
    return out


def node_names(entity: Entity, index: Any = None) -> list[str]:
    """The node FQNs behind ``entity`` (an app's own; a component's or a function's apps'), sorted, once each:
    the scope of its faults and its logs (medkit's rule)."""
    if entity.collection == "apps":
        apps: list[Entity | None] = [entity]
    else:
        index = index if index is not None else rosclient.get().entities()
        apps = [index.get("apps", app_id) for app_id in entity.app_ids]
    fqns = set()
    for app in apps:
        ros2 = (app.x_medkit.get("ros2") if app is not None else None) or {}
        fqn = ros2.get("node") if isinstance(ros2, dict) else None
        if isinstance(fqn, str) and fqn:
            fqns.add(fqn)
    return sorted(fqns)


def in_scope(fault: dict[str, Any], fqns: list[str]) -> bool:
    """medkit's ``fault_in_source_scope``: every reporting source is one of ``fqns`` (:func:`node_names`) or
    below one (the faults' scope; a recording's too, app/bulk_data/)."""
    sources = fault.get("reporting_sources")
    if not fqns or not isinstance(sources, list) or not sources:
        return False
    return all(isinstance(s, str) and any(s == f or s.startswith(f.rstrip("/") + "/") for f in fqns)
               for s in sources)


def lookup_owner(collection: str, entity_id: str) -> Entity:
    """The entity whose relation collection is asked for, or medkit's typed 400/404.

    medkit's relation handlers of areas, components and functions
    (``discovery_handlers.cpp``) look only in their own collection and name the
    type: ``400 "Invalid component ID"`` with ``component_id``, ``404
    "Component not found"``; an id of another type is simply not found there.
    """
    type_name = KINDS[collection][1]
    param = PARAM_NAMES[collection]
    problem = entity_id_problem(entity_id)
    if problem:
        raise ApiError(400, "invalid-parameter", f"Invalid {type_name.lower()} ID",
                       {"details": problem, param: entity_id[:300]})
    asked = time.monotonic()
    entity = rosclient.get().entities().get(collection, entity_id)
    if entity is None:
        entity = rosclient.get().entities(checked_since=asked).get(collection, entity_id)
    if entity is None:
        raise ApiError(404, "entity-not-found", f"{type_name} not found", {param: entity_id})
    return entity
