"""The audit trail: who tried to change what, and what came of it (``trail.py``; the store is
``app/core/accessdb.py``).

:func:`init_app` records every write (``POST``, ``PUT``, ``DELETE``, ``PATCH``) that matched a
route, once its answer is made (an ``after_request`` hook: refusals by the role check, a lock or a
switch included), and serves ``GET /api/v1/x-medkit-audit`` (admin only whenever authentication
is on: ``app/auth/``):

- filters (each optional, all must hold): ``client_id``, ``address``, ``method``, ``family``
  (``data``, ``operations``, ``configurations``, ``faults``, ``locks``, ``auth`` ...),
  ``collection`` and ``entity_id``, ``request_id``, ``status`` (a code, or ``2xx``, ``4xx``,
  ``5xx``), ``since`` and ``until`` (Unix seconds);
- paging: ``limit`` (1–1000, default 100) records, newest first (by time, then id); ``before`` an
  id, for the page after one whose last record had that id.  The answer: ``{"items": [...], "next_before"?: id}``
  (``next_before`` when there may be more).

A record's fields: ``id``, ``timestamp`` (ISO 8601, UTC), ``ts_ns``, ``client_id`` (null when the
request carried no good token), ``address``, ``role``, ``method``, ``resource`` (the path),
``family``, ``collection``, ``entity_id``, ``request_id``, ``status``, ``error_code``.
"""

from __future__ import annotations

import logging
import re
import time
from typing import Any

import orjson
from flask import Blueprint, Flask, Response, current_app, request

from .. import auth
from ..core import accessdb, blocking, requestid
from ..core import target as targets
from ..core.common import json_response
from ..core.entities import API_BASE
from ..core.errors import ApiError
from .trail import AuditTrail

log = logging.getLogger("sovd.http.audit")
EXTENSION = "sovd_audit"
LIMIT_MAX = 1000
_STATUS_CLASS = re.compile(r"^([1-5])xx$")
_FILTERS = ("client_id", "address", "method", "family", "collection", "entity_id", "request_id")

bp = Blueprint("audit", __name__, url_prefix=API_BASE)


def _record(response: Response) -> Response:
    req = request._get_current_object()
    if req.method not in targets.WRITE_METHODS or req.url_rule is None:
        return response
    trail: AuditTrail = current_app.extensions[EXTENSION]
    target = targets.of(req)
    who = auth.identity(req)
    client_id = req.environ.get(auth.GRANTED) or (who.client_id if who is not None else None)
    trail.record((time.time_ns(), client_id, req.environ.get("REMOTE_ADDR") or "",
                  who.role if who is not None else None, req.method, req.path[:2048], target.family,
                  target.collection, (target.entity_id or "")[:256] or None, requestid.current(),
                  response.status_code, _error_code(response)))
    return response


def _error_code(response: Response) -> str | None:
    """The answer's ``error_code`` (or OAuth2 ``error``), for an error answer with a JSON body."""
    if response.status_code < 400 or response.is_streamed or response.mimetype != "application/json":
        return None
    try:
        body = orjson.loads(response.get_data())
    except orjson.JSONDecodeError:
        return None
    if not isinstance(body, dict):
        return None
    code = body.get("error") if "error" in body else body.get("error_code")
    return str(code)[:100] if code is not None else None


@bp.get("/x-medkit-audit")
def audit():
    trail: AuditTrail = current_app.extensions[EXTENSION]
    if not trail.enabled:
        raise ApiError(404, "resource-not-found", "The audit trail is off on this gateway",
                       {"details": "audit_max_records is 0"})
    where: list[tuple[str, Any]] = []
    args = request.args
    for name in _FILTERS:
        if name in args:
            where.append((name, args[name][:2048]))
    if "status" in args:
        where += _status(args["status"])
    for name in ("since", "until"):
        if name in args:
            where.append((name + "_ns", int(_number(args[name], name) * 1e9)))
    limit = int(_number(args.get("limit", "100"), "limit", whole=True))
    if not 1 <= limit <= LIMIT_MAX:
        raise ApiError(400, "invalid-parameter", f"limit must be 1 to {LIMIT_MAX}", {"limit": args["limit"][:50]})
    before = int(_number(args["before"], "before", whole=True)) if "before" in args else None
    rows = blocking.run(trail.query, where, before, limit + 1)
    body: dict[str, Any] = {"items": [_shown(row) for row in rows[:limit]]}
    if len(rows) > limit:
        body["next_before"] = rows[limit - 1]["id"]
    return json_response(body)


def _status(text: str) -> list[tuple[str, Any]]:
    match = _STATUS_CLASS.match(text)
    if match:
        low = int(match.group(1)) * 100
        return [("status_min", low), ("status_max", low + 99)]
    if text.isdigit() and len(text) == 3:
        return [("status", int(text))]
    raise ApiError(400, "invalid-parameter", "status must be a status code (409) or a class (4xx)",
                   {"status": text[:50]})


def _number(text: str, name: str, whole: bool = False) -> float:
    """A query parameter as a number from 0 to 10**10 (Unix seconds up to the year 2286; ids, limits)."""
    try:
        value = int(text) if whole else float(text)
    except ValueError:
        value = None
    if value is None or not 0 <= value <= 1e10:  # (NaN and the infinities fail too)
        raise ApiError(400, "invalid-parameter", f"{name} must be a {'whole ' if whole else ''}number from 0 "
                       "to 10000000000", {name: text[:50]})
    return value


def _shown(row: dict[str, Any]) -> dict[str, Any]:
    seconds, ns = divmod(row["ts_ns"], 10**9)
    stamp = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(seconds)) + f".{ns // 1000:06d}Z"
    return {"id": row["id"], "timestamp": stamp, **{k: v for k, v in row.items() if k != "id"}}


def init_app(app: Flask) -> None:
    cfg = app.config["SOVD"]
    app.extensions[EXTENSION] = AuditTrail(accessdb.path_for(cfg), cfg.audit_max_records, cfg.audit_max_age_days)
    app.after_request(_record)
    app.register_blueprint(bp)
