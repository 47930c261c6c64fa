"""Real responses of every route validate against the OpenAPI 3.1 document (GET /api/v1/docs).

Every documented operation is exercised, and every status a request gets must
be documented for its operation (or fall under ``default``).
"""

from __future__ import annotations

import io
import os
import re
import tempfile

import jsonschema
import pytest

from app import openapi
from app.core import unimplemented
from app.core.entities import RELATIONS
from app.sse.hub import hub_of
from ipc.errors import IpcError
from tests.support.fakeworker import ROBOT, FakeWorker, data_sample, make_app

TOKEN = "s3cret-token-0123456789"
PUT_BODY = {"type": "std_msgs/msg/Bool", "data": {"data": True}}
ENTITY = {"areas": None, "components": "test-robot", "apps": "temp_sensor", "functions": "powertrain"}


@pytest.fixture(scope="module")
def doc():
    return openapi.document()


def _template_regex(template: str) -> re.Pattern:
    parts = re.split(r"(\{[^}]+\})", template)
    out = ""
    for part in parts:
        if part == "{data_id}":
            out += r"[\s\S]*"
        elif part.startswith("{"):
            out += "[^/]+"
        else:
            out += re.escape(part)
    return re.compile(out)


def operation(doc, method: str, path: str) -> tuple[str, dict]:
    path = path.split("?", 1)[0]
    # Paths under the API base are relative to it; an operation with a server of its own
    # (GET /metrics) is matched by its whole path.
    rel = path[len("/api/v1"):] if path == "/api/v1" or path.startswith("/api/v1/") else path
    matches = [t for t in doc["paths"] if _template_regex(t).fullmatch(rel)]
    # OpenAPI: concrete paths match before templated ones (`/apps/docs` before `/apps/{app_id}`).
    fewest = min((t.count("{") for t in matches), default=0)
    matches = [t for t in matches if t.count("{") == fewest]
    assert len(matches) == 1, f"{path} matches {matches}"
    ops = doc["paths"][matches[0]]
    assert method.lower() in ops, f"{method} {matches[0]} is not documented"
    return f"{method.upper()} {matches[0]}", ops[method.lower()]


def resolve(doc, node: dict) -> dict:
    while "$ref" in node and node["$ref"].startswith("#/components/responses/"):
        node = doc["components"]["responses"][node["$ref"].rsplit("/", 1)[1]]
    return node


def check(doc, method: str, path: str, response) -> str:
    key, op = operation(doc, method, path)
    status = str(response.status_code)
    documented = op["responses"].get(status) or op["responses"].get("default")
    if status not in op["responses"]:
        # `default` only covers errors: a success code must be listed.
        assert response.status_code >= 400, f"{key} answered {status}, which is not documented"
    spec = resolve(doc, documented)
    if "content" not in spec:  # 204: no body at all
        assert response.data == b"", f"{key} {status} has a body"
        return key
    if "application/json" not in spec["content"]:  # text (the metrics)
        binary = all(c["schema"].get("format") == "binary" for c in spec["content"].values())  # a file's own type
        assert binary or any(response.headers["Content-Type"].startswith(kind) for kind in spec["content"]), key
        return key
    schema = spec["content"]["application/json"]["schema"]
    assert response.headers["Content-Type"] == "application/json"
    validator = jsonschema.Draft202012Validator({**schema, "components": doc["components"]})
    errors = sorted(validator.iter_errors(response.get_json()), key=str)
    assert not errors, f"{key} {status}: " + "; ".join(e.message for e in errors[:5])
    return key


def _exercise_bulk_data(doc, fw, seen: dict, auth: dict) -> None:
    """Bulk data (issue 32): every route and its statuses, a recording on disk as the ROS worker lists it
    (the real recordings: tests/system/bulk_data/test_bulk_data.py)."""
    with tempfile.TemporaryDirectory() as tmp:
        bag = os.path.join(tmp, "fault_HOT_1.mcap")
        with open(bag, "wb") as fh:
            fh.write(b"\x89MCAP0\r\n" + bytes(range(256)))
        recording = {"id": "fault_HOT_1", "format": "mcap", "fault_codes": ["HOT"],
                     "sources": {"HOT": ["/powertrain/engine/temp_sensor"]}, "created_ns": 1_700_000_000_000_000_000,
                     "started_ns": 1, "ended_ns": 2, "duration_sec": 1.5, "messages": 3, "path": bag, "size": 264,
                     "topics": [{"topic": "/powertrain/engine/temperature", "type": "sensor_msgs/msg/Temperature"}]}
        fw.replies = {**getattr(fw, "replies", {}), "bulk_rosbags": {"items": [recording]},
                      "bulk_rosbag_get": lambda args: recording if args["id"] == "fault_HOT_1" else
                      IpcError("no-such-recording", "Bulk-data not found", {"bulk_data_id": args["id"]}),
                      "fault_list": {"items": []}}
        client = make_app(fw, allow_bulk_data=True, api_token=TOKEN, bulk_data_categories="calibration",
                          bulk_data_storage_dir=os.path.join(tmp, "files"), bulk_data_max_upload_size=1000,
                          bulk_data_max_total_mb=1).test_client()
        off = make_app(fw, bulk_data_categories="calibration", bulk_data_storage_dir=os.path.join(tmp, "files"),
                       ).test_client()
        upload = {"data": {"file": (io.BytesIO(b"calibrated"), "cal.bin")}, "content_type": "multipart/form-data"}
        made = client.post("/api/v1/apps/temp_sensor/bulk-data/calibration", headers=auth,
                           **{**upload, "data": {"file": (io.BytesIO(b"calibrated"), "cal.bin")}})
        assert made.status_code == 201, made.data
        for collection, eid in ENTITY.items():
            base = f"/api/v1/{collection}/{eid or 'nope'}/bulk-data"
            requests = [("GET", base, {}), ("GET", f"/api/v1/{collection}/bad.id/bulk-data", {}),
                        ("GET", base + "/rosbags", {}), ("GET", base + "/nope", {}), ("GET", base + "/..%2Fx", {}),
                        ("GET", base + "/rosbags/fault_HOT_1", {}),
                        ("GET", base + "/rosbags/fault_HOT_1", {"headers": {"Range": "bytes=0-9"}}),
                        ("GET", base + "/rosbags/fault_HOT_1", {"headers": {"Range": "bytes=999-"}}),
                        ("GET", base + "/rosbags/fault_NONE_1", {}), ("GET", base + "/rosbags/..%2F..%2Fx", {}),
                        ("GET", base + "/calibration", {}), ("GET", base + "/calibration/nope_1", {})]
            if collection in ("areas", "components"):
                sub = f"{base[:-len('/bulk-data')]}/{'subareas' if collection == 'areas' else 'subcomponents'}/s"
                requests += [("GET", sub + "/bulk-data", {}), ("GET", sub + "/bulk-data/rosbags", {}),
                             ("GET", sub + "/bulk-data/rosbags/fault_HOT_1", {})]
            if collection in ("apps", "components"):
                item = f"{base}/calibration/{made.get_json()['id']}" if collection == "apps" else base + "/calibration/x_1"
                requests += [("GET", item, {}),
                             ("POST", base + "/calibration", {**upload, "headers": auth}),
                             ("POST", base + "/calibration", {**upload}),
                             ("POST", base + "/calibration", {**upload, "headers": {"Authorization": "Bearer no"}}),
                             ("POST", base + "/rosbags", {**upload, "headers": auth}),
                             ("POST", base + "/nope", {**upload, "headers": auth}),
                             ("POST", base + "/calibration", {"data": b"x", "content_type": "text/plain",
                                                              "headers": auth}),
                             ("POST", base + "/calibration", {"data": {"file": (io.BytesIO(b"x" * 2000), "big")},
                                                              "content_type": "multipart/form-data", "headers": auth}),
                             ("DELETE", item, {"headers": auth}), ("DELETE", item, {"headers": auth}),
                             ("DELETE", item, {}), ("DELETE", base + "/rosbags/fault_HOT_1", {"headers": auth})]
            for method, path, kw in requests:
                if "data" in kw and isinstance(kw["data"], dict):  # a fresh file object per request
                    kw = {**kw, "data": {k: (io.BytesIO(v[0].getvalue()), v[1]) for k, v in kw["data"].items()}}
                r = client.open(path, method=method, **kw)
                check(doc, method, path, r)
                seen.setdefault(operation(doc, method, path)[0], set()).add(r.status_code)
            r = off.post(base + "/calibration", **{**upload, "data": {"file": (io.BytesIO(b"x"), "x")}})
            assert collection not in ("apps", "components") or r.status_code == 403, r.data
        del fw.replies["bulk_rosbags"], fw.replies["bulk_rosbag_get"], fw.replies["fault_list"]
    for statuses in (seen["GET /apps/{app_id}/bulk-data/{category_id}/{file_id}"],
                     seen["POST /apps/{app_id}/bulk-data/{category_id}"]):
        assert len(statuses) >= 3, statuses


def test_schemas_are_valid_json_schema(doc):
    for schema in doc["components"]["schemas"].values():
        jsonschema.Draft202012Validator.check_schema(schema)  # raises, naming the problem
    assert doc["openapi"] == "3.1.0"


def test_every_tag_an_operation_uses_is_declared(doc):
    """An OpenAPI tag an operation names is declared once in the top-level ``tags`` (generators group by it)."""
    declared = [t["name"] for t in doc["tags"]]
    used = {tag for path in doc["paths"].values() for op in path.values() for tag in op["tags"]}
    assert len(declared) == len(set(declared))
    assert used <= set(declared), sorted(used - set(declared))
    assert "Configuration" in used


def test_names_generated_clients_see_are_medkits(doc):
    """The names medkit's published spec gives, which generated clients import."""
    assert doc["info"]["x-sovd-version"] == "1.0.0"
    assert doc["components"]["responses"]["GenericError"]["content"]["application/json"]["schema"] == {
        "$ref": "#/components/schemas/GenericError"}
    assert {"GenericError", "ComponentList", "ComponentListItem", "ComponentDetail", "AppList", "AppListItem",
            "AppDetail", "AreaList", "AreaDetail", "FunctionList", "FunctionDetail", "XMedkitApp",
            "XMedkitCollection", "DataItem", "DataList", "DataValue", "DataWriteRequest", "HealthStatus",
            "RootOverview", "VersionInfo"} <= set(doc["components"]["schemas"])
    ops = {f"{m.upper()} {p}": (op["operationId"], op["tags"]) for p, path in doc["paths"].items()
           for m, op in path.items()}
    assert ops["GET /components"] == ("listComponents", ["Discovery"])
    assert ops["GET /apps/{app_id}"] == ("getApp", ["Discovery"])
    assert ops["GET /apps/{app_id}/is-located-on"] == ("getAppHost", ["Discovery"])
    assert ops["GET /apps/{app_id}/belongs-to"] == ("getAppArea", ["Discovery"])
    assert ops["GET /apps/{app_id}/depends-on"] == ("listAppDependencies", ["Discovery"])
    assert ops["GET /components/{component_id}/hosts"] == ("listComponentHosts", ["Discovery"])
    assert ops["GET /components/{component_id}/subcomponents"] == ("listSubcomponents", ["Discovery"])
    assert ops["GET /components/{component_id}/depends-on"] == ("listComponentDependencies", ["Discovery"])
    assert ops["GET /functions/{function_id}/hosts"] == ("listFunctionHosts", ["Discovery"])
    assert ops["GET /areas/{area_id}/contains"] == ("listAreaContains", ["Discovery"])
    assert ops["GET /apps/{app_id}/data"] == ("listAppData", ["Data"])
    assert ops["GET /apps/{app_id}/data/{data_id}"] == ("getAppDataItem", ["Data"])
    assert ops["PUT /components/{component_id}/data/{data_id}"] == ("putComponentDataItem", ["Data"])
    assert ops["GET /health"] == ("getHealth", ["Server"])
    # faults (issue 22): medkit's names (ros2_medkit_clients spec/openapi.yaml)
    assert ops["GET /faults"] == ("listAllFaults", ["Faults"]) and ops["DELETE /faults"][0] == "clearAllFaults"
    assert ops["GET /faults/stream"] == ("streamFaults", ["Faults"])
    assert ops["GET /apps/{app_id}/faults"][0] == "listAppFaults"
    assert ops["DELETE /components/{component_id}/faults"][0] == "clearAllComponentFaults"
    assert ops["GET /functions/{function_id}/faults/{fault_code}"][0] == "getFunctionFault"
    assert ops["DELETE /apps/{app_id}/faults/{fault_code}"][0] == "clearAppFault"
    assert {"FaultList", "FaultListItem", "FaultDetail"} <= set(doc["components"]["schemas"])
    assert len({op_id for op_id, _ in ops.values()}) == len(ops)  # operationIds are unique
    # Every error response is the one GenericError response.
    for path in doc["paths"].values():
        for op in path.values():
            for status, response in op["responses"].items():
                if status == "default" or int(status) >= 400:
                    assert response["$ref"] == "#/components/responses/GenericError", (op["operationId"], status)
                    assert response["description"]


def test_every_route_answers_per_the_document(doc):
    with FakeWorker() as fw:
        fw.set_graph(list(ROBOT))
        fw.samples["/powertrain/engine/temperature"] = data_sample(
            "/powertrain/engine/temperature", "sensor_msgs/msg/Temperature", {"temperature": 93.5})
        fw.type_infos["sensor_msgs/msg/Temperature"] = {"schema": {"type": "object"},
                                                        "default_value": {"temperature": 0.0}}
        # (no failure limit: this test sends more bad tokens from one address than it lets through)
        client = make_app(fw, allow_publish=True, allow_configurations=True, allow_fault_clear=True, api_token=TOKEN,
                          auth_failure_limit="",
                          max_body_bytes=1024).test_client()
        auth = {"Authorization": f"Bearer {TOKEN}"}
        requests: list[tuple[str, str, dict]] = [
            ("GET", "/api/v1/", {}), ("GET", "/api/v1/version-info", {}), ("GET", "/api/v1/health", {}),
            ("GET", "/api/v1/docs", {}), ("GET", "/metrics", {}),
        ]
        for collection, relation in RELATIONS:
            base = f"/api/v1/{collection}"
            requests += [("GET", f"{base}/{ENTITY[collection] or 'nope'}/{relation}", {}),
                         ("GET", f"{base}/nope/{relation}", {}), ("GET", f"{base}/b.d/{relation}", {})]
        for collection, eid in ENTITY.items():
            base = f"/api/v1/{collection}"
            target = eid or "nope"
            requests += [
                ("GET", f"{base}/docs", {}),
                ("GET", f"{base}/{target}/docs", {}),
                ("GET", f"{base}/{target}/data/docs", {}),
                ("GET", base, {}),
                ("GET", f"{base}/{target}", {}),
                ("GET", f"{base}/bad.id", {}),
                ("GET", f"{base}/nope", {}),
                ("GET", f"{base}/{target}/data", {}),
                ("GET", f"{base}/{target}/data/powertrain/engine/temperature", {}),
                ("GET", f"{base}/{target}/data/powertrain%2Fengine%2Ftemperature?bytes=base64", {}),
                ("GET", f"{base}/{target}/data//not/sampled/yet", {}),
                ("GET", f"{base}/{target}/data/bad-topic", {}),
                ("GET", f"{base}/{target}/data/x?bytes=hex", {}),
                ("GET", f"{base}/{target}/data-categories", {}),
                ("GET", f"{base}/{target}/data-groups", {}),
                ("PUT", f"{base}/{target}/data/body/lights/cmd", {"json": PUT_BODY, "headers": auth}),
                ("PUT", f"{base}/{target}/data/body/lights/cmd", {"json": PUT_BODY}),
                ("PUT", f"{base}/{target}/data/body/lights/cmd",
                 {"json": PUT_BODY, "headers": {"Authorization": "Bearer wrong"}}),
                ("PUT", f"{base}/{target}/data/body/lights/cmd", {"data": b"nope", "headers": auth}),
                ("PUT", f"{base}/{target}/data/body/lights/cmd",
                 {"json": PUT_BODY, "headers": {**auth, "Content-Type": "text/plain"}}),
                ("PUT", f"{base}/{target}/data/body/lights/cmd",
                 {"json": {"type": "bad", "data": {}}, "headers": auth}),
                ("PUT", f"{base}/{target}/data/body/lights/cmd",
                 {"json": {"type": "std_msgs/msg/String", "data": {"data": "x" * 2000}}, "headers": auth}),
            ]
        seen: dict[str, set[int]] = {}
        for method, path, kw in requests:
            r = client.open(path, method=method, **kw)
            key = check(doc, method, path, r)
            seen.setdefault(key, set()).add(r.status_code)

        # Cyclic subscriptions (their event streams' 200 is text/event-stream: tests/system/subscriptions/test_app_streams.py).
        for collection in ("apps", "components", "functions"):
            base = f"/api/v1/{collection}/{ENTITY[collection]}/cyclic-subscriptions"
            resource = f"/api/v1/{collection}/{ENTITY[collection]}/data/powertrain/engine/temperature"
            good = {"resource": resource, "interval": "fast", "duration": 30}
            made = client.post(base, json=good, headers=auth)
            sub = f"{base}/{made.get_json()['id']}"
            wrong = {"Authorization": "Bearer wrong"}
            for method, path, kw in [
                ("POST", base, {"json": good, "headers": auth}),
                ("POST", base, {"json": {**good, "interval": "hourly"}, "headers": auth}),
                ("POST", base, {"json": {**good, "resource": "/api/v1/apps/x/faults"}, "headers": auth}),
                ("POST", f"/api/v1/{collection}/nope/cyclic-subscriptions", {"json": good, "headers": auth}),
                ("POST", base, {"json": good}), ("POST", base, {"json": good, "headers": wrong}),
                ("GET", base, {}), ("GET", f"/api/v1/{collection}/bad.id/cyclic-subscriptions", {}),
                ("GET", sub, {}), ("GET", base + "/sub_0000000000000000", {}),
                ("POST", base, {"data": b"{}", "content_type": "text/plain", "headers": auth}),
                ("PUT", sub, {"json": {"interval": "slow"}, "headers": auth}),
                ("PUT", sub, {"json": {"duration": -1}, "headers": auth}),
                ("PUT", sub, {"data": b'{"interval": "slow"}', "content_type": "text/plain", "headers": auth}),
                ("PUT", base + "/sub_0000000000000000", {"json": {"interval": "slow"}, "headers": auth}),
                ("PUT", sub, {"json": {"interval": "slow"}}), ("PUT", sub, {"json": {"interval": "slow"},
                                                                             "headers": wrong}),
                ("GET", base + "/sub_0000000000000000/events", {}),
                ("DELETE", sub, {}), ("DELETE", sub, {"headers": wrong}),
                ("DELETE", sub, {"headers": auth}), ("DELETE", sub, {"headers": auth}),
            ]:
                r = client.open(path, method=method, **kw)
                check(doc, method, path, r)
                seen.setdefault(operation(doc, method, path)[0], set()).add(r.status_code)
        # logs (issue 22): app/logs/routes.py
        for collection in ("apps", "components", "functions"):
            base = f"/api/v1/{collection}/{ENTITY[collection]}/logs"
            for method, path, kw in [
                ("GET", base, {}), ("GET", base + "?severity=loud", {}), ("GET", f"/api/v1/{collection}/nope/logs", {}),
                ("GET", base + "/configuration", {}), ("GET", f"/api/v1/{collection}/b.d/logs/configuration", {}),
                ("PUT", base + "/configuration", {"json": {"max_entries": 5}, "headers": auth}),
                ("PUT", base + "/configuration", {"json": {"max_entries": 0}, "headers": auth}),
                ("PUT", base + "/configuration", {"json": {"max_entries": 5}}),
                ("PUT", base + "/configuration", {"json": {}, "headers": {"Authorization": "Bearer wrong"}}),
                ("PUT", base + "/configuration", {"data": b"{}", "content_type": "text/plain", "headers": auth}),
            ]:
                r = client.open(path, method=method, **kw)
                check(doc, method, path, r)
                seen.setdefault(operation(doc, method, path)[0], set()).add(r.status_code)
        # faults (issue 22): app/faults/routes.py, over the ROS worker's answers (rosworker/faults/manager.py::public)
        fault = {"fault_code": "TEMP_SENSOR_HOT", "severity": 2, "severity_label": "ERROR", "description": "hot",
                 "first_occurred": 1700000000.5, "last_occurred": 1700000001.5, "occurrence_count": 1,
                 "status": "CONFIRMED", "reporting_sources": ["/powertrain/engine/temp_sensor"]}
        frame = {"type": "freeze_frame", "name": "temp_sensor: hot", "topic": "", "message_type": "",
                 "captured_at_ns": 1700000001000000000, "data": '{"celsius": "93.5"}'}
        fw.replies = {
            "fault_list": {"items": [fault, {**fault, "fault_code": "ELSEWHERE", "reporting_sources": ["/other"]}]},
            "fault_get": lambda args: (IpcError("no-such-fault", "Fault not found", {"fault_code": args["code"]})
                                       if args["code"] != fault["fault_code"] else
                                       {"fault": fault, "snapshots": [frame], "first_ns": 1700000000500000000,
                                        "last_ns": 1700000001500000000}),
            "fault_clear": {"cleared": [fault["fault_code"]]},
        }
        wrong = {"Authorization": "Bearer wrong"}
        faults = [("GET", "/api/v1/faults", {}), ("GET", "/api/v1/faults?status=all", {}),
                  ("GET", "/api/v1/faults?status=loud", {}), ("DELETE", "/api/v1/faults", {"headers": auth}),
                  ("DELETE", "/api/v1/faults?status=loud", {"headers": auth}), ("DELETE", "/api/v1/faults", {}),
                  ("DELETE", "/api/v1/faults", {"headers": wrong})]
        for collection in ("apps", "components", "functions"):
            base = f"/api/v1/{collection}/{ENTITY[collection]}/faults"
            one, elsewhere = base + "/TEMP_SENSOR_HOT", base + "/ELSEWHERE"
            faults += [
                ("GET", base, {}), ("GET", base + "?status=cleared", {}), ("GET", base + "?status=x", {}),
                ("GET", f"/api/v1/{collection}/nope/faults", {}), ("GET", f"/api/v1/{collection}/b.d/faults", {}),
                ("DELETE", base, {"headers": auth}), ("DELETE", base + "?status=x", {"headers": auth}),
                ("DELETE", base, {}), ("DELETE", base, {"headers": wrong}),
                ("DELETE", f"/api/v1/{collection}/nope/faults", {"headers": auth}),
                ("GET", one, {}), ("GET", base + "/NO_SUCH", {}), ("GET", elsewhere, {}),
                ("GET", base + "/" + "A" * 300, {}),
                ("DELETE", one, {"headers": auth}), ("DELETE", one, {}), ("DELETE", one, {"headers": wrong}),
                ("DELETE", elsewhere, {"headers": auth}), ("DELETE", base + "/" + "A" * 300, {"headers": auth}),
            ]
        for method, path, kw in faults:
            r = client.open(path, method=method, **kw)
            check(doc, method, path, r)
            seen.setdefault(operation(doc, method, path)[0], set()).add(r.status_code)
        r = client.get("/api/v1/faults/stream")  # the head only: events are tests/system/faults/test_app_faults.py's
        assert r.status_code == 200
        seen.setdefault(check(doc, "GET", "/api/v1/faults/stream", r), set()).add(r.status_code)
        r.close()
        hub = hub_of("faults", client.application)
        held = [object() for _ in range(16)]  # max_fault_streams (16) streams open in this HTTP worker
        hub.streams.update(held)
        r = client.get("/api/v1/faults/stream")
        hub.streams.difference_update(held)
        assert r.status_code == 503 and r.headers["Retry-After"] == "5"
        seen.setdefault(check(doc, "GET", "/api/v1/faults/stream", r), set()).add(r.status_code)
        # Triggers (their event streams' 200 is text/event-stream: tests/app/triggers/test_app_triggers.py).
        for collection in ("apps", "components", "functions"):
            base = f"/api/v1/{collection}/{ENTITY[collection]}/triggers"
            resource = f"/api/v1/{collection}/{ENTITY[collection]}/data/powertrain/engine/temperature"
            good = {"resource": resource, "trigger_condition": {"condition_type": "OnChange"}, "lifetime": 30}
            made = client.post(base, json=good, headers=auth)
            trig = f"{base}/{made.get_json()['id']}"
            wrong = {"Authorization": "Bearer wrong"}
            unknown = base + "/trig_0000000000000000"
            for method, path, kw in [
                ("POST", base, {"json": good, "headers": auth}),
                ("POST", base, {"json": {**good, "trigger_condition": {}}, "headers": auth}),
                ("POST", base, {"json": {**good, "resource": "/api/v1/apps/x/data/t"}, "headers": auth}),
                ("POST", base, {"json": {**good, "resource": "/api/v1/apps/x/../data/t"}, "headers": auth}),
                ("POST", f"/api/v1/{collection}/nope/triggers", {"json": good, "headers": auth}),
                ("POST", base, {"json": good}), ("POST", base, {"json": good, "headers": wrong}),
                ("POST", base, {"data": b"{}", "content_type": "text/plain", "headers": auth}),
                ("GET", base, {}), ("GET", f"/api/v1/{collection}/bad.id/triggers", {}),
                ("GET", trig, {}), ("GET", unknown, {}),
                ("PUT", trig, {"json": {"lifetime": 60}, "headers": auth}),
                ("PUT", trig, {"json": {"lifetime": 0}, "headers": auth}),
                ("PUT", trig, {"data": b'{"lifetime": 5}', "content_type": "text/plain", "headers": auth}),
                ("PUT", unknown, {"json": {"lifetime": 60}, "headers": auth}),
                ("PUT", trig, {"json": {"lifetime": 60}}), ("PUT", trig, {"json": {"lifetime": 60}, "headers": wrong}),
                ("GET", unknown + "/events", {}),
                ("DELETE", trig, {}), ("DELETE", trig, {"headers": wrong}),
                ("DELETE", trig, {"headers": auth}), ("DELETE", trig, {"headers": auth}),
            ]:
                r = client.open(path, method=method, **kw)
                check(doc, method, path, r)
                seen.setdefault(operation(doc, method, path)[0], set()).add(r.status_code)
        fw.errors["trig_create"] = IpcError("triggers-full", "full", {"max_triggers": 1000})
        r = client.post("/api/v1/apps/temp_sensor/triggers", json={
            "resource": "/api/v1/apps/temp_sensor/data/x", "trigger_condition": {"condition_type": "OnChange"}},
            headers=auth)
        assert r.status_code == 503 and r.headers["Retry-After"] == "5"
        check(doc, "POST", "/api/v1/apps/temp_sensor/triggers", r)
        # medkit's routes not served here: 501 whatever the ids (app/core/unimplemented.py); a write
        # is asked for its token first, as every write (app/auth/).
        for route, path, _ in unimplemented.paths():
            concrete = "/api/v1" + re.sub(r"\{[^}]+\}", "x1", path)
            r = client.open(concrete, method=route.method, headers=auth if route.method != "GET" else {})
            assert r.status_code == 501, (route.method, concrete, r.data)
            seen.setdefault(check(doc, route.method, concrete, r), set()).add(r.status_code)
        fw.errors["sub_create"] = IpcError("subscriptions-full", "full", {"max_subscriptions": 1000})
        r = client.post("/api/v1/apps/temp_sensor/cyclic-subscriptions", json={
            "resource": "/api/v1/apps/temp_sensor/data/x", "interval": "slow", "duration": 5}, headers=auth)
        assert r.status_code == 503
        check(doc, "POST", "/api/v1/apps/temp_sensor/cyclic-subscriptions", r)

        # The ROS worker's troubles, as documented.
        fw.errors["sample"] = IpcError("cold-wait-cap-exceeded", "cap", {"topic": "/x", "cold_wait_cap": 4})
        r = client.get("/api/v1/apps/temp_sensor/data/x")
        assert r.status_code == 503
        check(doc, "GET", "/api/v1/apps/temp_sensor/data/x", r)
        fw.errors["publish"] = IpcError("type-not-installed", "not installed")
        r = client.put("/api/v1/apps/temp_sensor/data/x", json=PUT_BODY, headers=auth)
        assert r.status_code == 400
        check(doc, "PUT", "/api/v1/apps/temp_sensor/data/x", r)
        fw.errors["sample"] = IpcError("deadline-exceeded", "late")
        r = client.get("/api/v1/apps/temp_sensor/data/x")
        assert r.status_code == 504
        check(doc, "GET", "/api/v1/apps/temp_sensor/data/x", r)
        # Configurations (with real nodes: tests/system/configurations/test_configurations.py).
        param = {"name": "rate", "value": 1.0, "type": "double"}
        fw.replies = {
            "param_list": lambda args: {"nodes": {n: {"ok": True, "parameters": [param]} for n in args["nodes"]}},
            "param_get": {**param, "description": "", "read_only": False},
            "param_set": param, "param_reset": {},
            "param_reset_all": lambda args: {"nodes": {n: {"ok": True, "result": {
                "reset": [], "failed": [{"name": "mode", "reason": "locked"}]}} for n in args["nodes"]}},
        }
        for collection in ("apps", "components", "functions"):
            base = f"/api/v1/{collection}/{ENTITY[collection]}/configurations"
            item = base + ("/rate" if collection != "components" else "/temp_sensor:rate")
            for method, path, kw in [
                ("GET", base, {}), ("GET", f"/api/v1/{collection}/nope/configurations", {}),
                ("GET", item, {}), ("GET", base + "/" + "a" * 600, {}),
                ("PUT", item, {"json": {"data": 2.0}, "headers": auth}), ("PUT", item, {"json": {"data": 2.0}}),
                ("PUT", item, {"json": {"data": 2.0}, "headers": {"Authorization": "Bearer wrong"}}),
                ("PUT", item, {"json": {}, "headers": auth}),
                ("PUT", item, {"data": b'{"data": 1}', "content_type": "text/plain", "headers": auth}),
                ("PUT", item, {"json": {"data": "x" * 2000}, "headers": auth}),
                ("DELETE", item, {"headers": auth}), ("DELETE", item, {}),
                ("DELETE", base, {"headers": auth}), ("DELETE", base, {}),
            ]:
                r = client.open(path, method=method, **kw)
                check(doc, method, path, r)
                seen.setdefault(operation(doc, method, path)[0], set()).add(r.status_code)
        # GET .../status: ready (a plain node, the host component), notReady (a managed node not active), 404
        fw.replies = {**getattr(fw, "replies", {}), "lifecycle_state": {"managed": True, "state": "inactive"}}
        for path, answer in (("/api/v1/components/test-robot/status", "ready"),
                             ("/api/v1/apps/temp_sensor/status", "notReady"),
                             ("/api/v1/apps/nope/status", None), ("/api/v1/components/nope/status", None)):
            r = client.get(path)
            assert (r.status_code, r.get_json().get("status")) == ((200, answer) if answer else (404, None)), path
            check(doc, "GET", path, r)
            seen.setdefault(operation(doc, "GET", path)[0], set()).add(r.status_code)
        del fw.replies["lifecycle_state"]

        def answer(method: str, path: str, **kw) -> int:
            r = client.open(path, method=method, **kw)
            seen.setdefault(check(doc, method, path, r), set()).add(r.status_code)
            return r

        # who is acting (issue 31): the locks (the fake worker holds rosworker/locks/' table), the auth
        # routes (off on this gateway: 404; on in the app below), the audit trail
        for base in ("/api/v1/apps/temp_sensor/locks", "/api/v1/components/test-robot/locks"):
            me = {**auth, "X-Client-Id": "tester"}
            lock = answer("POST", base, json={"lock_expiration": 60, "scopes": ["data"]}, headers=me).get_json()
            answer("POST", base, json={"lock_expiration": 60}, headers={**auth, "X-Client-Id": "other"})  # 409
            answer("POST", base, json={"lock_expiration": 0}, headers=me)  # 400
            answer("GET", base, headers={"X-Client-Id": "tester"})
            answer("GET", f"{base}/{lock['id']}")
            answer("GET", f"{base}/lock_999")  # 404
            answer("PUT", f"{base}/{lock['id']}", json={"lock_expiration": 30}, headers=me)
            answer("PUT", f"{base}/{lock['id']}", json={"lock_expiration": 30}, headers={**auth, "X-Client-Id": "x"})
            answer("DELETE", f"{base}/{lock['id']}", headers={**auth, "X-Client-Id": "x"})  # 403
            answer("DELETE", f"{base}/{lock['id']}", headers=me)
        for path in ("/api/v1/auth/authorize", "/api/v1/auth/token", "/api/v1/auth/revoke"):
            answer("POST", path, json={})
        answer("GET", "/api/v1/auth/x-medkit-whoami", headers=auth)
        answer("GET", "/api/v1/auth/x-medkit-whoami")
        answer("GET", "/api/v1/x-medkit-audit?limit=2", headers=auth)
        answer("GET", "/api/v1/x-medkit-audit?status=9xx", headers=auth)
        answer("GET", "/api/v1/x-medkit-audit")  # 401
        secured = make_app(fw, auth_enabled=True, jwt_secret="s" * 32, auth_clients="op:op-secret:operator",
                           auth_failure_limit="")
        client, plain = secured.test_client(), client
        granted = answer("POST", "/api/v1/auth/authorize", json={
            "grant_type": "client_credentials", "client_id": "op", "client_secret": "op-secret"}).get_json()
        answer("POST", "/api/v1/auth/authorize", data="grant_type=client_credentials&client_id=op&client_secret=no",
               content_type="application/x-www-form-urlencoded")
        answer("POST", "/api/v1/auth/authorize", json={"grant_type": "password"})
        answer("POST", "/api/v1/auth/token", json={"grant_type": "refresh_token",
                                                   "refresh_token": granted["refresh_token"]})
        answer("POST", "/api/v1/auth/token", json={"grant_type": "refresh_token", "refresh_token": "no"})
        answer("GET", "/api/v1/auth/x-medkit-whoami", headers={"Authorization": f"Bearer {granted['access_token']}"})
        answer("POST", "/api/v1/auth/revoke", json={"token": granted["refresh_token"]})
        answer("POST", "/api/v1/auth/revoke", data=b"{", content_type="application/json")
        answer("GET", "/api/v1/x-medkit-audit", headers={"Authorization": f"Bearer {granted['access_token']}"})
        client = plain
        fw.errors["param_get"] = IpcError("node-unavailable", "did not respond", {"retry_after_s": 3})
        r = client.get("/api/v1/apps/temp_sensor/configurations/rate")
        assert r.status_code == 503 and r.headers["Retry-After"] == "3"
        check(doc, "GET", "/api/v1/apps/temp_sensor/configurations/rate", r)
        _exercise_bulk_data(doc, fw, seen, auth)
        fw.stop()
        for path in ("/api/v1/health", "/api/v1/apps", "/api/v1/apps/temp_sensor",
                     "/api/v1/components/test-robot/hosts", "/api/v1/apps/temp_sensor/docs"):
            check(doc, "GET", path, client.get(path))

    # The operations routes answer from real servers: they are exercised through the real gateway
    # (tests/system/operations/test_operations.py::test_answers_follow_the_openapi_document).
    documented = {f"{m.upper()} {p}" for p, ops in doc["paths"].items() for m in ops if "/operations" not in p}
    assert documented == set(seen), f"not exercised: {documented - set(seen)}"
    # Successes of entity routes were seen for every collection that has entities.
    assert 200 in seen["GET /apps/{app_id}/data/{data_id}"]
    assert 200 in seen["PUT /functions/{function_id}/data/{data_id}"]
    assert {400, 401, 413, 415} <= seen["PUT /components/{component_id}/data/{data_id}"]  # a wrong token: 401
    for op in ("POST /apps/{app_id}/cyclic-subscriptions", "PUT /apps/{app_id}/cyclic-subscriptions/{subscription_id}"):
        assert 415 in seen[op], op
    for collection, relation in RELATIONS:  # each relation answered, and refused both ways
        param = "{" + collection[:-1] + "_id}"
        expected = {400, 404} if collection == "areas" else {200, 400, 404}
        assert seen[f"GET /{collection}/{param}/{relation}"] == expected
    assert seen["GET /apps/{app_id}/data/docs"] == {200}
    assert seen["GET /areas/{area_id}/docs"] == {404}
    assert {200, 400, 401, 413, 415} <= seen["PUT /components/{component_id}/configurations/{config_id}"]
    assert {204, 401} <= seen["DELETE /apps/{app_id}/configurations/{config_id}"]
    assert {207, 401} <= seen["DELETE /functions/{function_id}/configurations"]
    # faults (issue 22): every fault route answered, and refused as documented
    assert seen["GET /faults"] == {200, 400} and seen["DELETE /faults"] == {204, 400, 401}
    assert seen["GET /faults/stream"] == {200, 503}
    for collection in ("apps", "components", "functions"):
        param = "{" + collection[:-1] + "_id}"
        assert seen[f"GET /{collection}/{param}/faults"] == {200, 400, 404}
        assert seen[f"DELETE /{collection}/{param}/faults"] == {204, 400, 401, 404}
        assert seen[f"GET /{collection}/{param}/faults/{{fault_code}}"] == {200, 400, 404}
        assert seen[f"DELETE /{collection}/{param}/faults/{{fault_code}}"] == {204, 400, 401, 404}


def test_every_operation_with_a_json_body_documents_the_body_errors(doc):
    """415 (not declared JSON), 413 (too large) and 408 (too slow): app/core/bodies.py, on every body."""
    with_body = [(method, path, op) for path, ops in doc["paths"].items() for method, op in ops.items()
                 if "requestBody" in op]
    # PUT data of 4 collections; POST and PUT cyclic-subscriptions of 3; POST and PUT executions of 3;
    # PUT configurations of 3; PUT logs/configuration of 3; POST and PUT triggers of 3; POST and PUT
    # locks of 2; the three POST /auth routes; POST bulk-data of 2
    assert len(with_body) == 37
    for method, path, op in with_body:
        if path.startswith("/auth/"):  # medkit's OAuth2 routes: a form too, and 400 for another type
            assert {"408", "413", "400"} <= set(op["responses"]), (method, path)
            assert "application/json" in op["requestBody"]["content"]
            continue
        multipart = "/bulk-data/" in path  # an upload (app/bulk_data/files.py)
        assert list(op["requestBody"]["content"]) == ["multipart/form-data" if multipart else "application/json"], \
            (method, path)
        assert {"408", "413", "415"} <= set(op["responses"]), (method, path)


def test_rate_limits_and_metrics_are_documented(doc):
    """429 on every rate-limited operation (all but health and metrics); GET /metrics beside the base."""
    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            if op["operationId"] in ("getHealth", "getMetrics"):
                assert "429" not in op["responses"], op["operationId"]
            else:
                assert op["responses"]["429"]["$ref"] == "#/components/responses/GenericError", (method, path)
    metrics = doc["paths"]["/metrics"]["get"]
    assert metrics["servers"] == [{"url": "/", "description": metrics["servers"][0]["description"]}]
    assert "text/plain" in metrics["responses"]["200"]["content"]
    headers = doc["components"]["responses"]["GenericError"]["headers"]
    assert {"Retry-After", "X-RateLimit-Limit", "X-RateLimit-Remaining", "X-RateLimit-Reset"} <= set(headers)
    assert "GET /metrics" in openapi.endpoint_list()


def test_every_operation_documents_a_success_with_its_schema(doc):
    """medkit's spec check (test_docs_spec_completeness): every operation has a 2xx response, and
    each 2xx but 204 says what its body is."""
    missing = []
    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            ok = {s: r for s, r in op["responses"].items() if s.startswith("2")}
            if not ok:
                missing.append(f"{method.upper()} {path}: no 2xx response")
            for status, response in ok.items():
                if status != "204" and "schema" not in next(iter(response.get("content", {}).values()), {}):
                    missing.append(f"{method.upper()} {path}: {status} without a schema")
    assert not missing, "\n".join(missing)


def test_the_success_check_catches_an_operation_without_one(doc):
    broken = {**doc, "paths": {**doc["paths"], "/x": {"get": {"responses": {"404": {}}}}}}
    with pytest.raises(AssertionError, match="GET /x: no 2xx response"):
        test_every_operation_documents_a_success_with_its_schema(broken)
