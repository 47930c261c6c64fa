"""The OpenAPI part of the locks: medkit's operationIds (``acquireAppLock`` ...), tag ``Locking`` and
schemas (``Lock``, ``LockList``, ``AcquireLockRequest``, ``ExtendLockRequest``)."""

from __future__ import annotations

from typing import Any

from ..core.entities import PARAM_NAMES
from ..core.target import LOCK_SCOPES as SCOPES
from ..openapi import build as oa

TAG = {"name": "Locking", "description": "SOVD locks on components and apps (ISO 17978-3 §7.17)"}
SCOPE = {"enum": list(SCOPES)}
SCHEMAS: dict[str, Any] = {
    "Lock": oa.obj(["id", "owned", "lock_expiration"], id={"type": "string", "pattern": "^lock_[0-9]+$"},
                    owned={"type": "boolean", "description": "held by the client asking (its token's client id, "
                                                             "else its X-Client-Id)"},
                    scopes={"type": "array", "items": SCOPE, "description": "left out: every collection"},
                    lock_expiration={"type": "string", "format": "date-time"}),
    "LockList": oa.obj(["items"], items={"type": "array", "maxItems": 1, "items": oa.ref("Lock")}),
    "AcquireLockRequest": oa.obj(["lock_expiration"],
                                  lock_expiration={**oa.INT, "minimum": 1,
                                                   "description": "seconds, at most locking_default_max_expiration"},
                                  scopes={"type": "array", "items": SCOPE}, break_lock={"type": "boolean"}),
    "ExtendLockRequest": oa.obj(["lock_expiration"], lock_expiration={**oa.INT, "minimum": 1,
                                                                       "description": "seconds from now"}),
}
CLIENT_ID = {"name": "X-Client-Id", "in": "header", "schema": {"type": "string", "minLength": 1, "maxLength": 256},
             "description": "who the client is when it sends no token (a token's client id wins)"}
OFF = ("501", "Locking is off (`not-implemented`, locking_enabled false)")
NO_CLIENT = ("400", "No token and no `X-Client-Id`, a bad `lock_expiration` or scope (`invalid-parameter`), a bad id "
                    "or body (`invalid-request`)")
NOT_FOUND = ("404", "Unknown entity (`entity-not-found`) or lock (`resource-not-found`, `Lock not found`)")


def paths() -> dict[str, Any]:
    out: dict[str, Any] = {}
    for collection in ("apps", "components"):
        title, param = oa.schema_name(collection), PARAM_NAMES[collection]
        base = f"/{collection}/{{{param}}}/locks"
        params = [oa.id_param(collection), {**CLIENT_ID, "required": False}]
        lock_param = {"name": "lock_id", "in": "path", "required": True, "schema": oa.STR}
        acquire = oa.op(f"acquire{title}Lock", "Locking", f"Lock a {collection[:-1]} for this client", None,
                         NO_CLIENT, NOT_FOUND, ("409", "The entity is locked by another client (`invalid-request`, "
                                                       "parameters `existing_lock_id`); `break_lock` takes it over"),
                         *oa.BODY_ERRORS, OFF, "503", "504", parameters=params,
                         requestBody={"required": True, "content": {
                             "application/json": {"schema": oa.ref("AcquireLockRequest")}}})
        acquire["responses"] = {"201": {"description": "Acquired", "headers": {"Location": {"schema": oa.STR}},
                                        "content": {"application/json": {"schema": oa.ref("Lock")}}},
                                **acquire["responses"]}
        mine = ("403", "A lock of another client (`forbidden`)")
        extend = oa.op(f"extend{title}Lock", "Locking", "A new expiry, counted from now", None, NO_CLIENT, mine,
                        NOT_FOUND, *oa.BODY_ERRORS, OFF, "503", "504", parameters=params + [lock_param],
                        requestBody={"required": True, "content": {
                            "application/json": {"schema": oa.ref("ExtendLockRequest")}}})
        extend["responses"] = {"204": {"description": "Extended"}, **extend["responses"]}
        release = oa.op(f"release{title}Lock", "Locking", "Release a lock", None, NO_CLIENT, mine, NOT_FOUND, OFF,
                         "503", "504", parameters=params + [lock_param])
        release["responses"] = {"204": {"description": "Released"}, **release["responses"]}
        out[base] = {"get": oa.op(f"list{title}Locks", "Locking", f"The lock of a {collection[:-1]} (0 or 1)",
                                   oa.ok("LockList"), "400", NOT_FOUND, OFF, "503", "504", parameters=params),
                     "post": acquire}
        out[base + "/{lock_id}"] = {
            "get": oa.op(f"get{title}Lock", "Locking", "One lock", oa.ok("Lock"), "400", NOT_FOUND, OFF, "503", "504",
                          parameters=params + [lock_param]),
            "put": extend, "delete": release}
    return out


HEALTH_SCHEMA = oa.counters_schema("locks", "SOVD locks: held, acquired, released, broken, expired (ROS worker); "
                                            "writes refused by a lock (every HTTP worker)")
SPEC = oa.Spec(paths=paths, schemas=SCHEMAS, tags=(TAG,))
