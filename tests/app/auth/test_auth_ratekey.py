"""The rate limiter keys on the token's client id when a request carries a good token, else on the
address (app/ratelimit.py with app/auth's rate_key): two clients behind one address have a bucket
each, and a bad token is counted as its address."""

from __future__ import annotations

import pytest

from tests.support.auth import ENV, SECRETS
from tests.support.fakeworker import make_app

pytestmark = pytest.mark.fakeworker()
AUTH = {"auth_enabled": True, "auth_clients": ENV["SOVD_AUTH_CLIENTS"], "jwt_secret": ENV["SOVD_JWT_SECRET"]}


def test_each_client_has_its_own_bucket_behind_one_address(fw):
    issuer = make_app(fw, **AUTH).test_client()   # the tokens: signed, so good for any app with the secret

    def token(role: str) -> dict:
        granted = issuer.post("/api/v1/auth/authorize", json={"grant_type": "client_credentials", "client_id": role,
                                                                "client_secret": SECRETS[role]})
        return {"Authorization": f"Bearer {granted.get_json()['access_token']}"}

    viewer, operator = token("viewer"), token("operator")
    client = make_app(fw, **AUTH, rate_limit="0.001/2").test_client()   # 2 requests, then (nearly) none
    for expected in (200, 200, 429):
        assert client.get("/api/v1/apps", headers=viewer).status_code == expected
    for expected in (200, 200, 429):   # another client from the same address: a bucket of its own
        assert client.get("/api/v1/apps", headers=operator).status_code == expected
    for expected in (200, 200, 429):   # no token: the address's bucket, untouched until now
        assert client.get("/api/v1/apps").status_code == expected
    r = client.get("/api/v1/apps", headers={"Authorization": "Bearer not-a-token"})
    assert r.status_code == 429 and r.get_json()["parameters"]["scope"] == "client"   # counted as its address
