"""The OpenAPI part of the audit trail: ``GET /x-medkit-audit`` (this gateway's)."""

from __future__ import annotations

from typing import Any

from ..openapi import build as oa
from . import LIMIT_MAX

TAG = {"name": "Audit", "description": "Who tried to change what, and what came of it (admin)"}
NULLABLE = {"type": ["string", "null"]}
SCHEMAS: dict[str, Any] = {
    "AuditRecord": oa.obj(
        ["id", "timestamp", "ts_ns", "client_id", "address", "role", "method", "resource", "family", "collection",
         "entity_id", "request_id", "status", "error_code"],
        id=oa.INT, timestamp={"type": "string", "format": "date-time"}, ts_ns=oa.INT,
        client_id={**NULLABLE, "description": "the token's client id (a granted token's client on /auth routes); "
                                              "null without a good token"},
        address=oa.STR, role=NULLABLE, method={"enum": ["POST", "PUT", "DELETE", "PATCH"]}, resource=oa.STR,
        family=oa.STR, collection=NULLABLE, entity_id=NULLABLE, request_id=NULLABLE, status=oa.INT,
        error_code=NULLABLE),
    "AuditList": oa.obj(["items"], items={"type": "array", "items": oa.ref("AuditRecord")},
                         next_before={**oa.INT, "description": "`before` for the next page, when there may be one"}),
}


def paths() -> dict[str, Any]:
    query = [{"name": name, "in": "query", "required": False, "schema": oa.STR, "description": text} for name, text in (
        ("client_id", "records of this client"), ("address", "records of this client address"),
        ("method", "POST, PUT, DELETE or PATCH"), ("family", "data, operations, configurations, faults, locks, auth …"),
        ("collection", "apps, components, functions"), ("entity_id", "records of this entity"),
        ("request_id", "the record of this request"), ("status", "a status (409) or a class (4xx)"),
        ("since", "Unix seconds, inclusive"), ("until", "Unix seconds, exclusive"),
        ("limit", f"records per page, 1 to {LIMIT_MAX} (default 100)"),
        ("before", "the next page: records older than this id"))]
    return {"/x-medkit-audit": {"get": oa.op(
        "listAuditRecords", "Audit", "The audit trail, newest first, filtered and paged", oa.ok("AuditList"),
        ("400", "A bad filter or paging value (`invalid-parameter`)"),
        ("404", "The audit trail is off (audit_max_records 0)"), parameters=query)}}
