"""CORS (flask-cors): an allowed origin, a disallowed one, a preflight, ``*``, and nothing when off.

The event streams' headers are checked through a real gateway in ``tests/test_fleet_e2e.py``.
"""

from __future__ import annotations

import pytest

from tests.support.fakeworker import ROBOT, FakeWorker, make_app

UI = "https://dashboard.example:8443"
CORS_HEADERS = ("Access-Control-Allow-Origin", "Access-Control-Allow-Credentials",
                "Access-Control-Allow-Methods", "Access-Control-Allow-Headers", "Access-Control-Expose-Headers")


@pytest.fixture(scope="module")
def fw():
    with FakeWorker() as worker:
        worker.set_graph(list(ROBOT))
        yield worker


@pytest.fixture(scope="module")
def client(fw):
    return make_app(fw, cors_origins=f"{UI},http://localhost:3000").test_client()


def test_an_allowed_origin_gets_its_origin_back_with_credentials(client):
    r = client.get("/api/v1/apps", headers={"Origin": UI})
    assert r.status_code == 200
    assert r.headers["Access-Control-Allow-Origin"] == UI
    assert r.headers["Access-Control-Allow-Credentials"] == "true"
    assert "Origin" in r.headers["Vary"]
    exposed = {h.strip().lower() for h in r.headers["Access-Control-Expose-Headers"].split(",")}
    assert {"x-request-id", "retry-after", "x-ratelimit-remaining"} <= exposed
    # Errors carry them too (a page must be able to read a 404 or a 429).
    r = client.get("/api/v1/apps/nope", headers={"Origin": UI})
    assert r.status_code == 404 and r.headers["Access-Control-Allow-Origin"] == UI


@pytest.mark.parametrize("origin", ["https://evil.example", "https://dashboard.example",  # other port
                                    "https://dashboard.example:8443.evil.example", "http://dashboard.example:8443",
                                    "null"])
def test_a_disallowed_origin_gets_no_cors_headers(client, origin):
    r = client.get("/api/v1/apps", headers={"Origin": origin})
    assert r.status_code == 200  # the browser, not the gateway, keeps the answer from the page
    assert not any(h in r.headers for h in CORS_HEADERS)


def test_a_preflight_allows_the_methods_and_headers_of_the_api(client):
    r = client.options("/api/v1/apps/controller/data/body/lights/cmd", headers={
        "Origin": UI, "Access-Control-Request-Method": "PUT",
        "Access-Control-Request-Headers": "Authorization, Content-Type"})
    assert r.status_code == 200
    assert r.headers["Access-Control-Allow-Origin"] == UI
    assert {m.strip() for m in r.headers["Access-Control-Allow-Methods"].split(",")} == {
        "GET", "PUT", "POST", "DELETE"}
    assert {h.strip().lower() for h in r.headers["Access-Control-Allow-Headers"].split(",")} == {
        "authorization", "content-type"}
    assert int(r.headers["Access-Control-Max-Age"]) > 0
    r = client.options("/api/v1/apps", headers={"Origin": "https://evil.example",
                                                 "Access-Control-Request-Method": "GET"})
    assert "Access-Control-Allow-Origin" not in r.headers


def test_any_origin_never_comes_with_credentials(fw):
    client = make_app(fw, cors_origins="*").test_client()
    r = client.get("/api/v1/apps", headers={"Origin": "https://anyone.example"})
    assert r.headers["Access-Control-Allow-Origin"] == "*"
    assert "Access-Control-Allow-Credentials" not in r.headers
    r = client.options("/api/v1/apps", headers={"Origin": "https://anyone.example",
                                                 "Access-Control-Request-Method": "DELETE"})
    assert r.headers["Access-Control-Allow-Origin"] == "*"
    assert "Access-Control-Allow-Credentials" not in r.headers


def test_off_by_default_no_cors_header_at_all(fw):
    client = make_app(fw).test_client()
    for r in (client.get("/api/v1/apps", headers={"Origin": UI}),
              client.options("/api/v1/apps", headers={"Origin": UI, "Access-Control-Request-Method": "GET"})):
        assert not any(h in r.headers for h in CORS_HEADERS), dict(r.headers)
