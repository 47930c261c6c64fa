"""The cyclic subscriptions' routes (app/subscriptions/spec.py) answer per the OpenAPI document (their event
streams' 200 is text/event-stream: tests/system/subscriptions/test_app_streams.py); run by
tests/app/openapi/test_app_openapi.py."""

from __future__ import annotations

from ipc.errors import IpcError
from tests.app.openapi.answers import AUTH, ENTITY, WRONG


def exercise(ex) -> None:
    for collection in ("apps", "components", "functions"):
        base = f"/api/v1/{collection}/{ENTITY[collection]}/cyclic-subscriptions"
        resource = f"/api/v1/{collection}/{ENTITY[collection]}/data/powertrain/engine/temperature"
        good = {"resource": resource, "interval": "fast", "duration": 30}
        made = ex.client.post(base, json=good, headers=AUTH)
        sub = f"{base}/{made.get_json()['id']}"
        ex.answer_all([
            ("POST", base, {"json": good, "headers": AUTH}),
            ("POST", base, {"json": {**good, "interval": "hourly"}, "headers": AUTH}),
            ("POST", base, {"json": {**good, "resource": "/api/v1/apps/x/faults"}, "headers": AUTH}),
            ("POST", f"/api/v1/{collection}/nope/cyclic-subscriptions", {"json": good, "headers": AUTH}),
            ("POST", base, {"json": good}), ("POST", base, {"json": good, "headers": WRONG}),
            ("GET", base, {}), ("GET", f"/api/v1/{collection}/bad.id/cyclic-subscriptions", {}),
            ("GET", sub, {}), ("GET", base + "/sub_0000000000000000", {}),
            ("POST", base, {"data": b"{}", "content_type": "text/plain", "headers": AUTH}),
            ("PUT", sub, {"json": {"interval": "slow"}, "headers": AUTH}),
            ("PUT", sub, {"json": {"duration": -1}, "headers": AUTH}),
            ("PUT", sub, {"data": b'{"interval": "slow"}', "content_type": "text/plain", "headers": AUTH}),
            ("PUT", base + "/sub_0000000000000000", {"json": {"interval": "slow"}, "headers": AUTH}),
            ("PUT", sub, {"json": {"interval": "slow"}}), ("PUT", sub, {"json": {"interval": "slow"}, "headers": WRONG}),
            ("GET", base + "/sub_0000000000000000/events", {}),
            ("DELETE", sub, {}), ("DELETE", sub, {"headers": WRONG}),
            ("DELETE", sub, {"headers": AUTH}), ("DELETE", sub, {"headers": AUTH}),
        ])
    ex.fw.errors["sub_create"] = IpcError("subscriptions-full", "full", {"max_subscriptions": 1000})
    r = ex.client.post("/api/v1/apps/temp_sensor/cyclic-subscriptions", json={
        "resource": "/api/v1/apps/temp_sensor/data/x", "interval": "slow", "duration": 5}, headers=AUTH)
    assert r.status_code == 503
    ex.check("POST", "/api/v1/apps/temp_sensor/cyclic-subscriptions", r)
    for op in ("POST /apps/{app_id}/cyclic-subscriptions", "PUT /apps/{app_id}/cyclic-subscriptions/{subscription_id}"):
        assert 415 in ex.seen[op], op
