"""Tokens through the real gateway: expired, tampered, wrong-algorithm (``alg: none``, an RS256/HS256
swap), wrong issuer and revoked tokens are refused; a refresh token is used twice; a revoked refresh
token takes its access tokens along; both HTTP workers and a restarted gateway agree on a
revocation; failed authorizations are limited per address; no secret shows in a command line.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import os
import time

import jwt
import psutil
import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.auth import ENV, JWT_SECRET, SECRETS, bearer, grant

OP = "/apps/nope/operations/x/executions"   # an operator's write: allowed, then 404 (no such app)


def b64(data: bytes) -> str:
    return base64.urlsafe_b64encode(data).rstrip(b"=").decode()


def forged(header: dict, claims: dict, key: bytes | None) -> str:
    """A JWT made by hand: ``key`` None leaves the signature empty (``alg: none``)."""
    head = b64(json.dumps(header).encode()) + "." + b64(json.dumps(claims).encode())
    signature = b"" if key is None else hmac.new(key, head.encode(), hashlib.sha256).digest()
    return head + "." + b64(signature)


def claims(role: str = "admin", **extra) -> dict:
    now = int(time.time())
    return {"iss": "sovd_gateway", "sub": role, "iat": now, "exp": now + 600, "jti": f"forged-{now}", "role": role,
            **extra}


def refused(gw, token: str, reason: str) -> None:
    r = gw.request("POST", OP, json={}, headers=bearer(token))
    assert r.status_code == 401, (reason, r.status_code, r.text)
    assert r.json()["error"] == "invalid_token" and r.headers["WWW-Authenticate"].startswith("Bearer"), reason


def accepted(gw, token: str) -> bool:
    return gw.request("POST", OP, json={}, headers=bearer(token)).status_code == 404


@pytest.fixture(scope="module")
def state_dir(tmp_path_factory):
    return str(tmp_path_factory.mktemp("auth-state"))


@pytest.fixture(scope="module")
def gw(state_dir, gateway):
    return gateway("--auth-enabled", "--allow-operations", "--workers", "2", "--debug-commands", "--state-dir", state_dir,
                   "--token-expiry-seconds", "600", env={**ENV, "SOVD_API_TOKEN": "legacy-admin-token-0123456789"})


def test_a_good_token_is_accepted_and_forged_ones_are_not(gw):
    good = grant(gw, "operator")["access_token"]
    assert accepted(gw, good)
    head, body, signature = good.split(".")
    tampered_body = b64(json.dumps({**jwt.decode(good, options={"verify_signature": False}), "role": "admin"}).encode())
    refused(gw, f"{head}.{tampered_body}.{signature}", "tampered claims")
    refused(gw, f"{head}.{body}.{signature[:-4]}AAAA", "tampered signature")
    refused(gw, forged({"alg": "none", "typ": "access"}, claims(), None), "alg none")
    refused(gw, forged({"alg": "HS256", "typ": "access"}, claims(), b"a guessed secret of some length, wrong"),
            "another secret")
    refused(gw, forged({"alg": "HS256", "typ": "access"}, claims(iss="someone-else"), JWT_SECRET.encode()), "issuer")
    refused(gw, forged({"alg": "HS256", "typ": "access"}, claims(sub="mallory", role="admin"), JWT_SECRET.encode()),
            "a client that is not configured")
    refused(gw, grant(gw, "operator")["refresh_token"], "a refresh token as the bearer")
    refused(gw, "legacy-admin-token-012345678", "one byte short of the legacy token")
    assert accepted(gw, "legacy-admin-token-0123456789")  # the legacy api_token: an admin's credential


def test_a_refresh_token_works_again_and_returns_itself(gw):
    first = grant(gw, "operator")
    for _ in range(2):
        r = requests.post(gw.api + "/auth/token", json={"grant_type": "refresh_token",
                                                        "refresh_token": first["refresh_token"]}, timeout=10)
        assert r.status_code == 200, r.text
        again = r.json()
        assert again["refresh_token"] == first["refresh_token"] and again["scope"] == "operator"
        assert again["access_token"] != first["access_token"] and accepted(gw, again["access_token"])
    r = requests.post(gw.api + "/auth/token", data={"grant_type": "refresh_token", "refresh_token": "x.y.z"}, timeout=10)
    assert r.status_code == 401 and r.json()["error"] == "invalid_grant"


def test_a_revoked_refresh_token_takes_its_access_tokens_along_in_both_workers(gw):
    tokens = grant(gw, "operator")
    refreshed = requests.post(gw.api + "/auth/token", json={"grant_type": "refresh_token",
                                                            "refresh_token": tokens["refresh_token"]}, timeout=10).json()
    sessions = gw.worker_sessions()
    for session in sessions.values():  # each worker has checked (and remembers) both access tokens
        for token in (tokens["access_token"], refreshed["access_token"]):
            assert session.post(gw.api + OP, json={}, headers=bearer(token), timeout=10).status_code == 404
    first, second = sessions.values()
    r = first.post(gw.api + "/auth/revoke", json={"token": tokens["refresh_token"]}, timeout=10)
    assert r.status_code == 200 and r.json() == {"status": "revoked"}
    for session in (second, first):   # the other worker refuses them at once: the revoke was answered
        for token in (tokens["access_token"], refreshed["access_token"]):
            r = session.post(gw.api + OP, json={}, headers=bearer(token), timeout=10)
            assert r.status_code == 401, r.text
            assert r.json()["error_description"] == "Associated refresh token has been revoked"
    r = second.post(gw.api + "/auth/token", json={"grant_type": "refresh_token",
                                                  "refresh_token": tokens["refresh_token"]}, timeout=10)
    assert r.status_code == 401 and r.json() == {**r.json(), "error": "invalid_grant",
                                                 "error_description": "Refresh token has been revoked"}
    # revoking an access token alone: that token only
    other = grant(gw, "operator")
    sibling = requests.post(gw.api + "/auth/token", json={"grant_type": "refresh_token",
                                                          "refresh_token": other["refresh_token"]}, timeout=10).json()
    assert second.post(gw.api + "/auth/revoke", json={"token": other["access_token"]}, timeout=10).status_code == 200
    r = first.post(gw.api + OP, json={}, headers=bearer(other["access_token"]), timeout=10)
    assert r.status_code == 401 and r.json()["error_description"] == "Token has been revoked"
    assert first.post(gw.api + OP, json={}, headers=bearer(sibling["access_token"]), timeout=10).status_code == 404
    # a token that is not one of ours: the same answer (RFC 7009), nothing recorded
    assert first.post(gw.api + "/auth/revoke", json={"token": "garbage"}, timeout=10).json() == {"status": "revoked"}
    for session in sessions.values():
        session.close()


def test_revocations_survive_a_restart_of_the_gateway(gw, state_dir):
    kept, revoked = grant(gw, "configurator"), grant(gw, "configurator")
    assert requests.post(gw.api + "/auth/revoke", json={"token": revoked["access_token"]}, timeout=10).status_code == 200
    second = Gateway("--auth-enabled", "--allow-operations", "--state-dir", state_dir, env=ENV)
    try:
        refused(second, revoked["access_token"], "revoked before the restart")
        assert accepted(second, kept["access_token"])  # signed with the same secret: still good
        r = requests.post(second.api + "/auth/token", json={"grant_type": "refresh_token",
                                                            "refresh_token": kept["refresh_token"]}, timeout=10)
        assert r.status_code == 200  # medkit forgets refresh tokens at a restart; these are signed, not stored
    finally:
        second.stop()


def test_an_expired_token_is_refused():
    gateway = Gateway("--auth-enabled", "--allow-operations", "--token-expiry-seconds", "1", "--refresh-token-expiry-seconds", "2", env=ENV)
    try:
        tokens = grant(gateway, "operator")
        assert accepted(gateway, tokens["access_token"])   # remembered now: its expiry is checked on each use
        poll_until(lambda: gateway.request("POST", OP, json={}, headers=bearer(tokens)).status_code == 401, 10,
                   message="the access token refused once expired")
        r = gateway.request("POST", OP, json={}, headers=bearer(tokens))
        assert r.json()["error_description"] == "Token has expired"

        def refresh_refused() -> bool:
            r = requests.post(gateway.api + "/auth/token", json={"grant_type": "refresh_token",
                                                                 "refresh_token": tokens["refresh_token"]}, timeout=10)
            return r.status_code == 401 and r.json()["error_description"] == "Refresh token has expired"

        poll_until(refresh_refused, 10, message="the refresh token refused once expired")
    finally:
        gateway.stop()


def test_rs256_tokens_and_the_hs256_swap(tmp_path):
    """RS256 with a key pair made here; an HS256 token signed with the public key (the classic
    confusion) is refused, as is an RS256 token of another key."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import rsa

    def pair(name: str):
        key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
        private = tmp_path / f"{name}.pem"
        public = tmp_path / f"{name}.pub.pem"
        private.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                              serialization.NoEncryption()))
        public.write_bytes(key.public_key().public_bytes(serialization.Encoding.PEM,
                                                         serialization.PublicFormat.SubjectPublicKeyInfo))
        return key, private, public

    _, private, public = pair("gateway")
    stranger, _, _ = pair("stranger")
    gateway = Gateway("--auth-enabled", "--allow-operations", "--jwt-algorithm", "RS256", "--jwt-public-key", str(public),
                      env={**ENV, "SOVD_JWT_SECRET": str(private)})
    try:
        tokens = grant(gateway, "operator")
        assert jwt.get_unverified_header(tokens["access_token"])["alg"] == "RS256"
        assert accepted(gateway, tokens["access_token"])
        refused(gateway, forged({"alg": "HS256", "typ": "access"}, claims(), public.read_bytes()), "RS/HS swap")
        refused(gateway, forged({"alg": "none", "typ": "access"}, claims(), None), "alg none")
        refused(gateway, jwt.encode(claims(), stranger, algorithm="RS256", headers={"typ": "access"}), "another key")
    finally:
        gateway.stop()


def test_failed_authorizations_are_limited_per_address():
    gateway = Gateway("--auth-enabled", "--allow-operations", "--auth-failure-limit", "0.05/3", "--workers", "1",
                      env=ENV)
    try:
        good = grant(gateway, "operator")
        assert accepted(gateway, good["access_token"])  # checked once: remembered by the (one) HTTP worker
        wrong = {"grant_type": "client_credentials", "client_id": "operator", "client_secret": "guess"}
        for _ in range(3):
            r = requests.post(gateway.api + "/auth/authorize", json=wrong, timeout=10)
            assert r.status_code == 401 and r.json()["error"] == "invalid_client"
        r = requests.post(gateway.api + "/auth/authorize", json=wrong, timeout=10)
        assert r.status_code == 429 and int(r.headers["Retry-After"]) >= 1
        assert r.json()["error_code"] == "rate-limit-exceeded"
        # while the address is out of failures, no secret is compared: the right one is refused too,
        r = requests.post(gateway.api + "/auth/authorize", json={**wrong, "client_secret": SECRETS["operator"]}, timeout=10)
        assert r.status_code == 429
        # and so is a bearer token never seen, but one checked before still works
        assert gateway.request("POST", OP, json={}, headers=bearer("some.guessed.token")).status_code == 429
        assert accepted(gateway, good["access_token"])
    finally:
        gateway.stop()


def test_no_secret_is_on_a_command_line(gw):
    """Secrets come from the environment or the config file: ps shows none of them."""
    procs = [psutil.Process(gw.pid), *psutil.Process(gw.pid).children(recursive=True)]
    assert len(procs) >= 4  # supervisor, ROS worker, gunicorn and its workers
    for proc in procs:
        line = " ".join(proc.cmdline())
        for secret in (*SECRETS.values(), JWT_SECRET, "legacy-admin-token-0123456789"):
            assert secret not in line, (proc.pid, line)
    assert os.environ.get("SOVD_JWT_SECRET") is None  # (the test's own environment passed nothing on)
