"""``/api/v1/auth/...``: medkit's OAuth2 routes, and who a token is.

- ``POST /auth/authorize``: the ``client_credentials`` grant, as a JSON or a form body
  (``grant_type``, ``client_id``, ``client_secret``) → 200 the tokens
  (``app/auth/tokens.py``); 400 ``invalid_request`` / ``unsupported_grant_type``, 401
  ``invalid_client``;
- ``POST /auth/token``: the ``refresh_token`` grant, JSON or form → 200 a new access token (the
  same refresh token); 401 ``invalid_grant``;
- ``POST /auth/revoke``: ``{"token": ...}``, JSON only → 200 ``{"status": "revoked"}`` whether
  the token was good or not (RFC 7009; medkit);
- ``GET /auth/x-medkit-whoami`` (this gateway's): the client id and role of the bearer token, and
  what that role may do (``roles.summary``), for the dashboard and for an operator's check.

With ``auth_enabled`` off every one answers 404 ``Authentication is not enabled`` (medkit), but
``whoami`` with the legacy ``api_token``.  Bodies are medkit's OAuth2 ones
(``app/auth/__init__.py``'s ``oauth_response``, the handler of an ``OAuthError`` a route raises).
Failed grants spend the address's failure budget, and an address without one is answered 429
before any secret is compared (``failures.py``).  These routes never need a token themselves.
"""

from __future__ import annotations

import math
from typing import Any
from urllib.parse import parse_qsl

import orjson
from flask import Blueprint, request

from ..core import bodies
from ..core.common import json_response
from ..core.entities import API_BASE
from . import GRANTED, _resolve, get, identity, oauth_response, roles
from .revocations import StoreError
from .tokens import OAuthError

bp = Blueprint("auth", __name__, url_prefix=API_BASE + "/auth")

FIELD_MAX = 8192   # characters of any one field (a token is well under it)
GRANT_FIELDS = ("grant_type", "client_id", "client_secret", "refresh_token", "scope")


@bp.post("/authorize")
def authorize():
    body = _grant_body()
    if body.get("grant_type") != "client_credentials":
        raise OAuthError(400, "unsupported_grant_type", "Only 'client_credentials' grant type is supported")
    client_id, secret = body.get("client_id"), body.get("client_secret")
    if not client_id:
        raise OAuthError(400, "invalid_request", "client_id is required")
    if not secret:
        raise OAuthError(400, "invalid_request", "client_secret is required")
    return json_response(_granted(lambda auth: auth.tokens.authorize(client_id, secret)))


@bp.post("/token")
def token():
    body = _grant_body()
    if body.get("grant_type") != "refresh_token":
        raise OAuthError(400, "unsupported_grant_type",
                         "Only 'refresh_token' grant type is supported on this endpoint")
    refresh = body.get("refresh_token")
    if not refresh:
        raise OAuthError(400, "invalid_request", "refresh_token is required")
    return json_response(_granted(lambda auth: auth.tokens.refresh(refresh)))


@bp.post("/revoke")
def revoke():
    auth = _enabled()
    try:
        body = orjson.loads(bodies.read_body())
    except orjson.JSONDecodeError as exc:
        raise OAuthError(400, "invalid_request", f"Invalid JSON: {_short(exc)}") from None
    value = body.get("token") if isinstance(body, dict) else None
    if not isinstance(value, str) or not value or len(value) > FIELD_MAX:
        raise OAuthError(400, "invalid_request", "token is required")
    try:
        auth.tokens.revoke(value)
    except StoreError:
        raise OAuthError(500, "server_error", "The revocation could not be stored; it holds in one "
                         "HTTP worker only, until it restarts") from None
    return json_response({"status": "revoked"})


@bp.get("/x-medkit-whoami")
def whoami():
    auth = get()
    if not auth.active:
        return oauth_response(_disabled())
    header = request.headers.get("Authorization")
    who = identity()
    if who is None:
        found = _resolve(request._get_current_object())
        return oauth_response(found if isinstance(found, OAuthError) else
                              OAuthError(401, "invalid_token", "Missing Authorization header" if header is None
                                         else "Invalid Authorization header format. Expected: Bearer <token>"))
    expires = None if math.isinf(who.expires_at) else int(who.expires_at)
    return json_response({"client_id": who.client_id, "role": who.role, "expires_at": expires,
                          "require_auth_for": auth.mode, "may": roles.summary(who.role)})


# ---- helpers ---------------------------------------------------------------------------------------
def _enabled():
    auth = get()
    if not auth.enabled:
        raise _disabled()
    return auth


def _disabled() -> OAuthError:
    return OAuthError(404, "resource-not-found", "Authentication is not enabled")


def _granted(grant) -> dict[str, Any]:
    """Run a grant within the address's failure budget; a refused grant spends one failure.  The
    audit record of a granted one names the client (``GRANTED``)."""
    auth = _enabled()
    address = request.environ.get("REMOTE_ADDR") or ""
    auth.failures.check(address)
    try:
        granted = grant(auth)
    except OAuthError as exc:
        if exc.status == 401:
            auth.failures.failed(address)
        raise
    request.environ[GRANTED] = granted.client_id
    return granted.answer


def _grant_body() -> dict[str, str]:
    """The grant's fields from a JSON or form body (medkit's ``AuthorizeRequest::parse_request``)."""
    _enabled()
    kind = request.content_type or ""
    raw = bodies.read_body()
    if "application/json" in kind:
        try:
            body = orjson.loads(raw)
        except orjson.JSONDecodeError as exc:
            raise OAuthError(400, "invalid_request", f"Invalid JSON: {_short(exc)}") from None
        if not isinstance(body, dict):
            raise OAuthError(400, "invalid_request", "The body must be a JSON object")
    elif "application/x-www-form-urlencoded" in kind:
        try:
            body = dict(parse_qsl(raw.decode("utf-8"), keep_blank_values=True))
        except (UnicodeDecodeError, ValueError):
            raise OAuthError(400, "invalid_request", "The form body is not UTF-8 text") from None
    else:
        raise OAuthError(400, "invalid_request",
                         "Content-Type must be application/json or application/x-www-form-urlencoded")
    fields = {}
    for name in GRANT_FIELDS:
        value = body.get(name)
        if value is None:
            continue
        if not isinstance(value, str) or len(value) > FIELD_MAX:
            raise OAuthError(400, "invalid_request", f"{name} must be a string of at most {FIELD_MAX} characters")
        fields[name] = value
    return fields


def _short(exc: Exception) -> str:
    return str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
