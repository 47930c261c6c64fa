"""Real responses of every route validate against the OpenAPI 3.1 document (GET /api/v1/docs).

Every documented operation is exercised, and every status a request gets must
be documented for its operation (or fall under ``default``).
"""

from __future__ import annotations

import re

import jsonschema
import pytest

from app import openapi
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
    rel = path.split("?", 1)[0][len("/api/v1"):]
    matches = [t for t in doc["paths"] if _template_regex(t).fullmatch(rel)]
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
    schema = spec["content"]["application/json"]["schema"]
    assert response.headers["Content-Type"] == "application/json"
    validator = jsonschema.Draft202012Validator({**schema, "components": doc["components"]})
    errors = sorted(validator.iter_errors(response.get_json()), key=str)
    assert not errors, f"{key} {status}: " + "; ".join(e.message for e in errors[:5])
    return key


def test_schemas_are_valid_json_schema(doc):
    for schema in doc["components"]["schemas"].values():
        jsonschema.Draft202012Validator.check_schema(schema)  # raises, naming the problem
    assert doc["openapi"] == "3.1.0"


def test_every_route_answers_per_the_document(doc):
    with FakeWorker() as fw:
        fw.set_graph(list(ROBOT))
        fw.samples["/powertrain/engine/temperature"] = data_sample(
            "/powertrain/engine/temperature", "sensor_msgs/msg/Temperature", {"temperature": 93.5})
        fw.type_infos["sensor_msgs/msg/Temperature"] = {"schema": {"type": "object"},
                                                        "default_value": {"temperature": 0.0}}
        client = make_app(fw, allow_publish=True, api_token=TOKEN, max_body_bytes=1024).test_client()
        auth = {"Authorization": f"Bearer {TOKEN}"}
        requests: list[tuple[str, str, dict]] = [
            ("GET", "/api/v1/", {}), ("GET", "/api/v1/version-info", {}), ("GET", "/api/v1/health", {}),
            ("GET", "/api/v1/docs", {}),
            ("GET", "/api/v1/apps/temp_sensor/is-located-on", {}),
            ("GET", "/api/v1/apps/nope/is-located-on", {}),
            ("GET", "/api/v1/apps/b.d/is-located-on", {}),
        ]
        for collection, eid in ENTITY.items():
            base = f"/api/v1/{collection}"
            target = eid or "nope"
            requests += [
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
                 {"json": {"type": "bad", "data": {}}, "headers": auth}),
                ("PUT", f"{base}/{target}/data/body/lights/cmd",
                 {"json": {"type": "std_msgs/msg/String", "data": {"data": "x" * 2000}}, "headers": auth}),
            ]
        seen: dict[str, set[int]] = {}
        for method, path, kw in requests:
            r = client.open(path, method=method, **kw)
            key = check(doc, method, path, r)
            seen.setdefault(key, set()).add(r.status_code)

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
        fw.stop()
        for path in ("/api/v1/health", "/api/v1/apps", "/api/v1/apps/temp_sensor"):
            check(doc, "GET", path, client.get(path))

    documented = {f"{m.upper()} {p}" for p, ops in doc["paths"].items() for m in ops}
    assert documented == set(seen), f"not exercised: {documented - set(seen)}"
    # Successes of entity routes were seen for every collection that has entities.
    assert 200 in seen["GET /apps/{app_id}/data/{data_id}"]
    assert 200 in seen["PUT /functions/{function_id}/data/{data_id}"]
    assert {400, 401, 403, 413} <= seen["PUT /components/{component_id}/data/{data_id}"]
