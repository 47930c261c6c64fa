"""Who is acting: identities and roles (OAuth2 client credentials, JWTs, medkit's four roles).

The family's parts: ``roles.py`` (medkit's permission table, as data), ``tokens.py`` (issuing and
checking tokens with PyJWT), ``revocations.py`` (revoked token ids, shared and kept),
``failures.py`` (failed authorizations limited per address), ``routes.py`` (``/api/v1/auth/...``).

Here: the check every request passes through before its route runs (:func:`_check`, registered
by :func:`init_app` after the rate limiter), as medkit's ``AuthMiddleware`` does it before
routing, so a route that does not exist is refused the same way:

- ``auth_enabled`` off and no ``api_token``: nothing is checked (every write still needs its
  ``allow_*`` switch: what the robot permits at all);
- ``auth_enabled`` on: ``require_auth_for`` says which requests need a token: ``none``,
  ``write`` (``POST``, ``PUT``, ``DELETE``, ``PATCH``; the default) or ``all`` (every request
  under ``/api/v1`` and ``/metrics``: ``/health`` too, as in medkit's code, whatever its docs
  say).  ``/api/v1/auth/**`` never needs one; the dashboard's files neither (no robot data in
  them; its sign-in form is there).  ``GET /api/v1/x-medkit-audit`` always needs one (admin);
- ``api_token`` alone (the legacy credential): as ``write``, with that one admin token.

A request that needs a token and has none, or a bad one, is answered 401 with
``WWW-Authenticate: Bearer``; one whose role may not do it, 403.  Both bodies are medkit's
OAuth2 ones (``error``: ``invalid_token``, ``insufficient_scope``; ``error_description``) with
the gateway's ``error_code`` and ``message`` beside them, so either kind of client reads them.

Who the client is, for everything else (:func:`identity`): the rate limiter keys on the token's
client id when a request carries a good one (:func:`rate_key`), the lock of a write is its
client id (:func:`lock_owner`; without a token, medkit's ``X-Client-Id`` header), and the audit
trail records it.  A bad token on a request that needs none is ignored, as in medkit.
"""

from __future__ import annotations

from typing import Any

from flask import Flask, Response, current_app, request

from common.generations import Generations

from ..core import accessdb
from ..core import target as targets
from ..core.errors import HTTP_CODES
from . import roles
from .failures import FailureLimit, TooManyFailures
from .revocations import Revocations
from .tokens import Identity, OAuthError, TokenService

EXTENSION = "sovd_auth"
IDENTITY = "sovd.identity"        # in the request's environ: Identity, OAuthError or None
GRANTED = "sovd.auth.granted"     # ... and the client a token was just granted to (its audit record)
API_PREFIX = "/api/v1"
AUTH_PREFIX = "/api/v1/auth/"
ALWAYS = ("/api/v1/x-medkit-audit",)   # need a token whenever there is authentication at all
REALM = 'Bearer realm="sovd-gateway", error="invalid_token"'
CLIENT_ID_HEADER = "X-Client-Id"
CLIENT_ID_MAX = 256


class Auth:
    """One HTTP worker's authentication: the policy, the tokens, the failure limit."""

    def __init__(self, cfg):
        self.enabled = bool(cfg.auth_enabled)
        self.active = self.enabled or bool(cfg.api_token)
        self.mode = cfg.require_auth_for if self.enabled else "write"
        self.algorithm = cfg.jwt_algorithm
        self.revocations = Revocations(accessdb.path_for(cfg), Generations(cfg.runtime_dir))
        self.tokens = TokenService(cfg, self.revocations)
        self.failures = FailureLimit(cfg.runtime_dir, cfg.auth_failure_limit)

    def required(self, method: str, path: str) -> bool:
        """Does this request need a token?"""
        if not self.active or path.startswith(AUTH_PREFIX) or method == "OPTIONS":
            return False
        if path.startswith(ALWAYS):
            return True
        if self.mode == "write":
            return method in targets.WRITE_METHODS
        if self.mode == "all":
            return path.startswith(API_PREFIX) or path == "/metrics"
        return False


def get() -> Auth:
    return current_app.extensions[EXTENSION]


def bearer(header: str) -> str | None:
    """The token of ``Authorization: Bearer <token>`` (scheme in any case), or None."""
    scheme, _, token = header.partition(" ")
    token = token.strip()
    return token if scheme.lower() == "bearer" and token else None


def identity(req=None) -> Identity | None:
    """Who sent the request, by its bearer token; None without one or with a bad one (nothing counted)."""
    found = _resolve(req if req is not None else request._get_current_object())
    return found if isinstance(found, Identity) else None


def _resolve(req) -> Identity | OAuthError | None:
    env = req.environ
    if IDENTITY in env:
        return env[IDENTITY]
    auth = current_app.extensions.get(EXTENSION)
    header = req.headers.get("Authorization")
    found: Identity | OAuthError | None = None
    if auth is not None and auth.active and header is not None:
        token = bearer(header)
        if token is None:
            found = OAuthError(401, "invalid_token", "Invalid Authorization header format. Expected: Bearer <token>")
        else:
            try:
                found = auth.tokens.identify(token)
            except OAuthError as exc:
                found = exc
    env[IDENTITY] = found
    return found


def rate_key(req) -> str:
    """The rate limiter's key: the token's client id when there is a good token, else the address."""
    who = identity(req)
    return "client:" + who.client_id if who is not None else (req.environ.get("REMOTE_ADDR") or "")


def client_id_header(req) -> str | None:
    """medkit's ``X-Client-Id`` header when it is usable (1–256 characters, no control character)."""
    value = req.headers.get(CLIENT_ID_HEADER)
    if not value or len(value) > CLIENT_ID_MAX or any(ord(c) < 0x20 or ord(c) == 0x7F for c in value):
        return None
    return value


def lock_owner(req=None) -> str | None:
    """Who owns what this request locks, and whose locks it may pass: the token's client id (a
    header never overrides a token), else the ``X-Client-Id`` header; None when neither."""
    req = req if req is not None else request._get_current_object()
    who = identity(req)
    if who is not None and not who.legacy:
        return who.client_id
    return client_id_header(req)


# ---- the check -------------------------------------------------------------------------------------
def authenticate(req=None) -> Identity:
    """The request's identity, or :class:`OAuthError` (401; 429 while its address has no failure left).

    A token checked before passes at once; a new one is compared with the secrets only within the
    address's failure budget, and a refused one spends a failure (``failures.py``).
    """
    req = req if req is not None else request._get_current_object()
    auth: Auth = current_app.extensions[EXTENSION]
    address = req.environ.get("REMOTE_ADDR") or ""
    header = req.headers.get("Authorization")
    if header is None:
        raise OAuthError(401, "invalid_token", "Missing Authorization header")
    who = req.environ.get(IDENTITY)
    if who is None:
        token = bearer(header)
        if token is None:
            raise OAuthError(401, "invalid_token", "Invalid Authorization header format. Expected: Bearer <token>")
        try:
            who = auth.tokens.identify(token, gate=lambda: auth.failures.check(address))
        except TooManyFailures:
            raise
        except OAuthError as exc:
            who = exc
        req.environ[IDENTITY] = who
    elif isinstance(who, OAuthError):
        auth.failures.check(address)
    if isinstance(who, OAuthError):
        auth.failures.failed(address)
        raise who
    return who


def require_identity() -> None:
    """For a route that wants a known client even for a read (a request through the fleet): 401 without
    a good token while authentication is on (``auth_enabled`` or the legacy ``api_token``)."""
    if current_app.extensions[EXTENSION].active:
        authenticate()


def _check() -> Response | None:
    req = request._get_current_object()
    auth: Auth = current_app.extensions[EXTENSION]
    if not auth.required(req.method, req.path):
        return None
    try:
        who = authenticate(req)
        if not _allowed(req, who.role):
            raise OAuthError(403, "insufficient_scope", "Insufficient permissions")
    except OAuthError as exc:
        return oauth_response(exc)
    return None


_decisions: dict[tuple[str, str, str], bool] = {}


def _allowed(req, role: str) -> bool:
    """The role table's answer for this request.  For a matched route it depends only on the role, the
    method and the route's role path (its collection, every other variable one segment, bulk data's
    at most three: ``app/core/target.py``), so it is remembered by those (a bounded set); an unmatched
    path is matched each time."""
    method = "GET" if req.method == "HEAD" else req.method
    role_path = targets.of(req).role_path
    if req.url_rule is None:
        return roles.allowed(role, method, role_path)
    key = (role, method, role_path)
    decision = _decisions.get(key)
    if decision is None:
        decision = _decisions[key] = roles.allowed(role, method, role_path)
    return decision


def oauth_response(exc: OAuthError, extra: dict[str, Any] | None = None) -> Response:
    """medkit's OAuth2 error body, with the gateway's ``error_code`` and ``message`` beside it."""
    import orjson

    code = "rate-limit-exceeded" if exc.status == 429 else HTTP_CODES.get(exc.status, "internal-error")
    body: dict[str, Any] = {"error": exc.error, "error_description": exc.description,
                            "error_code": code, "message": exc.description}
    headers = {}
    if exc.status == 401:
        headers["WWW-Authenticate"] = REALM
    if isinstance(exc, TooManyFailures):
        headers["Retry-After"] = str(exc.retry_after)
        body["parameters"] = {"retry_after": exc.retry_after}
    body.update(extra or {})
    return current_app.response_class(orjson.dumps(body), status=exc.status, mimetype="application/json",
                                      headers=headers)


def init_app(app: Flask) -> None:
    """The auth routes, and the check of every request (call after ``ratelimit.init_app``)."""
    from . import routes

    app.extensions[EXTENSION] = Auth(app.config["SOVD"])
    app.before_request(_check)
    app.register_error_handler(OAuthError, oauth_response)  # require_identity() in a route
    app.register_blueprint(routes.bp)
