"""Root overview, version-info, health, docs, and the JSON error handlers (app/core/errors.py)."""

from __future__ import annotations

import logging
import re
import time

import pytest

from app import openapi
from app.core import unimplemented
from tests.support.fakeworker import STATS, data_sample, make_app


def test_root(client):
    r = client.get("/api/v1/")
    assert r.status_code == 200
    body = r.get_json()
    assert body["name"] == "sovd-gateway"
    assert re.match(r"^\d+\.\d+\.\d+", body["version"])
    assert body["api_base"] == "/api/v1"
    assert "GET /api/v1/health" in body["endpoints"]
    assert "PUT /api/v1/components/{component_id}/data/{data_id}" in body["endpoints"]
    assert "GET /api/v1/apps/{app_id}/is-located-on" in body["endpoints"]
    for route in ("/components/{component_id}/hosts", "/components/{component_id}/subcomponents",
                  "/components/{component_id}/depends-on", "/apps/{app_id}/belongs-to",
                  "/apps/{app_id}/depends-on", "/functions/{function_id}/hosts", "/areas/{area_id}",
                  "/areas/{area_id}/components", "/areas/{area_id}/contains", "/areas/{area_id}/subareas",
                  "/docs", "/apps/docs", "/apps/{app_id}/docs", "/apps/{app_id}/data/docs"):
        assert f"GET /api/v1{route}" in body["endpoints"], route
    for endpoint in ("GET /api/v1/faults", "DELETE /api/v1/faults", "GET /api/v1/faults/stream",  # faults
                     "GET /api/v1/apps/{app_id}/faults/{fault_code}", "DELETE /api/v1/functions/{function_id}/faults"):
        assert endpoint in body["endpoints"], endpoint
    assert body["endpoints"] == openapi.endpoint_list()
    caps = body["capabilities"]
    assert caps["discovery"] is True and caps["data_access"] is True and caps["publishing"] is False
    assert all(isinstance(v, bool) for v in caps.values())


def test_root_says_what_is_not_served(client):
    """The capabilities say what answers 501 (app/core/unimplemented.py) and what is not there yet."""
    body = client.get("/api/v1/").get_json()
    caps = body["capabilities"]
    for name in ("scripts", "lifecycle", "updates", "authentication", "tls", "bulk_data_writes"):
        assert caps[name] is False, name
    for name in ("cyclic_subscriptions", "docs", "operations", "async_actions", "configurations", "faults",
                 "logs", "triggers", "locking", "bulk_data"):  # locks: issue 31; bulk data: issue 32
        assert caps[name] is True, name
    assert "GET /api/v1/updates" in body["endpoints"]
    assert "POST /api/v1/apps/{app_id}/locks" in body["endpoints"]


def test_root_reflects_allow_publish(fw):
    body = make_app(fw, allow_publish=True).test_client().get("/api/v1/").get_json()
    assert body["capabilities"]["publishing"] is True


def test_root_reflects_allow_configurations(fw):
    """The dashboard's Parameters panel shows its editor only when the gateway allows configuration writes."""
    assert make_app(fw).test_client().get("/api/v1/").get_json()["capabilities"]["configuration_writes"] is False
    body = make_app(fw, allow_configurations=True).test_client().get("/api/v1/").get_json()
    assert body["capabilities"]["configuration_writes"] is True


def test_root_reflects_allow_fault_clear(fw):
    """The dashboard offers Clear on a fault only when the gateway would clear it."""
    assert make_app(fw).test_client().get("/api/v1/").get_json()["capabilities"]["fault_clear"] is False
    body = make_app(fw, allow_fault_clear=True).test_client().get("/api/v1/").get_json()
    assert body["capabilities"]["fault_clear"] is True


def test_version_info(client):
    body = client.get("/api/v1/version-info").get_json()
    (item,) = body["items"]
    assert item["version"] == "1.0.0" and item["base_uri"] == "/api/v1"
    assert item["vendor_info"]["name"] == "sovd-gateway" and item["vendor_info"]["version"]


def test_health_with_live_worker(client):
    r = client.get("/api/v1/health")
    assert r.status_code == 200
    body = r.get_json()
    assert body["status"] == "healthy"
    assert isinstance(body["timestamp"], int) and body["timestamp"] > 1_600_000_000 * 10**9
    assert body["discovery"] == {"mode": "runtime_only", "strategy": "runtime"}
    assert body["x-medkit-data-provider"] == {**STATS["data_provider"],
                                              "evictions": STATS["details"]["evictions"]}
    assert body["x-medkit-subscription-executor"] == STATS["executor"]


def test_health_degraded(client, fw):
    fw.stats["executor"]["degraded"] = True
    body = client.get("/api/v1/health").get_json()
    assert body["status"] == "degraded"
    assert body["x-medkit-subscription-executor"]["degraded"] is True
    assert body["x-medkit-subscription-executor"]["worker_alive"] is True


def test_health_without_worker_answers_at_once(tmp_path):
    client = make_app(runtime_dir=str(tmp_path), max_pool_size=99, cold_wait_cap=7).test_client()
    start = time.monotonic()
    r = client.get("/api/v1/health")
    assert time.monotonic() - start < 5  # generous: it must not wait for an IPC timeout
    assert r.status_code == 200
    body = r.get_json()
    assert body["status"] == "unhealthy"
    executor = body["x-medkit-subscription-executor"]
    assert executor["worker_alive"] is False and executor["degraded"] is False
    assert set(executor) == set(STATS["executor"])
    provider = body["x-medkit-data-provider"]
    assert set(provider) == set(STATS["data_provider"]) | {"evictions"}
    assert provider["evictions"] == {}  # by cause: unknown until the ROS worker first answers
    assert provider["pool_cap"] == 99 and provider["cold_wait_cap"] == 7 and provider["pool_hits"] == 0


def test_health_keeps_last_known_counters_when_worker_dies(fw):
    client = make_app(fw).test_client()
    assert client.get("/api/v1/health").get_json()["x-medkit-subscription-executor"]["worker_alive"]
    fw.stop()
    body = client.get("/api/v1/health").get_json()
    assert body["status"] == "unhealthy"
    assert body["x-medkit-subscription-executor"]["worker_alive"] is False
    assert body["x-medkit-subscription-executor"]["tasks_completed"] == STATS["executor"]["tasks_completed"]
    assert body["x-medkit-data-provider"]["pool_hits"] == STATS["data_provider"]["pool_hits"]


def test_health_with_worker_not_answering(fw):
    fw.silent.add("stats")
    client = make_app(fw).test_client()
    start = time.monotonic()
    body = client.get("/api/v1/health").get_json()
    assert time.monotonic() - start < 5
    assert body["x-medkit-subscription-executor"]["worker_alive"] is False


def test_docs_is_openapi_31(client):
    r = client.get("/api/v1/docs")
    assert r.status_code == 200
    doc = r.get_json()
    assert doc["openapi"].startswith("3.1")
    assert "/apps/{app_id}/data/{data_id}" in doc["paths"]
    params = doc["paths"]["/apps/{app_id}/data/{data_id}"]["get"]["parameters"]
    assert any(p["name"] == "bytes" and p["in"] == "query" for p in params)
    put = doc["paths"]["/components/{component_id}/data/{data_id}"]["put"]
    assert {"401", "403", "413"} <= set(put["responses"])
    assert doc["info"]["x-sovd-version"] == "1.0.0"
    assert doc == openapi.document()


def test_collection_docs_is_the_subtree(client):
    r = client.get("/api/v1/apps/docs")
    assert r.status_code == 200 and r.headers["Content-Type"] == "application/json"
    doc = r.get_json()
    whole = openapi.document()
    expected = [p for p in whole["paths"] if p == "/apps" or p.startswith("/apps/")]
    assert list(doc["paths"]) == expected and "/apps/{app_id}/is-located-on" in expected
    assert doc["paths"]["/apps"] == whole["paths"]["/apps"]
    assert doc["components"] == whole["components"] and doc["openapi"] == "3.1.0"
    assert doc["info"]["title"] == "sovd-gateway - apps" and doc["info"]["x-sovd-version"] == "1.0.0"


def test_entity_docs_fill_in_the_entity(client):
    doc = client.get("/api/v1/components/test-robot/docs").get_json()
    # In the document's order: the core's first paths (the entity, its relations), then each family's in
    # name order (app/<family>/spec.py), then the core's last ones (the scoped docs, medkit's 501s).
    assert list(doc["paths"]) == [
        "/components/test-robot", "/components/test-robot/subcomponents", "/components/test-robot/hosts",
        "/components/test-robot/depends-on",
        "/components/test-robot/bulk-data", "/components/test-robot/bulk-data/{category_id}",  # issue 32
        "/components/test-robot/bulk-data/{category_id}/{file_id}",
        "/components/test-robot/subcomponents/{subcomponent_id}/bulk-data",
        "/components/test-robot/subcomponents/{subcomponent_id}/bulk-data/{category_id}",
        "/components/test-robot/subcomponents/{subcomponent_id}/bulk-data/{category_id}/{file_id}",
        "/components/test-robot/configurations", "/components/test-robot/configurations/{config_id}",
        "/components/test-robot/data", "/components/test-robot/data/{data_id}",
        "/components/test-robot/data-categories", "/components/test-robot/data-groups",
        "/components/test-robot/faults", "/components/test-robot/faults/{fault_code}",
        "/components/test-robot/locks", "/components/test-robot/locks/{lock_id}",  # locks (issue 31)
        "/components/test-robot/logs", "/components/test-robot/logs/configuration",
        "/components/test-robot/operations", "/components/test-robot/operations/{operation_id}",
        "/components/test-robot/operations/{operation_id}/executions",
        "/components/test-robot/operations/{operation_id}/executions/{execution_id}",
        "/components/test-robot/status",  # GET .../status (its transitions are 501: below)
        "/components/test-robot/cyclic-subscriptions",
        "/components/test-robot/cyclic-subscriptions/{subscription_id}",
        "/components/test-robot/cyclic-subscriptions/{subscription_id}/events",
        "/components/test-robot/triggers", "/components/test-robot/triggers/{trigger_id}",
        "/components/test-robot/triggers/{trigger_id}/events",
        "/components/test-robot/docs", "/components/test-robot/data/docs",
        # medkit's routes not served here (501), in the order of unimplemented.ROUTES
        *dict.fromkeys(path.replace("{component_id}", "test-robot")
                       for _, path, collection in unimplemented.paths() if collection == "components")]
    get = doc["paths"]["/components/test-robot/hosts"]["get"]
    assert get["operationId"] == "listComponentHosts" and "parameters" not in get
    read = doc["paths"]["/components/test-robot/data/{data_id}"]["get"]
    assert [p["name"] for p in read["parameters"]] == ["data_id", "bytes"]
    assert doc["info"]["title"] == "sovd-gateway - components/test-robot"


def test_data_docs_list_the_entitys_topics(client):
    doc = client.get("/api/v1/apps/temp_sensor/data/docs").get_json()
    assert list(doc["paths"]) == ["/apps/temp_sensor/data", "/apps/temp_sensor/data/{data_id}",
                                  "/apps/temp_sensor/data/docs"]
    (data_id,) = [p for p in doc["paths"]["/apps/temp_sensor/data/{data_id}"]["get"]["parameters"]
                  if p["name"] == "data_id"]
    assert data_id["examples"]["/powertrain/engine/temperature"]["value"] == "powertrain/engine/temperature"
    assert set(data_id["examples"]) == {"/powertrain/engine/temperature", "/rosout", "/parameter_events"}


@pytest.mark.parametrize("path", ["/api/v1/apps/nope/docs", "/api/v1/apps/nope/data/docs",
                                  "/api/v1/apps/bad.id/docs", "/api/v1/components/temp_sensor/docs",
                                  "/api/v1/areas/root/data/docs"])
def test_docs_of_no_entity_is_medkits_404(client, path):
    r = client.get(path)
    assert r.status_code == 404
    assert r.get_json() == {"error_code": "resource-not-found",
                            "message": "No capability description available for the requested path"}


def test_topic_named_docs_is_still_readable(client, fw):
    fw.samples["/docs"] = data_sample("/docs", "std_msgs/msg/String", {"data": "not the OpenAPI"})
    for path in ("/api/v1/apps/temp_sensor/data//docs", "/api/v1/apps/temp_sensor/data/%2Fdocs"):
        body = client.get(path).get_json()
        assert body["id"] == "/docs" and body["data"] == {"data": "not the OpenAPI"}, path
    assert "paths" in client.get("/api/v1/apps/temp_sensor/data/docs").get_json()


# "/" is the dashboard now (it redirects to ui/: tests/app/ui/test_app_ui.py); any other path outside it stays a 404.
@pytest.mark.parametrize("path", ["/api/v1/nope", "/api/v2/", "/robots", "/api/v1/apps/x/y/z",
                                  "/api/v1/robots/x"])
def test_unmatched_route_is_json_404(client, path):
    r = client.get(path)
    assert r.status_code == 404
    assert r.headers["Content-Type"] == "application/json"
    body = r.get_json()
    assert body["error_code"] == "resource-not-found"
    assert body["message"] == "Resource not found"
    assert body["parameters"]["status"] == 404  # medkit's parameter


def test_405_is_json_with_allow(client):
    r = client.delete("/api/v1/health")
    assert r.status_code == 405
    assert r.headers["Content-Type"] == "application/json"
    assert "GET" in r.headers["Allow"]
    assert r.get_json()["error_code"] == "invalid-request"


def test_unexpected_error_is_500_without_traceback(fw, caplog):
    app = make_app(fw)

    def boom():
        raise RuntimeError("secret internal detail")

    app.add_url_rule("/api/v1/boom", view_func=boom)
    with caplog.at_level(logging.ERROR):
        r = app.test_client().get("/api/v1/boom")
    assert r.status_code == 500
    assert r.get_json() == {"error_code": "internal-error", "message": "Internal server error"}
    assert "secret" not in r.get_data(as_text=True)
    assert any("secret internal detail" in (rec.exc_text or "") or rec.exc_info for rec in caplog.records)


def test_error_bodies_leave_out_empty_parameters(client, fw):
    fw.stop()
    body = client.get("/api/v1/apps").get_json()
    assert "parameters" not in body
