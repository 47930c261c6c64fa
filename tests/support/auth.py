"""Identities for the tests of issue 31: medkit's four roles as configured clients, and their tokens.

``ENV`` is what a gateway with authentication gets in its environment (secrets never go in flags);
``grant(gw, role)`` asks it for that role's tokens through ``POST /auth/authorize``.
"""

from __future__ import annotations

import requests

JWT_SECRET = "test-jwt-secret-that-is-long-enough-0123456789"
SECRETS = {"viewer": "viewer-secret-1", "operator": "operator-secret-2", "configurator": "configurator-secret-3",
           "admin": "admin-secret-4"}
ROLES = tuple(SECRETS)
ENV = {"SOVD_AUTH_CLIENTS": ",".join(f"{role}:{secret}:{role}" for role, secret in SECRETS.items()),
       "SOVD_JWT_SECRET": JWT_SECRET}


def grant(gw, role: str, **kw) -> dict:
    """The tokens of the client named after ``role`` (``access_token``, ``refresh_token`` ...)."""
    r = requests.post(gw.api + "/auth/authorize", json={"grant_type": "client_credentials", "client_id": role,
                                                        "client_secret": SECRETS[role]},
                      timeout=10, verify=gw.verify, **kw)
    assert r.status_code == 200, r.text
    return r.json()


def bearer(tokens: dict | str) -> dict[str, str]:
    token = tokens if isinstance(tokens, str) else tokens["access_token"]
    return {"Authorization": f"Bearer {token}"}
