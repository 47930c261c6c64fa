"""Errors that cross the process boundary: one table of codes, sent as data.

An error travels as ``{"code", "message", "params"}``.  The
receiving side rebuilds an :class:`IpcError` only from the codes in
:data:`CODES`; anything else becomes ``internal``.  Tracebacks never travel:
they go to the ROS worker's log.  What a code means to an HTTP client (status,
SOVD ``error_code``, ``vendor_code``, ``Retry-After``) is the HTTP side's
business: ``app/core/errors.py``.
"""

from __future__ import annotations

from typing import Any

# Every code an error on the wire may carry (the HTTP side's answer to each: app/core/errors.py).
CODES: frozenset[str] = frozenset({
    "bad-request",
    "invalid-topic",
    "invalid-type",
    "type-mismatch",
    "type-not-installed",
    "invalid-data",
    "unknown-command",
    "unsupported-version",
    "not-enabled",
    "no-such-topic",
    "no-such-subscription",
    "subscribe-failed",
    "publish-failed",
    "internal",
    "message-undecodable",
    "cold-wait-cap-exceeded",
    "backpressure",
    "pool-busy",
    "shutdown",
    "unavailable",
    "outcome-unknown",   # a write reached the ROS worker, which went away before it answered
    "subscriptions-full",
    "deadline-exceeded",
    "no-such-recording",  # bulk data: a fault recording that is not there (rosworker/bulk_data/)
    # operations: services and actions
    "invalid-operation-data",
    "type-introspection-failed",
    "service-unavailable",
    "action-unavailable",
    "action-rejected",
    "not-responding",
    "no-such-execution",
    "goals-full",
    # configurations (rosworker/configurations/clients.py)
    "node-unavailable",
    "no-such-parameter",
    "no-default",
    "parameter-read-only",
    "invalid-parameter-value",
    "parameter-failed",
    # faults (rosworker/faults/manager.py)
    "no-such-fault",
    # triggers (rosworker/triggers/registry.py)
    "no-such-trigger",
    "triggers-full",
    "lock-conflict", "lock-not-found", "lock-not-owner", "locks-full",  # locks (rosworker/locks/)
})


class IpcError(Exception):
    """An error answered by (or about) the ROS worker."""

    def __init__(self, code: str, message: str, params: dict[str, Any] | None = None):
        if code not in CODES:
            code = "internal"
        super().__init__(message)
        self.code = code
        self.message = message
        self.params = dict(params or {})

    def to_wire(self) -> dict[str, Any]:
        return {"code": self.code, "message": self.message, "params": self.params}

    @classmethod
    def from_wire(cls, data: Any) -> IpcError:
        if not isinstance(data, dict):
            return cls("internal", "malformed error reply from the ROS worker")
        code = data.get("code")
        message = data.get("message")
        params = data.get("params")
        if not isinstance(message, str):
            message = "error reply without a message"
        if not isinstance(params, dict):
            params = {}
        return cls(code if isinstance(code, str) else "internal", message, params)

    def __repr__(self) -> str:
        return f"IpcError({self.code!r}, {self.message!r}, {self.params!r})"
