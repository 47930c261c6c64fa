"""The faults' routes (app/faults/spec.py) answer per the OpenAPI document, over the ROS worker's answers
(rosworker/faults/manager.py::public); the stream's events are tests/system/faults/test_app_faults.py's.  Run by
tests/app/openapi/test_app_openapi.py."""

from __future__ import annotations

from app.sse.hub import hub_of
from ipc.errors import IpcError
from tests.app.openapi.answers import AUTH, ENTITY, WRONG


def exercise(ex) -> None:
    fault = {"fault_code": "TEMP_SENSOR_HOT", "severity": 2, "severity_label": "ERROR", "description": "hot",
             "first_occurred": 1700000000.5, "last_occurred": 1700000001.5, "occurrence_count": 1,
             "status": "CONFIRMED", "reporting_sources": ["/powertrain/engine/temp_sensor"]}
    frame = {"type": "freeze_frame", "name": "temp_sensor: hot", "topic": "", "message_type": "",
             "captured_at_ns": 1700000001000000000, "data": '{"celsius": "93.5"}'}
    ex.fw.replies = {
        "fault_list": {"items": [fault, {**fault, "fault_code": "ELSEWHERE", "reporting_sources": ["/other"]}]},
        "fault_get": lambda args: (IpcError("no-such-fault", "Fault not found", {"fault_code": args["code"]})
                                   if args["code"] != fault["fault_code"] else
                                   {"fault": fault, "snapshots": [frame], "first_ns": 1700000000500000000,
                                    "last_ns": 1700000001500000000}),
        "fault_clear": {"cleared": [fault["fault_code"]]},
    }
    faults = [("GET", "/api/v1/faults", {}), ("GET", "/api/v1/faults?status=all", {}),
              ("GET", "/api/v1/faults?status=loud", {}), ("DELETE", "/api/v1/faults", {"headers": AUTH}),
              ("DELETE", "/api/v1/faults?status=loud", {"headers": AUTH}), ("DELETE", "/api/v1/faults", {}),
              ("DELETE", "/api/v1/faults", {"headers": WRONG})]
    for collection in ("apps", "components", "functions"):
        base = f"/api/v1/{collection}/{ENTITY[collection]}/faults"
        one, elsewhere = base + "/TEMP_SENSOR_HOT", base + "/ELSEWHERE"
        faults += [
            ("GET", base, {}), ("GET", base + "?status=cleared", {}), ("GET", base + "?status=x", {}),
            ("GET", f"/api/v1/{collection}/nope/faults", {}), ("GET", f"/api/v1/{collection}/b.d/faults", {}),
            ("DELETE", base, {"headers": AUTH}), ("DELETE", base + "?status=x", {"headers": AUTH}),
            ("DELETE", base, {}), ("DELETE", base, {"headers": WRONG}),
            ("DELETE", f"/api/v1/{collection}/nope/faults", {"headers": AUTH}),
            ("GET", one, {}), ("GET", base + "/NO_SUCH", {}), ("GET", elsewhere, {}),
            ("GET", base + "/" + "A" * 300, {}),
            ("DELETE", one, {"headers": AUTH}), ("DELETE", one, {}), ("DELETE", one, {"headers": WRONG}),
            ("DELETE", elsewhere, {"headers": AUTH}), ("DELETE", base + "/" + "A" * 300, {"headers": AUTH}),
        ]
    ex.answer_all(faults)
    r = ex.client.get("/api/v1/faults/stream")  # the head only
    assert r.status_code == 200
    ex.note("GET", "/api/v1/faults/stream", r)
    r.close()
    hub = hub_of("faults", ex.client.application)
    held = [object() for _ in range(16)]  # max_fault_streams (16) streams open in this HTTP worker
    hub.streams.update(held)
    r = ex.client.get("/api/v1/faults/stream")
    hub.streams.difference_update(held)
    assert r.status_code == 503 and r.headers["Retry-After"] == "5"
    ex.note("GET", "/api/v1/faults/stream", r)
    # every fault route answered, and refused as documented
    seen = ex.seen
    assert seen["GET /faults"] == {200, 400} and seen["DELETE /faults"] == {204, 400, 401}
    assert seen["GET /faults/stream"] == {200, 503}
    for collection in ("apps", "components", "functions"):
        param = "{" + collection[:-1] + "_id}"
        assert seen[f"GET /{collection}/{param}/faults"] == {200, 400, 404}
        assert seen[f"DELETE /{collection}/{param}/faults"] == {204, 400, 401, 404}
        assert seen[f"GET /{collection}/{param}/faults/{{fault_code}}"] == {200, 400, 404}
        assert seen[f"DELETE /{collection}/{param}/faults/{{fault_code}}"] == {204, 400, 401, 404}
