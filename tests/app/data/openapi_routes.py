"""The data family's routes (app/data/spec.py) answer per the OpenAPI document; run by
tests/app/openapi/test_app_openapi.py."""

from __future__ import annotations

from ipc.errors import IpcError
from tests.app.openapi.answers import AUTH, ENTITY, PUT_BODY


def exercise(ex) -> None:
    for collection, eid in ENTITY.items():
        base = f"/api/v1/{collection}"
        target = eid or "nope"
        put = f"{base}/{target}/data/body/lights/cmd"
        ex.answer_all([
            ("GET", f"{base}/{target}/data", {}),
            ("GET", f"{base}/{target}/data/powertrain/engine/temperature", {}),
            ("GET", f"{base}/{target}/data/powertrain%2Fengine%2Ftemperature?bytes=base64", {}),
            ("GET", f"{base}/{target}/data//not/sampled/yet", {}),
            ("GET", f"{base}/{target}/data/bad-topic", {}),
            ("GET", f"{base}/{target}/data/x?bytes=hex", {}),
            ("GET", f"{base}/{target}/data-categories", {}),
            ("GET", f"{base}/{target}/data-groups", {}),
            ("PUT", put, {"json": PUT_BODY, "headers": AUTH}),
            ("PUT", put, {"json": PUT_BODY}),
            ("PUT", put, {"json": PUT_BODY, "headers": {"Authorization": "Bearer wrong"}}),
            ("PUT", put, {"data": b"nope", "headers": AUTH}),
            ("PUT", put, {"json": PUT_BODY, "headers": {**AUTH, "Content-Type": "text/plain"}}),
            ("PUT", put, {"json": {"type": "bad", "data": {}}, "headers": AUTH}),
            ("PUT", put, {"json": {"type": "std_msgs/msg/String", "data": {"data": "x" * 2000}}, "headers": AUTH}),
        ])
    # The ROS worker's troubles, as documented.
    fw, client = ex.fw, ex.client
    fw.errors["sample"] = IpcError("cold-wait-cap-exceeded", "cap", {"topic": "/x", "cold_wait_cap": 4})
    r = client.get("/api/v1/apps/temp_sensor/data/x")
    assert r.status_code == 503
    ex.check("GET", "/api/v1/apps/temp_sensor/data/x", r)
    fw.errors["publish"] = IpcError("type-not-installed", "not installed")
    r = client.put("/api/v1/apps/temp_sensor/data/x", json=PUT_BODY, headers=AUTH)
    assert r.status_code == 400
    ex.check("PUT", "/api/v1/apps/temp_sensor/data/x", r)
    fw.errors["sample"] = IpcError("deadline-exceeded", "late")
    r = client.get("/api/v1/apps/temp_sensor/data/x")
    assert r.status_code == 504
    ex.check("GET", "/api/v1/apps/temp_sensor/data/x", r)
    # Successes of entity routes were seen for every collection that has entities.
    assert 200 in ex.seen["GET /apps/{app_id}/data/{data_id}"]
    assert 200 in ex.seen["PUT /functions/{function_id}/data/{data_id}"]
    assert {400, 401, 413, 415} <= ex.seen["PUT /components/{component_id}/data/{data_id}"]  # a wrong token: 401
