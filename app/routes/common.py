"""What every blueprint needs: JSON responses, entity lookup with the contract's id rules."""

from __future__ import annotations

import re
from typing import Any

import orjson
from flask import Response, current_app
from werkzeug.routing import BaseConverter

from .. import rosclient
from ..entities import COLLECTIONS, ENTITY_ID_MAX, KINDS, Entity
from ..errors import ApiError

_ID_CHAR = re.compile(r"[^A-Za-z0-9_-]")


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
    everything and leaves the checking to :func:`app.routes.requests.topic_from_data_id`.
    """

    regex = r"[\s\S]*"
    part_isolating = False
    weight = 200


def entity_id_problem(entity_id: str) -> str | None:
    """Why ``entity_id`` is not 1–256 characters of ``[A-Za-z0-9_-]``, or None."""
    if not entity_id:
        return "Entity ID must not be empty"
    if len(entity_id) > ENTITY_ID_MAX:
        return f"Entity ID is longer than {ENTITY_ID_MAX} characters"
    bad = _ID_CHAR.search(entity_id)
    if bad:
        return (f"Entity ID contains the character {bad.group()!r}; only letters, digits, "
                "'_' and '-' are allowed")
    return None


def check_entity_id(entity_id: str) -> None:
    problem = entity_id_problem(entity_id)
    if problem:
        raise ApiError(400, "invalid-parameter", "Invalid entity ID",
                       {"details": problem, "entity_id": entity_id[:300]})


def lookup(collection: str, entity_id: str) -> Entity:
    """The entity, or the contract's 400 (bad id / other type) or 404."""
    check_entity_id(entity_id)
    index = rosclient.get().entities()
    entity = index.get(collection, entity_id)
    if entity is not None:
        return entity
    other = index.elsewhere(collection, entity_id)
    expected = KINDS[collection][1]
    if other is not None:
        raise ApiError(400, "invalid-parameter", f"Entity is not a {expected}",
                       {"details": f"'{entity_id}' is a {other.type_name}, not a {expected}",
                        "entity_id": entity_id, "expected_type": expected,
                        "actual_type": other.type_name})
    raise ApiError(404, "entity-not-found", "Entity not found", {"entity_id": entity_id})
