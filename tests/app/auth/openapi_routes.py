"""The auth routes (app/auth/doc.py) answer per the OpenAPI document: off on the exercise's app (404), on in
an app of their own; run by tests/app/openapi/test_app_openapi.py."""

from __future__ import annotations

from tests.app.openapi.answers import AUTH
from tests.support.fakeworker import make_app


def exercise(ex) -> None:
    for path in ("/api/v1/auth/authorize", "/api/v1/auth/token", "/api/v1/auth/revoke"):
        ex.answer("POST", path, json={})
    ex.answer("GET", "/api/v1/auth/x-medkit-whoami", headers=AUTH)
    ex.answer("GET", "/api/v1/auth/x-medkit-whoami")
    client = make_app(ex.fw, auth_enabled=True, jwt_secret="s" * 32, auth_clients="op:op-secret:operator",
                      auth_failure_limit="").test_client()  # one client: op, an operator
    granted = ex.answer("POST", "/api/v1/auth/authorize", client, json={
        "grant_type": "client_credentials", "client_id": "op", "client_secret": "op-secret"}).get_json()
    ex.answer("POST", "/api/v1/auth/authorize", client,
              data="grant_type=client_credentials&client_id=op&client_secret=no",
              content_type="application/x-www-form-urlencoded")
    ex.answer("POST", "/api/v1/auth/authorize", client, json={"grant_type": "password"})
    ex.answer("POST", "/api/v1/auth/token", client, json={"grant_type": "refresh_token",
                                                          "refresh_token": granted["refresh_token"]})
    ex.answer("POST", "/api/v1/auth/token", client, json={"grant_type": "refresh_token", "refresh_token": "no"})
    ex.answer("GET", "/api/v1/auth/x-medkit-whoami", client,
              headers={"Authorization": f"Bearer {granted['access_token']}"})
    ex.answer("POST", "/api/v1/auth/revoke", client, json={"token": granted["refresh_token"]})
    ex.answer("POST", "/api/v1/auth/revoke", client, data=b"{", content_type="application/json")
