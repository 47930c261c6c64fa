"""``/{apps|components}/{id}/locks``: acquire, list, get, extend and release SOVD locks.

medkit's ``lock_handlers.cpp``, in its order of checks:

- ``locking_enabled`` off: 501 ``not-implemented`` (``Locking is not enabled on this gateway``);
- who: the token's client id with a good bearer token, else ``X-Client-Id`` (required to acquire,
  extend and release: 400 ``invalid-parameter`` without it; 1–256 characters, no control
  character);
- the entity: 400 for a bad id or one of another type, 404 ``entity-not-found``;
- ``POST``: ``{"lock_expiration": <seconds ≥ 1>, "scopes"?: [...], "break_lock"?: bool}`` → 201
  the lock, ``Location`` its URL; 400 ``invalid-parameter`` for a bad ``lock_expiration``
  (or one past ``locking_default_max_expiration``) or an unknown scope; 409
  ``invalid-request`` when another lock holds the entity (``existing_lock_id``), unless
  ``break_lock``;
- ``GET .../locks``: ``{"items": [lock]}`` (at most one); ``GET .../locks/{id}``: the lock, or
  404 ``resource-not-found`` (``Lock not found``);
- ``PUT .../locks/{id}`` ``{"lock_expiration"}`` → 204, counted from now; ``DELETE`` → 204;
  403 ``forbidden`` for a lock of another client.

A lock: ``{"id": "lock_1", "owned": bool, "scopes"?: [...], "lock_expiration":
"2026-03-18T21:30:00Z"}`` (``scopes`` left out when the lock covers every collection; the
expiry on the wall clock, from the monotonic deadline, at the time of the answer).  The table
is the ROS worker's (``rosworker/locks/``).
"""

from __future__ import annotations

import time
from typing import Any

from flask import Blueprint, current_app, request

from .. import auth
from ..core import bodies, rosclient
from ..core.common import json_response, lookup
from ..core.entities import API_BASE
from ..core.errors import ApiError
from .check import SCOPES

bp = Blueprint("locks", __name__, url_prefix=API_BASE)

COLLECTIONS = "<any(apps, components):collection>/<entity_id>"


@bp.post(f"/{COLLECTIONS}/locks")
def acquire(collection: str, entity_id: str):
    _enabled()
    owner = _owner(required=True)
    lookup(collection, entity_id)
    body = bodies.json_object('{"lock_expiration": <seconds>, "scopes": [...], "break_lock": false}')
    args: dict[str, Any] = {"collection": collection, "entity_id": entity_id, "owner": owner,
                            "lock_expiration": _expiration(body.get("lock_expiration")),
                            "scopes": _scopes(body.get("scopes")),
                            "break_lock": _flag(body.get("break_lock", False), "break_lock")}
    lock = rosclient.get().call("lock_acquire", args)
    return json_response(_shown(lock, owner), 201, {"Location": f"{request.path}/{lock['id']}"})


@bp.get(f"/{COLLECTIONS}/locks")
def listing(collection: str, entity_id: str):
    _enabled()
    owner = _owner(required=False)
    lookup(collection, entity_id)
    return json_response({"items": [_shown(lock, owner) for lock in _locks_of(collection, entity_id)]})


@bp.get(f"/{COLLECTIONS}/locks/<lock_id>")
def detail(collection: str, entity_id: str, lock_id: str):
    _enabled()
    owner = _owner(required=False)
    lookup(collection, entity_id)
    for lock in _locks_of(collection, entity_id):
        if lock["id"] == lock_id:
            return json_response(_shown(lock, owner))
    raise _not_found(lock_id, entity_id)


@bp.put(f"/{COLLECTIONS}/locks/<lock_id>")
def extend(collection: str, entity_id: str, lock_id: str):
    _enabled()
    owner = _owner(required=True)
    lookup(collection, entity_id)
    if not any(lock["id"] == lock_id for lock in _locks_of(collection, entity_id)):
        raise _not_found(lock_id, entity_id)
    body = bodies.json_object('{"lock_expiration": <seconds>}')
    rosclient.get().call("lock_extend", {"collection": collection, "entity_id": entity_id, "owner": owner, "lock_id": lock_id,
                          "lock_expiration": _expiration(body.get("lock_expiration"))})
    return current_app.response_class(status=204)


@bp.delete(f"/{COLLECTIONS}/locks/<lock_id>")
def release(collection: str, entity_id: str, lock_id: str):
    _enabled()
    owner = _owner(required=True)
    lookup(collection, entity_id)
    rosclient.get().call("lock_release", {"collection": collection, "entity_id": entity_id, "owner": owner, "lock_id": lock_id})
    return current_app.response_class(status=204)


# ---- helpers ---------------------------------------------------------------------------------------
def _enabled() -> None:
    if not current_app.config["SOVD"].locking_enabled:
        raise ApiError(501, "not-implemented", "Locking is not enabled on this gateway")


def _owner(required: bool) -> str | None:
    owner = auth.lock_owner()
    if owner is not None or not required:
        return owner
    given = request.headers.get(auth.CLIENT_ID_HEADER)
    if not given:
        raise ApiError(400, "invalid-parameter", "Missing required X-Client-Id header",
                       {"details": "X-Client-Id header is required for lock operations"})
    if len(given) > auth.CLIENT_ID_MAX:
        raise ApiError(400, "invalid-parameter", "X-Client-Id exceeds maximum length",
                       {"details": f"X-Client-Id must be at most {auth.CLIENT_ID_MAX} characters",
                        "max_length": auth.CLIENT_ID_MAX})
    raise ApiError(400, "invalid-parameter", "X-Client-Id contains invalid characters",
                   {"details": "X-Client-Id must not contain control characters"})


def _expiration(value: Any) -> int:
    limit = current_app.config["SOVD"].locking_default_max_expiration
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ApiError(400, "invalid-parameter", "Invalid lock_expiration",
                       {"details": "lock_expiration must be a positive integer (seconds)"})
    if value > limit:
        raise ApiError(400, "invalid-parameter", f"Expiration exceeds maximum allowed ({limit}s)",
                       {"details": f"lock_expiration must be at most {limit} seconds "
                                   "(locking_default_max_expiration)", "max_expiration": limit})
    return value


def _scopes(value: Any) -> list[str]:
    if value is None:
        return []
    if not isinstance(value, list) or not all(isinstance(scope, str) for scope in value):
        raise ApiError(400, "invalid-request", "scopes must be a list of strings",
                       {"details": "Valid scopes: " + ", ".join(SCOPES)})
    for scope in value:
        if scope not in SCOPES:
            raise ApiError(400, "invalid-parameter", f"Unknown lock scope: {scope[:100]}",
                           {"details": "Valid scopes: " + ", ".join(SCOPES), "invalid_scope": scope[:100]})
    return value


def _flag(value: Any, name: str) -> bool:
    if not isinstance(value, bool):
        raise ApiError(400, "invalid-request", f"{name} must be true or false")
    return value


def _locks_of(collection: str, entity_id: str) -> list[dict[str, Any]]:
    """The entity's lock (a list of at most one), as the ROS worker holds them now."""
    items = rosclient.get().call("lock_list", {})["items"]
    return [lock for lock in items if lock["collection"] == collection and lock["entity_id"] == entity_id]


def _shown(lock: dict[str, Any], owner: str | None) -> dict[str, Any]:
    shown: dict[str, Any] = {"id": lock["id"], "owned": owner is not None and lock["owner"] == owner}
    if lock["scopes"]:
        shown["scopes"] = list(lock["scopes"])
    shown["lock_expiration"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(time.time() + lock["expires_in"]))
    return shown


def _not_found(lock_id: str, entity_id: str) -> ApiError:
    return ApiError(404, "resource-not-found", "Lock not found", {"lock_id": lock_id[:300], "entity_id": entity_id})
