"""The configurations' routes (app/configurations/spec.py) answer per the OpenAPI document (with real nodes:
tests/system/configurations/test_configurations.py); run by tests/app/openapi/test_app_openapi.py."""

from __future__ import annotations

from ipc.errors import IpcError
from tests.app.openapi.answers import AUTH, ENTITY, WRONG


def exercise(ex) -> None:
    param = {"name": "rate", "value": 1.0, "type": "double"}
    ex.fw.replies = {
        "param_list": lambda args: {"nodes": {n: {"ok": True, "parameters": [param]} for n in args["nodes"]}},
        "param_get": {**param, "description": "", "read_only": False},
        "param_set": param, "param_reset": {},
        "param_reset_all": lambda args: {"nodes": {n: {"ok": True, "result": {
            "reset": [], "failed": [{"name": "mode", "reason": "locked"}]}} for n in args["nodes"]}},
    }
    for collection in ("apps", "components", "functions"):
        base = f"/api/v1/{collection}/{ENTITY[collection]}/configurations"
        item = base + ("/rate" if collection != "components" else "/temp_sensor:rate")
        ex.answer_all([
            ("GET", base, {}), ("GET", f"/api/v1/{collection}/nope/configurations", {}),
            ("GET", item, {}), ("GET", base + "/" + "a" * 600, {}),
            ("PUT", item, {"json": {"data": 2.0}, "headers": AUTH}), ("PUT", item, {"json": {"data": 2.0}}),
            ("PUT", item, {"json": {"data": 2.0}, "headers": WRONG}),
            ("PUT", item, {"json": {}, "headers": AUTH}),
            ("PUT", item, {"data": b'{"data": 1}', "content_type": "text/plain", "headers": AUTH}),
            ("PUT", item, {"json": {"data": "x" * 2000}, "headers": AUTH}),
            ("DELETE", item, {"headers": AUTH}), ("DELETE", item, {}),
            ("DELETE", base, {"headers": AUTH}), ("DELETE", base, {}),
        ])
    ex.fw.errors["param_get"] = IpcError("node-unavailable", "did not respond", {"retry_after_s": 3})
    r = ex.client.get("/api/v1/apps/temp_sensor/configurations/rate")
    assert r.status_code == 503 and r.headers["Retry-After"] == "3"
    ex.check("GET", "/api/v1/apps/temp_sensor/configurations/rate", r)
    assert {200, 400, 401, 413, 415} <= ex.seen["PUT /components/{component_id}/configurations/{config_id}"]
    assert {204, 401} <= ex.seen["DELETE /apps/{app_id}/configurations/{config_id}"]
    assert {207, 401} <= ex.seen["DELETE /functions/{function_id}/configurations"]
