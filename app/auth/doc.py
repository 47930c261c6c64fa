"""The OpenAPI part of identities and roles: the ``/auth`` routes (medkit's operationIds and
schema names, ``ros2_medkit_clients``' spec), and what authentication, roles and locks add to every
operation (:func:`secure`: one place, as the checks themselves are one place).
"""

from __future__ import annotations

from copy import deepcopy
from typing import Any

from ..openapi import build as oa
from .roles import ACTIONS

TAG = {"name": "Authentication", "description": "OAuth2 client credentials and JWTs (medkit's four roles)"}

AUTH_401 = ("A token is needed (authentication on and `require_auth_for`, or the legacy `api_token`) and "
            "the request has none, or a bad, expired or revoked one (`unauthorized`; OAuth2 `error` "
            "`invalid_token` and `error_description`; `WWW-Authenticate: Bearer`)")
AUTH_403 = "The token's role may not do this (`forbidden`; OAuth2 `error` `insufficient_scope`)"
LOCK_409 = ("Another client holds a lock on the entity (or its component) whose scopes cover this "
            "collection (`lock-broken`, parameters `entity_id`, `collection`, `lock_id`)")
AUTH_403_LOWER = AUTH_403[0].lower() + AUTH_403[1:]
_STALE = (" or the token is wrong (`forbidden`)", ", a wrong API token (`forbidden`),", ", or the API token is wrong "
          "(`forbidden`)")

SCHEMAS: dict[str, Any] = {
    "AuthCredentials": {**oa.obj(["grant_type"], grant_type={"enum": ["client_credentials", "refresh_token"]},
                                  client_id=oa.STR, client_secret=oa.STR, refresh_token=oa.STR, scope=oa.STR),
                        "description": "medkit's AuthorizeRequest, as JSON or application/x-www-form-urlencoded "
                                       "(medkit's spec names username and password; its code reads these)"},
    "AuthTokenResponse": oa.obj(["access_token", "token_type", "expires_in", "refresh_token", "scope"],
                                 access_token=oa.STR, token_type={"const": "Bearer"}, expires_in=oa.INT,
                                 refresh_token=oa.STR, scope={"enum": ["viewer", "operator", "configurator", "admin"]}),
    "AuthRevokeRequest": oa.obj(["token"], token=oa.STR),
    "AuthRevokeResponse": oa.obj(["status"], status={"const": "revoked"}),
    "AuthWhoAmI": oa.obj(["client_id", "role", "expires_at", "require_auth_for", "may"], client_id=oa.STR,
                          role=oa.STR, expires_at={"type": ["integer", "null"]},
                          require_auth_for={"enum": ["none", "write", "all"]},
                          may=oa.obj([key for key, *_ in ACTIONS], **{key: {"type": "boolean"}
                                                                       for key, *_ in ACTIONS})),
}


def _oauth(description: str) -> dict[str, Any]:
    """An error of the auth routes: medkit's OAuth2 body (``error``, ``error_description``), which also
    holds the gateway's ``error_code`` and ``message``, so it is a GenericError too."""
    return oa.error(description + "; the body is OAuth2's (`error`, `error_description`) with `error_code` "
                                   "and `message` beside it")


def paths() -> dict[str, Any]:
    body = {"required": True, "content": {
        "application/json": {"schema": oa.ref("AuthCredentials")},
        "application/x-www-form-urlencoded": {"schema": oa.ref("AuthCredentials")}}}
    off = _oauth("Authentication is not enabled (`resource-not-found`)")
    bad = _oauth("A field missing or not a string, a body that is not JSON or a form, an unknown grant "
                 "(`invalid_request`, `unsupported_grant_type`)")

    def grant(op_id: str, summary: str, refused: str) -> dict[str, Any]:
        op = oa.op(op_id, "Authentication", summary, oa.ok("AuthTokenResponse"), "408", "413", requestBody=body)
        op["responses"].update({"400": bad, "401": _oauth(refused), "404": off, "429": _oauth(
            "Too many failed authorizations from this address (`rate-limit-exceeded`, OAuth2 `access_denied`); "
            "retry after `Retry-After` seconds")})
        return op

    revoke = oa.op("revokeToken", "Authentication", "Revoke a token (answered the same whether it was good)",
                    oa.ok("AuthRevokeResponse"), "408", "413", requestBody={"required": True, "content": {
                        "application/json": {"schema": oa.ref("AuthRevokeRequest")}}})
    revoke["responses"].update({"400": _oauth("No `token`, or a body that is not JSON (`invalid_request`)"),
                                "404": off, "500": _oauth("The revocation could not be stored (`server_error`)")})
    whoami = oa.op("getAuthWhoAmI", "Authentication", "Who the bearer token is, and what its role may do",
                    oa.ok("AuthWhoAmI"), security=[{"bearerAuth": []}])
    whoami["responses"].update({"401": _oauth("No token, or a bad one (`invalid_token`)"), "404": off})
    return {
        "/auth/authorize": {"post": grant("authorize", "OAuth2 client credentials: an access and a refresh token",
                                          "Unknown client or wrong secret (`invalid_client`)")},
        "/auth/token": {"post": grant("getToken", "A new access token for a refresh token (which stays valid)",
                                      "A bad, expired or revoked refresh token (`invalid_grant`)")},
        "/auth/revoke": {"post": revoke},
        "/auth/x-medkit-whoami": {"get": whoami},
    }


def amend(schemas: dict[str, Any]) -> None:
    """What authentication and TLS add to the overview, and the OAuth2 fields of a 401, a 403 and the
    auth routes' errors (medkit's ``error`` and ``error_description``) to the GenericError."""
    error = schemas["GenericError"] = deepcopy(schemas["GenericError"])
    error["properties"].update(
        error={"type": "string", "description": "OAuth2's error (401, 403 of the token and role checks, the "
                                                "/auth routes): invalid_token, insufficient_scope, invalid_client …"},
        error_description={"type": "string", "description": "OAuth2's text of it (the same as `message`)"})
    overview = schemas["RootOverview"]
    overview["properties"]["auth"] = oa.obj(["enabled", "algorithm", "require_auth_for"], enabled={"const": True},
                                             algorithm={"enum": ["HS256", "RS256"]},
                                             require_auth_for={"enum": ["none", "write", "all"]})
    overview["properties"]["tls"] = oa.obj(["enabled", "min_version"], enabled={"const": True},
                                            min_version={"enum": ["1.2", "1.3"]})


def secure(paths: dict[str, Any], lock_scopes: tuple[str, ...]) -> None:
    """Every operation may be refused by the token check (401) and the role check (403) (under
    ``require_auth_for=all`` a read too); every write of a lock scope's collection by a lock (409)."""
    for path, ops in paths.items():
        if path.startswith("/auth/"):
            continue
        segments = path.split("/")
        family = segments[3] if len(segments) > 3 and segments[1] in ("apps", "components", "functions", "areas") \
            else segments[1]
        for method, op in ops.items():
            responses = op["responses"]
            responses["401"] = oa.error(AUTH_401)
            text = responses["403"]["description"] if "403" in responses else ""
            if text.startswith("An API token is configured"):
                text = ""
            for cut in _STALE:  # what a wrong legacy token was answered before: 401 now, as in medkit
                text = text.replace(cut, "")
            responses["403"] = oa.error(f"{text}; or {AUTH_403_LOWER}" if text else AUTH_403)
            if method in ("post", "put", "delete") and family in lock_scopes:
                old409 = responses.get("409")
                responses["409"] = oa.error(LOCK_409 + (f"; {old409['description']}" if old409 else ""))
            op.setdefault("security", [{"bearerAuth": []}, {}])
