"""CORS (flask-cors): an allowed origin, a disallowed one, a preflight, ``*``, and nothing when off.

The event streams' headers are checked through a real gateway in ``tests/system/fleet/test_fleet_e2e.py``.
"""

from __future__ import annotations

import pytest
import requests

from tests.support.fakeworker import make_app

UI = "https://dashboard.example:8443"
CORS_HEADERS = ("Access-Control-Allow-Origin", "Access-Control-Allow-Credentials",
                "Access-Control-Allow-Methods", "Access-Control-Allow-Headers", "Access-Control-Expose-Headers")

pytestmark = pytest.mark.fakeworker(scope="module", client_scope="module",
                                    cors_origins=f"{UI},http://localhost:3000")


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


IPV6_UI = "http://[fd00::10]:8443"
# Origins that a pattern made of IPV6_UI would let in (a character class, a prefix), and neighbours.
NOT_IPV6_UI = ["http://d:8443", "http://0:8443", "http://f:8443", "http://[fd00::10]:84430",
               "http://[fd00::1]:8443", "https://[fd00::10]:8443", "http://[fd00::10]"]


def test_an_ipv6_origin_is_an_exact_origin_not_a_pattern():
    """Issue 18, defect 6: flask-cors read ``[fd00::10]`` as a regular expression's character class.

    Through a real gateway: the configured IPv6 origin (as a browser writes it, and
    as configured in another spelling) gets the CORS headers on a request and a
    preflight; ``http://d:8443``, ``http://0:8443`` and the other neighbours get none.
    """
    from common.harness.gateway import Gateway

    gw = Gateway("--cors-origins", f"http://[FD00:0::10]:8443,{UI}")  # another spelling of IPV6_UI
    try:
        for origin in (IPV6_UI, UI):
            r = gw.get("/apps", headers={"Origin": origin})
            assert r.status_code == 200
            assert r.headers.get("Access-Control-Allow-Origin") == origin, dict(r.headers)
            r = requests.options(gw.api + "/apps", headers={
                "Origin": origin, "Access-Control-Request-Method": "POST",
                "Access-Control-Request-Headers": "Content-Type"}, timeout=15)
            assert r.headers.get("Access-Control-Allow-Origin") == origin, dict(r.headers)
        for origin in NOT_IPV6_UI:
            r = gw.get("/apps", headers={"Origin": origin})
            assert r.status_code == 200
            assert not any(h in r.headers for h in CORS_HEADERS), (origin, dict(r.headers))
            r = requests.options(gw.api + "/apps", headers={"Origin": origin,
                                                            "Access-Control-Request-Method": "POST"}, timeout=15)
            assert "Access-Control-Allow-Origin" not in r.headers, (origin, dict(r.headers))
    finally:
        gw.stop()


@pytest.mark.parametrize("origin", NOT_IPV6_UI + ["http://[fd00::10]:8443/", "http://[fd00::10]:8443.evil"])
def test_no_configured_origin_is_read_as_a_pattern(fw, origin):
    client = make_app(fw, cors_origins=f"{IPV6_UI},http://a.b:1").test_client()
    assert client.get("/api/v1/apps", headers={"Origin": IPV6_UI}).headers["Access-Control-Allow-Origin"] == IPV6_UI
    r = client.get("/api/v1/apps", headers={"Origin": origin})
    assert not any(h in r.headers for h in CORS_HEADERS), dict(r.headers)
