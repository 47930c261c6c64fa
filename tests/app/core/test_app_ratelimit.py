"""Rate limiting: the shared token buckets, the 429 answer, the client behind a trusted proxy.

The buckets are checked with their own clock here; that two gunicorn workers
enforce one limit, and that a limited client does not slow another, is
checked through a real gateway in ``tests/system/fleet/test_fleet_e2e.py``.
"""

from __future__ import annotations

import os

import pytest

from app import openapi, ratelimit
from app.core.clientaddr import Trusted, client_address
from common import settings
from tests.app.openapi.answers import check
from tests.support.fakeworker import make_app

pytestmark = pytest.mark.fakeworker(scope="module")


def buckets(tmp_path, client="", overall="", slots=ratelimit.SLOTS) -> ratelimit.SharedBuckets:
    b = ratelimit.SharedBuckets(str(tmp_path / "ratelimit.buckets"), settings.parse_rate(client),
                                settings.parse_rate(overall), slots=slots)
    b._open()  # maps the file; the checks below pass their own clock to _take
    return b


def take(b: ratelimit.SharedBuckets, address: str, now: float) -> ratelimit.Decision:
    import hashlib

    key = hashlib.blake2b(address.encode(), digest_size=16, key=b._salt).digest() if b.client else b""
    return b._take(b._map, key, now)


def test_a_burst_then_the_rate(tmp_path):
    b = buckets(tmp_path, client="10/5")
    t = 1000.0
    decisions = [take(b, "10.0.0.1", t) for _ in range(6)]
    assert [d.allowed for d in decisions] == [True] * 5 + [False]
    assert [d.remaining for d in decisions[:5]] == [4, 3, 2, 1, 0]
    refused = decisions[5]
    assert (refused.scope, refused.limit, refused.remaining, refused.retry_after) == ("client", 5, 0, 1)
    assert refused.full_in == pytest.approx(0.5)  # 5 tokens at 10/s
    assert take(b, "10.0.0.1", t + 0.05).allowed is False   # half a token
    assert take(b, "10.0.0.1", t + 0.1).allowed is True     # one token after 0.1 s
    assert take(b, "10.0.0.1", t + 0.1).allowed is False
    # Another client has a bucket of its own.
    assert take(b, "10.0.0.2", t + 0.1).allowed is True


def test_the_global_bucket_covers_every_client_and_a_refused_client_takes_nothing(tmp_path):
    b = buckets(tmp_path, client="1/2", overall="1/3")
    t = 50.0
    assert take(b, "a", t).allowed and take(b, "a", t).allowed
    for _ in range(5):  # client a is over its own limit: the global bucket keeps its token
        d = take(b, "a", t)
        assert not d.allowed and d.scope == "client"
    assert take(b, "b", t).allowed  # the third global token
    d = take(b, "c", t)
    assert not d.allowed and d.scope == "global" and d.limit == 3
    assert d.retry_after == 1


def test_headers_describe_the_bucket_closer_to_empty(tmp_path):
    b = buckets(tmp_path, client="1/10", overall="100/3")
    d = take(b, "a", 7.0)
    assert d.allowed and (d.scope, d.limit, d.remaining) == ("global", 3, 2)
    # Both empty: the answer names the one that makes the client wait longer.
    (tmp_path / "both").mkdir()
    b = buckets(tmp_path / "both", client="1/1", overall="0.5/1")
    assert take(b, "a", 9.0).allowed
    d = take(b, "a", 9.0)
    assert not d.allowed and (d.scope, d.retry_after) == ("global", 2)


def test_memory_is_bounded_and_refilled_buckets_are_reused(tmp_path):
    b = buckets(tmp_path, client="1/1", slots=64)
    assert os.path.getsize(b.path) == ratelimit._HEADER.size + 64 * ratelimit._SLOT.size
    t = 10.0
    for i in range(1000):  # far more addresses than places: each one's first request passes
        assert take(b, f"10.1.{i // 256}.{i % 256}", t).allowed
    # Long after, every bucket has refilled: a client seen before starts full, never refused.
    assert take(b, "10.1.0.1", t + 5).allowed


def test_two_mappings_of_one_file_share_the_buckets(tmp_path):
    a = buckets(tmp_path, client="0.001/3")
    b = ratelimit.SharedBuckets(a.path, a.client, a.overall)
    allowed = [x.take("10.9.9.9").allowed for x in (a, b, a, b, a)]
    assert allowed == [True, True, True, False, False]


@pytest.mark.parametrize("text", ["50/100", "2.5", " 7 / 9 "])
def test_settings_parse(text):
    rate = settings.parse_rate(text)
    assert rate.rate > 0 and rate.burst >= 1


def test_client_address_behind_trusted_proxies():
    trusted = Trusted("127.0.0.1,::1,10.8.0.0/16")
    assert client_address("127.0.0.1", "198.51.100.7", trusted) == "198.51.100.7"
    # nginx appends what it saw; whatever the client wrote stands to the left and is not believed.
    assert client_address("127.0.0.1", "1.1.1.1, 198.51.100.7", trusted) == "198.51.100.7"
    # Proxies in a chain are skipped, from the right.
    assert client_address("127.0.0.1", "198.51.100.7, 10.8.3.4", trusted) == "198.51.100.7"
    # An untrusted peer cannot choose its address.
    assert client_address("203.0.113.9", "198.51.100.7", trusted) == "203.0.113.9"
    # Garbage ends the walk at the last good address.
    assert client_address("127.0.0.1", "not-an-ip, 127.0.0.1", trusted) == "127.0.0.1"
    assert client_address("::ffff:127.0.0.1", "198.51.100.7", trusted) == "198.51.100.7"
    assert client_address("203.0.113.9", "198.51.100.7", Trusted("*")) == "198.51.100.7"


def test_a_429_is_the_contracts_error_with_its_headers_and_monitoring_is_never_limited(fw):
    app = make_app(fw, rate_limit="1/2", forwarded_allow_ips="127.0.0.1")
    client = app.test_client()
    me = {"REMOTE_ADDR": "127.0.0.1"}
    xff = {"X-Forwarded-For": "192.0.2.10"}
    answers = [client.get("/api/v1/apps", headers=xff, environ_base=me) for _ in range(3)]
    assert [r.status_code for r in answers] == [200, 200, 429]
    for r in answers:
        assert r.headers["X-RateLimit-Limit"] == "2"
        assert int(r.headers["X-RateLimit-Reset"]) > 0
    assert [r.headers["X-RateLimit-Remaining"] for r in answers] == ["1", "0", "0"]
    refused = answers[2]
    body = refused.get_json()
    assert body["error_code"] == "rate-limit-exceeded"  # medkit's code (error_codes.hpp)
    assert body["message"].startswith("Too many requests")
    assert set(body["parameters"]) == {"retry_after", "limit", "reset", "scope"}
    assert body["parameters"]["scope"] == "client"
    assert int(refused.headers["Retry-After"]) == body["parameters"]["retry_after"] >= 1
    check(openapi.document(), "GET", "/api/v1/apps", refused)  # documented as 429 GenericError
    # Another client behind the same proxy is not limited by this one.
    other = client.get("/api/v1/apps", headers={"X-Forwarded-For": "192.0.2.11"}, environ_base=me)
    assert other.status_code == 200
    # Health and metrics are never limited, nor are CORS preflights.
    for _ in range(5):
        assert client.get("/api/v1/health", headers=xff, environ_base=me).status_code == 200
        assert client.get("/metrics", headers=xff, environ_base=me).status_code == 200
        r = client.options("/api/v1/apps", environ_base=me,
                           headers={**xff, "Origin": "http://x.example", "Access-Control-Request-Method": "GET"})
        assert r.status_code == 200
    assert "X-RateLimit-Limit" not in client.get("/api/v1/health", headers=xff, environ_base=me).headers
    # A client that is not a trusted proxy cannot pose as another client.
    spoofed = [client.get("/api/v1/apps", headers={"X-Forwarded-For": f"192.0.2.{50 + i}"},
                          environ_base={"REMOTE_ADDR": "203.0.113.1"}) for i in range(3)]
    assert [r.status_code for r in spoofed] == [200, 200, 429]


def test_off_by_default(fw):
    client = make_app(fw).test_client()
    for _ in range(20):
        r = client.get("/api/v1/apps")
        assert r.status_code == 200
        assert "X-RateLimit-Limit" not in r.headers
    assert ratelimit.EXTENSION not in client.application.extensions
