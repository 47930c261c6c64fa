"""The audit trail's route (app/audit/doc.py) answers per the OpenAPI document: to the api_token, refused
without it, and to a signed-in operator; run by tests/app/openapi/test_app_openapi.py."""

from __future__ import annotations

from tests.app.openapi.answers import AUTH
from tests.support.fakeworker import make_app


def exercise(ex) -> None:
    ex.answer("GET", "/api/v1/x-medkit-audit?limit=2", headers=AUTH)
    ex.answer("GET", "/api/v1/x-medkit-audit?status=9xx", headers=AUTH)
    ex.answer("GET", "/api/v1/x-medkit-audit")  # 401
    secured = make_app(ex.fw, auth_enabled=True, jwt_secret="s" * 32, auth_clients="op:op-secret:operator",
                       auth_failure_limit="").test_client()
    granted = secured.post("/api/v1/auth/authorize", json={
        "grant_type": "client_credentials", "client_id": "op", "client_secret": "op-secret"}).get_json()
    ex.answer("GET", "/api/v1/x-medkit-audit", secured, headers={"Authorization": f"Bearer {granted['access_token']}"})
