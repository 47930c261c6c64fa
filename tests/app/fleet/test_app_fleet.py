"""The fleet on the HTTP side (app/fleet/) with no fleet link behind it: what is answered before the link.

What the link answers is tested through the real thing (tests/system/fleet/test_fleet_zenoh.py,
test_fleet_sim.py); here, with the Flask test client: a robot asks a request that came through its
fleet link for an identity, even a read; the fleet gateway's own routes, its refusals (no identity,
writes off) made before anything is asked of the link, and its answers while the link is down.
"""

from __future__ import annotations

import tempfile

import pytest

from ipc import fleet
from tests.support.fakeworker import make_app
from tests.support.metrics import parse, value

TOKEN = "fleet-app-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture
def nobody():
    with tempfile.TemporaryDirectory() as path:   # no ROS worker, no fleet link there
        yield path


def test_a_robot_asks_a_request_through_its_fleet_link_for_an_identity_even_a_read(nobody):
    client = make_app(runtime_dir=nobody, api_token=TOKEN).test_client()
    assert client.get("/api/v1/version-info").status_code == 200                # local reads stay open
    marked = {fleet.MARK: "1"}
    r = client.get("/api/v1/version-info", headers=marked)
    assert r.status_code == 401 and r.json["error_code"] == "unauthorized"
    r = client.get("/api/v1/version-info", headers={**marked, "Authorization": "Bearer wrong-token-0123456"})
    assert r.status_code == 401
    assert client.get("/api/v1/version-info", headers={**marked, **AUTH}).status_code == 200
    assert client.get("/api/v1/").json["capabilities"]["aggregation"] is False


@pytest.fixture
def aggregator(nobody):
    return make_app(runtime_dir=nobody, api_token=TOKEN, fleet_aggregate=True, fleet_connect="tcp/127.0.0.1:1",
                    fleet_timeout=0.5, ipc_timeout=0.5).test_client()


def test_the_fleet_gateway_serves_its_own_routes_with_no_robot(aggregator):
    body = aggregator.get("/api/v1/").json
    caps = body["capabilities"]
    assert caps["aggregation"] is True and caps["publishing"] is False and caps["cyclic_subscriptions"] is False
    assert aggregator.get("/api/v1/version-info").json["items"][0]["version"]
    assert aggregator.get("/api/v1/docs").status_code == 200
    assert aggregator.get("/ui/").status_code == 200
    health = aggregator.get("/api/v1/health").json
    assert health["status"] == "unhealthy" and health["peers"] == [] and health["warnings"] == []
    assert health["warning_schema_version"] == 2 and health["x-medkit-fleet"]["link_alive"] is False
    assert health["x-medkit-fleet"]["max_robots"] == 1000


def test_the_fleet_gateway_refuses_before_it_asks_the_link(aggregator):
    assert aggregator.get("/api/v1/apps").status_code == 401
    assert aggregator.get("/api/v1/faults").status_code == 401
    assert aggregator.get("/api/v1/apps/x/data/t", headers={"Authorization": "Bearer nope-nope-nope-nope"}
                          ).status_code == 401
    r = aggregator.put("/api/v1/apps/x/data/t", json={}, headers=AUTH)
    assert r.status_code == 403 and "Writes through the fleet are disabled" in r.json["message"]
    r = aggregator.get("/api/v1/apps/bad$id", headers=AUTH)
    assert r.status_code == 400 and r.json["message"] == "Invalid entity ID"
    r = aggregator.get("/api/v1/faults?status=sometimes", headers=AUTH)
    assert r.status_code == 400 and r.json["parameters"]["parameter"] == "status"


def test_while_the_fleet_link_is_down_the_answer_is_a_503_that_says_so(aggregator):
    for path in ("/api/v1/apps", "/api/v1/apps/x", "/api/v1/faults"):
        r = aggregator.get(path, headers=AUTH)
        assert r.status_code == 503 and r.json["vendor_code"] == "x-medkit-fleet-link-unavailable", path
        assert r.headers["Retry-After"] == "2"


def test_the_fleet_gateways_metrics_have_no_ros_worker(aggregator):
    scrape = parse(aggregator.get("/metrics").get_data(as_text=True))
    assert value(scrape, "sovd_fleet_link_up") == 0
    assert "sovd_ros_worker_up" not in scrape
