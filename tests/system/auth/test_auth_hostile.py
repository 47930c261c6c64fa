"""Hostile input against every route of issue 31, through the real gateway: hypothesis makes the bodies
(JSON of any shape, forms, bytes, any content type), the headers (Authorization, X-Client-Id) and the
queries of ``/auth/authorize``, ``/auth/token``, ``/auth/revoke``, ``/auth/x-medkit-whoami``, the lock
routes and ``/x-medkit-audit``.

What must hold: every answer is a 4xx of the contract (a JSON body with ``error_code`` and a
message; OAuth2's ``error`` on the auth routes), never a 5xx; no secret or token comes back in an
answer; nothing is logged as an unhandled error; no HTTP or ROS worker restarts; nothing hostile
acquired a lock.
"""

from __future__ import annotations

import json

import pytest
import requests
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.auth import ENV, JWT_SECRET, SECRETS, bearer, grant
from tests.support.rospub import RosNode

APP = "hostile_auth_app"
EXAMPLES = 300
JSON = st.recursive(st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats(allow_nan=False)
                    | st.text(max_size=40), lambda inner: st.lists(inner, max_size=4)
                    | st.dictionaries(st.text(max_size=12), inner, max_size=4), max_leaves=12)
FIELDS = ("grant_type", "client_id", "client_secret", "refresh_token", "token", "scope", "lock_expiration",
          "scopes", "break_lock")
OBJECT = st.dictionaries(st.sampled_from(FIELDS) | st.text(max_size=10), JSON | st.sampled_from(
    ["client_credentials", "refresh_token", "admin", "operator", 60, 0, -1, 10**12, ["data"], ["nope"], True]),
    max_size=5)
TEXT = st.text(max_size=60)
HEADER = st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7e), max_size=80).map(str.strip)
CONTENT_TYPES = st.sampled_from(["application/json", "application/x-www-form-urlencoded", "text/plain",
                                 "application/json; charset=latin-1", "multipart/form-data", ""])


@pytest.fixture(scope="module")
def target():
    node = RosNode({"node": APP, "subscribe": [{"topic": "/hostile_auth/cmd", "type": "std_msgs/msg/String"}]})
    gw = Gateway("--auth-enabled", "--auth-failure-limit", "", "--workers", "2", "--log-level", "info", env=ENV)
    try:
        poll_until(lambda: APP in {a["id"] for a in gw.get("/apps").json()["items"]}, 30, message="the app listed")
        yield gw
    finally:
        gw.stop()
        node.stop()


def body_of(kind: str, value) -> tuple[bytes, str | None]:
    if kind == "json":
        return json.dumps(value).encode(), "application/json"
    if kind == "form":
        return "&".join(f"{k}={v}" for k, v in value.items()).encode("utf-8", "surrogatepass"), \
            "application/x-www-form-urlencoded"
    return value, None


REQUESTS = st.one_of(
    st.tuples(st.sampled_from(["POST"]), st.sampled_from(["/auth/authorize", "/auth/token", "/auth/revoke"]),
              st.one_of(st.tuples(st.just("json"), OBJECT | JSON), st.tuples(st.just("form"), OBJECT),
                        st.tuples(st.just("raw"), st.binary(max_size=200)))),
    st.tuples(st.sampled_from(["POST", "PUT", "DELETE", "GET"]),
              st.sampled_from([f"/apps/{APP}/locks", f"/apps/{APP}/locks/lock_1", "/components/x/locks",
                               f"/apps/{APP}/locks/%00", f"/apps/{APP}/locks/" + "l" * 300]),
              st.one_of(st.tuples(st.just("json"), OBJECT | JSON), st.tuples(st.just("raw"), st.binary(max_size=200)))),
)


def check(r: requests.Response, what: str) -> None:
    assert r.status_code < 500, (what, r.status_code, r.text[:300])
    if r.status_code >= 400:
        body = r.json()
        assert isinstance(body.get("error_code"), str) and isinstance(body.get("message"), str), (what, body)
    for secret in (*SECRETS.values(), JWT_SECRET):
        assert secret not in r.text, what


def test_hostile_requests_to_the_new_routes_get_clean_answers(target):
    gw = target
    before = {p.pid for p in gw.http_workers()} | {gw.rosworker_pid()}
    log_from = len(gw.output)
    session = requests.Session()
    admin = bearer(grant(gw, "admin"))

    @settings(max_examples=EXAMPLES, deadline=None, database=None, phases=[Phase.generate],
              suppress_health_check=list(HealthCheck))
    @given(request=REQUESTS, auth=st.one_of(st.none(), st.just("admin"), HEADER.map(lambda h: "Bearer " + h), HEADER),
           client=st.one_of(st.none(), HEADER), content_type=st.one_of(st.none(), CONTENT_TYPES))
    def fuzz(request, auth, client, content_type):
        method, path, (kind, value) = request
        data, declared = body_of(kind, value)
        headers = {}
        if declared or content_type is not None:
            headers["Content-Type"] = content_type if content_type is not None else declared
        if auth == "admin":
            headers.update(admin)
        elif auth is not None:
            headers["Authorization"] = auth
        if client is not None:
            headers["X-Client-Id"] = client
        r = session.request(method, gw.api + path, data=data if method != "GET" else None, headers=headers, timeout=20)
        check(r, f"{method} {path} {headers} {data[:100]!r}")
        if r.status_code == 201:  # an admin's well-formed acquire: release it, the next example starts clean
            owner = {**headers}
            assert session.delete(gw.api + f"/apps/{APP}/locks/{r.json()['id']}", headers=owner, timeout=20).status_code == 204

    fuzz()

    @settings(max_examples=EXAMPLES, deadline=None, database=None, phases=[Phase.generate],
              suppress_health_check=list(HealthCheck))
    @given(query=st.dictionaries(st.sampled_from(["client_id", "address", "method", "family", "collection", "entity_id",
                                                  "request_id", "status", "since", "until", "limit", "before"])
                                 | TEXT, TEXT | st.integers(-2**70, 2**70).map(str), max_size=5),
           auth=st.sampled_from(["admin", "none", "junk"]))
    def audit(query, auth):
        headers = admin if auth == "admin" else {} if auth == "none" else {"Authorization": "Bearer junk"}
        r = session.get(gw.api + "/x-medkit-audit", params=query, headers=headers, timeout=20)
        check(r, f"audit {query}")
        if auth != "admin":
            assert r.status_code == 401
        r = session.get(gw.api + "/auth/x-medkit-whoami", headers=headers, timeout=20)
        check(r, "whoami")

    audit()
    assert gw.proc.poll() is None
    assert {p.pid for p in gw.http_workers()} | {gw.rosworker_pid()} == before, "a worker restarted"
    log = "\n".join(gw.output[log_from:])
    for marker in ("Traceback", "Unhandled error", "[CRITICAL]"):
        assert marker not in log, f"{marker!r} in the gateway's log:\n{log[-3000:]}"
    assert gw.get(f"/apps/{APP}/locks").json()["items"] == []
