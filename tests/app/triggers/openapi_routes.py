"""The triggers' routes (app/triggers/spec.py) answer per the OpenAPI document (their event streams' 200 is
text/event-stream: tests/app/triggers/test_app_triggers.py); run by tests/app/openapi/test_app_openapi.py."""

from __future__ import annotations

from ipc.errors import IpcError
from tests.app.openapi.answers import AUTH, ENTITY, WRONG


def exercise(ex) -> None:
    for collection in ("apps", "components", "functions"):
        base = f"/api/v1/{collection}/{ENTITY[collection]}/triggers"
        resource = f"/api/v1/{collection}/{ENTITY[collection]}/data/powertrain/engine/temperature"
        good = {"resource": resource, "trigger_condition": {"condition_type": "OnChange"}, "lifetime": 30}
        made = ex.client.post(base, json=good, headers=AUTH)
        trig = f"{base}/{made.get_json()['id']}"
        unknown = base + "/trig_0000000000000000"
        ex.answer_all([
            ("POST", base, {"json": good, "headers": AUTH}),
            ("POST", base, {"json": {**good, "trigger_condition": {}}, "headers": AUTH}),
            ("POST", base, {"json": {**good, "resource": "/api/v1/apps/x/data/t"}, "headers": AUTH}),
            ("POST", base, {"json": {**good, "resource": "/api/v1/apps/x/../data/t"}, "headers": AUTH}),
            ("POST", f"/api/v1/{collection}/nope/triggers", {"json": good, "headers": AUTH}),
            ("POST", base, {"json": good}), ("POST", base, {"json": good, "headers": WRONG}),
            ("POST", base, {"data": b"{}", "content_type": "text/plain", "headers": AUTH}),
            ("GET", base, {}), ("GET", f"/api/v1/{collection}/bad.id/triggers", {}),
            ("GET", trig, {}), ("GET", unknown, {}),
            ("PUT", trig, {"json": {"lifetime": 60}, "headers": AUTH}),
            ("PUT", trig, {"json": {"lifetime": 0}, "headers": AUTH}),
            ("PUT", trig, {"data": b'{"lifetime": 5}', "content_type": "text/plain", "headers": AUTH}),
            ("PUT", unknown, {"json": {"lifetime": 60}, "headers": AUTH}),
            ("PUT", trig, {"json": {"lifetime": 60}}), ("PUT", trig, {"json": {"lifetime": 60}, "headers": WRONG}),
            ("GET", unknown + "/events", {}),
            ("DELETE", trig, {}), ("DELETE", trig, {"headers": WRONG}),
            ("DELETE", trig, {"headers": AUTH}), ("DELETE", trig, {"headers": AUTH}),
        ])
    ex.fw.errors["trig_create"] = IpcError("triggers-full", "full", {"max_triggers": 1000})
    r = ex.client.post("/api/v1/apps/temp_sensor/triggers", json={
        "resource": "/api/v1/apps/temp_sensor/data/x", "trigger_condition": {"condition_type": "OnChange"}},
        headers=AUTH)
    assert r.status_code == 503 and r.headers["Retry-After"] == "5"
    ex.check("POST", "/api/v1/apps/temp_sensor/triggers", r)
