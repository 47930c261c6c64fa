"""Tokens: OAuth2 client credentials in, JWTs out (PyJWT), and the check of each bearer token.

As medkit's ``AuthManager`` (``core/auth/auth_manager.cpp``), which its clients are written against:

- ``POST /auth/authorize`` (client credentials): a refresh token (``typ: refresh`` in the JWT
  header, ``refresh_token_expiry_seconds``) and an access token (``typ: access``,
  ``token_expiry_seconds``, a ``refresh_token_id`` claim naming its refresh token).  Claims:
  ``iss`` (``auth_issuer``), ``sub`` (the client id), ``iat``, ``exp``, ``jti`` (a random id) and
  ``role``.  The answer: ``{access_token, token_type: "Bearer", expires_in, refresh_token,
  scope: <role>}``.
- ``POST /auth/token`` (``grant_type=refresh_token``): a new access token; the refresh token stays
  valid and comes back unchanged (medkit's code; its tutorial calls refresh tokens single-use).
- A bearer token is good when its signature, algorithm (only the configured one: ``alg: none``
  and an RS256/HS256 swap are refused by PyJWT's ``algorithms`` list), issuer, expiry and type
  check out, its client is still configured, and neither it nor its refresh token is revoked.
- Revoking (``POST /auth/revoke``) records the token's id until its expiry (``revocations.py``);
  a revoked refresh token takes every access token made from it along.  medkit revokes refresh
  tokens only; an access token given here is revoked too.

Refresh tokens are not kept anywhere: one is good for as long as it is signed, unexpired and not
revoked, so it outlives a gateway restart (medkit forgets its refresh tokens at a restart).

Checks are cheap on the hot path: a token that checked out is remembered by its full text (never by
its id alone: a tampered token shares the id) until it expires, so each later request costs a
dictionary look-up and a look at the revocations.  Client secrets are compared in constant time,
and an unknown client id costs the same comparison.
"""

from __future__ import annotations

import hmac
import os
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jwt

from common.settings import Client, parse_clients

from .revocations import Revocations

LEGACY_CLIENT = "(api-token)"   # who the legacy api_token is: an admin, never a configured client id
CACHE_MAX = 10000               # checked tokens remembered per HTTP worker
_REQUIRED = ("exp", "iat", "iss", "sub", "jti")


class OAuthError(Exception):
    """An answer of the auth routes or of the bearer check: medkit's OAuth2 ``error`` and its text."""

    def __init__(self, status: int, error: str, description: str):
        super().__init__(description)
        self.status = status
        self.error = error
        self.description = description


@dataclass(frozen=True, slots=True)
class Identity:
    client_id: str
    role: str
    jti: str | None = None            # None: the legacy api_token
    refresh_jti: str | None = None    # the refresh token an access token was made from
    expires_at: float = float("inf")  # Unix time

    @property
    def legacy(self) -> bool:
        return self.jti is None


@dataclass(frozen=True, slots=True)
class Grant:
    client_id: str
    answer: dict[str, Any]   # the tokens, as the client gets them


class TokenService:
    """The clients, the keys and the token cache of one HTTP worker."""

    def __init__(self, cfg, revocations: Revocations):
        self.algorithm = cfg.jwt_algorithm
        self.issuer = cfg.auth_issuer
        self.expiry = cfg.token_expiry_seconds
        self.refresh_expiry = cfg.refresh_token_expiry_seconds
        self.enabled = bool(cfg.auth_enabled)
        self.clients: dict[str, Client] = {c.client_id: c for c in parse_clients(cfg.auth_clients)} \
            if self.enabled else {}
        self.legacy_token = cfg.api_token.encode("utf-8") if cfg.api_token else b""
        self.revocations = revocations
        self._cache: dict[str, Identity] = {}
        self._dummy_secret = os.urandom(32)
        self._sign_key: Any = None
        self._verify_key: Any = None
        if self.enabled:
            self._sign_key, self._verify_key = _keys(cfg)

    # ---- issuing --------------------------------------------------------------------------------
    def authorize(self, client_id: str, secret: str) -> Grant:
        client = self.clients.get(client_id)
        expected = client.secret.encode("utf-8") if client else self._dummy_secret
        good = hmac.compare_digest(secret.encode("utf-8", "surrogateescape"), expected)
        if client is None:
            raise OAuthError(401, "invalid_client", "Unknown client_id")
        if not good:
            raise OAuthError(401, "invalid_client", "Invalid client_secret")
        refresh_jti = _token_id()
        now = int(time.time())
        refresh = self._sign({"sub": client.client_id, "iat": now, "exp": now + self.refresh_expiry,
                              "jti": refresh_jti, "role": client.role}, "refresh")
        return self._answer(client.client_id, client.role, refresh_jti, refresh, now)

    def refresh(self, refresh_token: str) -> Grant:
        claims = self._checked(refresh_token, "refresh", "invalid_grant")
        if claims["jti"] in self.revocations.current():
            raise OAuthError(401, "invalid_grant", "Refresh token has been revoked")
        client = self.clients.get(claims["sub"])
        if client is None:
            raise OAuthError(401, "invalid_grant", "Client no longer exists")
        return self._answer(client.client_id, claims["role"], claims["jti"], refresh_token, int(time.time()))

    def _answer(self, client_id: str, role: str, refresh_jti: str, refresh: str, now: int) -> Grant:
        access = self._sign({"sub": client_id, "iat": now, "exp": now + self.expiry, "jti": _token_id(),
                             "role": role, "refresh_token_id": refresh_jti}, "access")
        return Grant(client_id, {"access_token": access, "token_type": "Bearer", "expires_in": self.expiry,
                                 "refresh_token": refresh, "scope": role})

    def _sign(self, claims: dict[str, Any], typ: str) -> str:
        return jwt.encode({"iss": self.issuer, **claims}, self._sign_key, algorithm=self.algorithm,
                          headers={"typ": typ})

    # ---- checking ---------------------------------------------------------------------------------
    def identify(self, token: str, gate: Callable[[], None] | None = None) -> Identity:
        """The identity of a bearer token, or :class:`OAuthError` (401 ``invalid_token``) saying why.

        ``gate`` is called before a token not checked before is compared with any secret (the
        failure limit, which raises to refuse); a remembered good token passes without it.
        """
        identity = self._cache.get(token)
        if identity is None:
            if gate is not None:
                gate()
            if self.legacy_token and hmac.compare_digest(token.encode("utf-8", "surrogateescape"),
                                                         self.legacy_token):
                identity = self._cache[token] = Identity(LEGACY_CLIENT, "admin")
                return identity
            if not self.enabled:
                raise OAuthError(401, "invalid_token", "Invalid API token")
            identity = self._verify(token)
        elif identity.expires_at <= time.time():
            self._cache.pop(token, None)
            raise OAuthError(401, "invalid_token", "Token has expired")
        revoked = self.revocations.current()
        if identity.jti in revoked:
            raise OAuthError(401, "invalid_token", "Token has been revoked")
        if identity.refresh_jti in revoked:
            raise OAuthError(401, "invalid_token", "Associated refresh token has been revoked")
        return identity

    def _verify(self, token: str) -> Identity:
        claims = self._checked(token, "access", "invalid_token")
        if claims["sub"] not in self.clients:
            raise OAuthError(401, "invalid_token", "Client no longer exists")
        refresh_jti = claims.get("refresh_token_id")
        identity = Identity(claims["sub"], claims["role"], claims["jti"],
                            refresh_jti if isinstance(refresh_jti, str) else None, float(claims["exp"]))
        if len(self._cache) >= CACHE_MAX:
            now = time.time()
            self._cache = {k: v for k, v in self._cache.items() if v.expires_at > now}
            if len(self._cache) >= CACHE_MAX:
                self._cache.clear()
        self._cache[token] = identity
        return identity

    def _checked(self, token: str, typ: str, error: str) -> dict[str, Any]:
        """The claims of a good token of type ``typ``, or :class:`OAuthError` (401 ``error``) saying
        why not, in medkit's words."""
        try:
            header, claims = self._decode(token)
        except jwt.ExpiredSignatureError:
            raise OAuthError(401, error, "Refresh token has expired" if typ == "refresh"
                             else "Token has expired") from None
        except jwt.InvalidTokenError as exc:
            raise OAuthError(401, error, f"Token verification failed: {_reason(exc)}") from None
        if header.get("typ") != typ:
            raise OAuthError(401, error, "Token is not a refresh token" if typ == "refresh"
                             else f"Invalid token type: expected access, got {str(header.get('typ'))[:20]}")
        return claims

    def _decode(self, token: str) -> tuple[dict[str, Any], dict[str, Any]]:
        """The verified header and claims (raises PyJWT's errors)."""
        decoded = jwt.api_jwt.decode_complete(token, self._verify_key, algorithms=[self.algorithm],
                                              issuer=self.issuer, options={"require": list(_REQUIRED)})
        claims = decoded["payload"]
        for name in ("sub", "jti"):
            if not isinstance(claims.get(name), str) or not claims[name]:
                raise jwt.InvalidTokenError(f"the {name} claim is not a string")
        if claims.get("role") not in ("viewer", "operator", "configurator", "admin"):
            raise jwt.InvalidTokenError("the role claim is not a role")
        return decoded["header"], claims

    # ---- revoking ---------------------------------------------------------------------------------
    def revoke(self, token: str) -> None:
        """Record the token's id (a token that does not check out, or has expired, needs nothing)."""
        try:
            _header, claims = self._decode(token)
        except jwt.InvalidTokenError:
            return
        self.revocations.add(claims["jti"], int(claims["exp"]))


def _token_id() -> str:
    return str(uuid.uuid4())


def _reason(exc: Exception) -> str:
    """PyJWT's reason, short (never the token: PyJWT's messages do not quote it)."""
    return (str(exc) or type(exc).__name__)[:200]


def _keys(cfg) -> tuple[Any, Any]:
    """The signing and the verifying key: the HS256 secret twice, or RS256's key pair from its files."""
    if cfg.jwt_algorithm == "HS256":
        return cfg.jwt_secret, cfg.jwt_secret
    from cryptography.hazmat.primitives import serialization

    with open(cfg.jwt_secret, "rb") as fh:
        private = serialization.load_pem_private_key(fh.read(), password=None)
    with open(cfg.jwt_public_key, "rb") as fh:
        public = serialization.load_pem_public_key(fh.read())
    return private, public
