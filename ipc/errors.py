"""Errors that cross the process boundary: one table of codes, sent as data.

An error travels as ``{"code", "message", "status", "params"}``.  The
receiving side rebuilds an :class:`IpcError` only from the codes in
:data:`CODES`; anything else becomes ``internal``.  Tracebacks never travel:
they go to the ROS worker's log.
"""

from __future__ import annotations

from typing import Any

# code -> (HTTP status, SOVD error_code, vendor_code or None, retry-after seconds or None)
CODES: dict[str, tuple[int, str, str | None, int | None]] = {
    "bad-request": (400, "invalid-request", None, None),
    "invalid-topic": (400, "invalid-parameter", None, None),
    "invalid-type": (400, "invalid-parameter", None, None),
    "type-mismatch": (400, "invalid-parameter", None, None),
    "type-not-installed": (400, "invalid-request", None, None),
    "invalid-data": (400, "invalid-request", None, None),
    "unknown-command": (400, "invalid-request", None, None),
    "unsupported-version": (400, "invalid-request", None, None),
    "not-enabled": (403, "invalid-request", None, None),
    "no-such-topic": (404, "resource-not-found", None, None),
    "no-such-subscription": (404, "resource-not-found", None, None),
    "subscribe-failed": (500, "vendor-error", "x-medkit-subscribe-failed", None),
    "publish-failed": (500, "vendor-error", "x-medkit-publish-failed", None),
    "internal": (500, "internal-error", None, None),
    "message-undecodable": (502, "vendor-error", "x-medkit-message-undecodable", None),
    "cold-wait-cap-exceeded": (503, "vendor-error", "x-medkit-cold-wait-cap-exceeded", 1),
    "backpressure": (503, "vendor-error", "x-medkit-ros-worker-backpressure", 1),
    "pool-busy": (503, "vendor-error", "x-medkit-pool-busy", 1),
    "shutdown": (503, "vendor-error", "x-medkit-gateway-shutdown", 2),
    "unavailable": (503, "vendor-error", "x-medkit-ros-worker-unavailable", 2),
    "subscriptions-full": (503, "service-unavailable", None, 5),
    "deadline-exceeded": (504, "not-responding", None, None),
}


class IpcError(Exception):
    """An error answered by (or about) the ROS worker."""

    def __init__(self, code: str, message: str, params: dict[str, Any] | None = None):
        if code not in CODES:
            code = "internal"
        super().__init__(message)
        self.code = code
        self.message = message
        self.params = dict(params or {})

    @property
    def status(self) -> int:
        return CODES[self.code][0]

    @property
    def error_code(self) -> str:
        return CODES[self.code][1]

    @property
    def vendor_code(self) -> str | None:
        return CODES[self.code][2]

    @property
    def retry_after(self) -> int | None:
        return CODES[self.code][3]

    def to_wire(self) -> dict[str, Any]:
        return {"code": self.code, "message": self.message, "status": self.status, "params": self.params}

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
