"""JSON errors: the application's own error type and the handlers that send every error as JSON.

Body (the C++ ros2_medkit gateway's, README "What you get over HTTP")::

    {"error_code": "entity-not-found", "message": "Entity not found", "parameters": {"entity_id": "x"}}

``parameters`` is left out when empty; vendor errors add ``vendor_code``.
A retryable 503 carries ``Retry-After``.  Handlers are registered most
specific first: :class:`ApiError`, :class:`~ipc.errors.IpcError`, Werkzeug's
``HTTPException`` (404 unmatched route, 405, 413 ...), and last a catch-all that
logs the traceback and answers a bare 500 (a traceback never reaches a client).
"""

from __future__ import annotations

from typing import Any

import orjson
from flask import Flask, Response, current_app, request
from werkzeug.exceptions import HTTPException

from ipc.errors import IpcError

# What an IPC error code (ipc/errors.py) answers an HTTP client:
# code -> (HTTP status, SOVD error_code, vendor_code or None, Retry-After seconds or None)
IPC_ANSWERS: dict[str, tuple[int, str, str | None, int | None]] = {
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
    "outcome-unknown": (504, "not-responding", None, None),  # a write sent; no retry advice
    "subscriptions-full": (503, "service-unavailable", None, 5),
    "deadline-exceeded": (504, "not-responding", None, None),
    # operations: services and actions
    "invalid-operation-data": (400, "invalid-parameter", None, None),
    "type-introspection-failed": (400, "vendor-error", "x-medkit-ros2-type-introspection-failed", None),
    "service-unavailable": (503, "vendor-error", "x-medkit-ros2-service-unavailable", 1),
    "action-unavailable": (503, "vendor-error", "x-medkit-ros2-action-unavailable", 1),
    "action-rejected": (400, "vendor-error", "x-medkit-ros2-action-rejected", None),
    "not-responding": (504, "not-responding", None, None),
    "no-such-execution": (404, "resource-not-found", None, None),
    "goals-full": (503, "service-unavailable", None, 5),
    # configurations (rosworker/configurations/clients.py): medkit's parameter_error_classification.cpp
    "node-unavailable": (503, "vendor-error", "x-medkit-ros2-node-unavailable", 2),
    "no-such-parameter": (404, "resource-not-found", None, None),
    "no-default": (404, "resource-not-found", None, None),
    "parameter-read-only": (403, "vendor-error", "x-medkit-ros2-parameter-read-only", None),
    "invalid-parameter-value": (400, "invalid-parameter", None, None),
    "parameter-failed": (500, "internal-error", None, None),
    # faults (app/faults/routes.py)
    "no-such-fault": (404, "resource-not-found", None, None),
    "no-such-recording": (404, "resource-not-found", None, None),  # bulk data (rosworker/bulk_data/)
    # triggers (app/triggers/routes.py)
    "no-such-trigger": (404, "resource-not-found", None, None),
    "triggers-full": (503, "service-unavailable", None, 5),
    # locks (app/locks/routes.py): medkit's lock_handlers.cpp to_sovd_error_code
    "lock-conflict": (409, "invalid-request", None, None),
    "lock-not-found": (404, "resource-not-found", None, None),
    "lock-not-owner": (403, "forbidden", None, None),
    "locks-full": (503, "service-unavailable", None, 5),
}

# HTTP status -> SOVD error_code for errors that Werkzeug raises.
HTTP_CODES = {
    400: "invalid-request",
    401: "unauthorized",
    403: "forbidden",
    404: "resource-not-found",
    405: "invalid-request",
    408: "invalid-request",
    413: "payload-too-large",
    500: "internal-error",
    501: "not-implemented",
    503: "service-unavailable",
    504: "not-responding",
}
HTTP_MESSAGES = {
    404: "Resource not found",
    405: "Method not allowed",
    408: "Request body not received in time",
    413: "Request body too large",
}


class ApiError(Exception):
    """An error answered to the HTTP client; carries its status and its body."""

    def __init__(self, status: int, error_code: str, message: str,
                 parameters: dict[str, Any] | None = None, *, vendor_code: str | None = None,
                 retry_after: int | None = None, headers: dict[str, str] | None = None):
        super().__init__(message)
        self.status = status
        self.error_code = error_code
        self.message = message
        self.parameters = dict(parameters or {})
        self.vendor_code = vendor_code
        self.retry_after = retry_after
        self.headers = dict(headers or {})

    def to_dict(self) -> dict[str, Any]:
        body: dict[str, Any] = {"error_code": self.error_code}
        if self.vendor_code:
            body["vendor_code"] = self.vendor_code
        body["message"] = self.message
        if self.parameters:
            body["parameters"] = self.parameters
        return body

    @classmethod
    def from_ipc(cls, exc: IpcError, parameters: dict[str, Any] | None = None,
                 message: str | None = None) -> ApiError:
        """Map a ROS-worker error through the one table, :data:`IPC_ANSWERS`."""
        params = {**exc.params, **(parameters or {})}
        status, error_code, vendor_code, retry_after = IPC_ANSWERS[exc.code]
        return cls(status, error_code, message or exc.message, params,
                   vendor_code=vendor_code, retry_after=retry_after)

    def __repr__(self) -> str:
        return f"ApiError({self.status}, {self.error_code!r}, {self.message!r})"


def error_response(err: ApiError) -> Response:
    headers = dict(err.headers)
    if err.retry_after is not None:
        headers["Retry-After"] = str(err.retry_after)
    body = err.to_dict()
    try:
        text = orjson.dumps(body)
    except (TypeError, orjson.JSONEncodeError):  # a parameter echoes what JSON cannot carry (2**70)
        text = orjson.dumps(_printable(body))
    return current_app.response_class(text, status=err.status, mimetype="application/json",
                                      headers=headers)


def _printable(value: Any) -> Any:
    """``value`` with whatever orjson refuses (integers beyond 64 bits ...) turned into strings."""
    if isinstance(value, dict):
        return {str(k): _printable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_printable(v) for v in value]
    if value is None or isinstance(value, (bool, float, str)):
        return value
    if isinstance(value, int) and -(2**63) <= value < 2**64:
        return value
    return str(value)[:100]


def _handle_api_error(err: ApiError) -> Response:
    return error_response(err)


def _handle_ipc_error(exc: IpcError) -> Response:
    if exc.code == "internal":
        current_app.logger.error("ROS worker error on %s %s: %s", request.method, request.path, exc.message)
    return error_response(ApiError.from_ipc(exc))


def _handle_http(exc: HTTPException) -> Response | HTTPException:
    status = exc.code
    if status is None or status < 400:
        return exc  # redirects and the like are not errors
    code = HTTP_CODES.get(status, "invalid-request" if status < 500 else "internal-error")
    message = HTTP_MESSAGES.get(status) or exc.name
    params: dict[str, Any] = {}
    headers: dict[str, str] = {}
    if status == 404:
        params.update(status=404, path=request.path)  # medkit's unmatched route: parameters.status
    elif status == 405:
        allowed = sorted(getattr(exc, "valid_methods", None) or [])
        params.update({"method": request.method, "allowed_methods": allowed})
        if allowed:
            headers["Allow"] = ", ".join(allowed)
    elif status == 413:
        limit = current_app.config.get("MAX_CONTENT_LENGTH")
        if limit:
            params["max_body_bytes"] = limit
            message = f"Request body too large (limit {limit} bytes)"
    elif status in (400, 408) and exc.description:
        params["details"] = exc.description
    return error_response(ApiError(status, code, message, params, headers=headers))


def _handle_unexpected(exc: Exception) -> Response:
    current_app.logger.exception("Unhandled error on %s %s", request.method, request.path)
    return error_response(ApiError(500, "internal-error", "Internal server error"))


def init_app(app: Flask) -> None:
    app.register_error_handler(ApiError, _handle_api_error)
    app.register_error_handler(IpcError, _handle_ipc_error)
    app.register_error_handler(HTTPException, _handle_http)
    app.register_error_handler(Exception, _handle_unexpected)
