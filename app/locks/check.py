"""The lock check of every write, in one place: before its route runs, by method and route family.

Every ``POST``, ``PUT``, ``DELETE`` and ``PATCH`` that reaches the gateway passes through
:func:`check` (a ``before_request`` hook registered by ``app/locks/__init__.py`` after the role
check): nothing in a route asks for it, so a route added later (bulk-data uploads, a fleet's
forwarded writes) is covered the moment it exists.  A write is refused 409 ``lock-broken``
(medkit's ``validate_lock_access``) when another client holds an unexpired lock whose scopes
cover the write's family (no scopes: every family):

- on an app: that app's lock, or its component's (a lock on a component covers its apps);
- on a component: that component's lock (as medkit: an app's lock does not stop a write
  addressed to its component);
- on a function (it has no locks of its own): the locks of the apps it hosts and of their
  component;
- on the whole robot (``DELETE /api/v1/faults``): every lock.  medkit clears the faults of the
  unlocked entities and passes over the rest; here the clear is refused, which says so.

The family is the path's resource collection, which is also the lock scope's name (``data``,
``operations``, ``configurations``, ``faults``, ``logs``, ``cyclic-subscriptions``, ``bulk-data``,
``scripts``, and this gateway's ``triggers``); the ``locks`` family itself and the families that
are no lock scope (``auth``, ``updates``, ``status``) are not checked.  The writer is
``app/auth``'s ``lock_owner``: the token's client id, or medkit's ``X-Client-Id``.

The locks are the ROS worker's; each HTTP worker keeps a copy (:class:`LockCopy`) that it fetches
again only after the ``locks`` generation moved (``common/generations.py``), so a write with no
lock change since the last one costs a read of shared memory and a look at a small dictionary.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from flask import current_app, request

from common.generations import Generations

from .. import auth
from ..core import metrics, rosclient
from ..core import target as targets
from ..core.errors import ApiError

SCOPES = targets.LOCK_SCOPES
SLOT = "locks"


class LockCopy:
    """This HTTP worker's copy of the ROS worker's lock table."""

    def __init__(self, runtime_dir: str):
        self.generations = Generations(runtime_dir)
        self._seen: int | None = None
        self._locks: list[dict[str, Any]] = []
        self._fetching = threading.Lock()

    def current(self) -> list[dict[str, Any]]:
        """The locks (``expires`` a monotonic deadline); fetched again when the table changed."""
        generation = self.generations.read(SLOT)
        if generation == self._seen:
            return self._locks
        with self._fetching:
            if generation != self._seen:
                answer = rosclient.get().call("lock_list")
                now = time.monotonic()
                self._locks = [{**lock, "expires": now + lock["expires_in"]} for lock in answer["items"]]
                self._seen = generation
        return self._locks


def covering(locks: list[dict[str, Any]], collection: str | None, entity_id: str | None) -> list[dict[str, Any]]:
    """The locks that guard a write to this entity (see the module docstring)."""
    if collection is None:
        return list(locks)
    keys = {(collection, entity_id)}
    if collection in ("apps", "functions"):
        index = rosclient.get().entities()
        entity = index.get(collection, entity_id)
        apps = [entity] if collection == "apps" else \
            [index.get("apps", app_id) for app_id in (entity.app_ids if entity is not None else [])]
        for app in apps:
            if app is not None:
                keys.add(("apps", app.id))
                if app.component_id:
                    keys.add(("components", app.component_id))
    return [lock for lock in locks if (lock["collection"], lock["entity_id"]) in keys]


def check() -> None:
    req = request._get_current_object()
    if req.method not in targets.WRITE_METHODS:
        return
    target = targets.of(req)
    if target.family not in SCOPES:
        return
    copy: LockCopy = current_app.extensions[EXTENSION]
    locks = copy.current()
    if not locks:
        return
    owner = auth.lock_owner(req)
    now = time.monotonic()
    for lock in covering(locks, target.collection, target.entity_id):
        if lock["owner"] != owner and lock["expires"] > now and (not lock["scopes"] or target.family in lock["scopes"]):
            refused(lock, target.family)


def refused(lock: dict[str, Any], family: str) -> None:
    metrics.http().declared["lock_refusals"].inc()
    raise ApiError(409, "lock-broken", f"Entity '{lock['entity_id']}' is locked by another client",
                   {"entity_id": lock["entity_id"], "collection": family, "lock_id": lock["id"]})


EXTENSION = "sovd_locks"
