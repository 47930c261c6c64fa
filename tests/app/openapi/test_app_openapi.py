"""Real responses of every route validate against the OpenAPI 3.1 document (GET /api/v1/docs).

Every documented operation is exercised, and every status a request gets must
be documented for its operation (or fall under ``default``).
"""

from __future__ import annotations

import ast
import importlib

import jsonschema
import pytest

from app import openapi
from common.harness.procs import REPO
from tests.app.openapi.answers import TEMPERATURE, TOKEN, Exercise, part_operations, parts
from tests.support.fakeworker import ROBOT, FakeWorker, data_sample, make_app


@pytest.fixture(scope="module")
def doc():
    return openapi.document()


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


def test_the_parts_of_the_document_hold_every_operation_once(doc):
    """The parts the next test exercises one by one (the core's, auth's, audit's, each family's spec) are the
    whole document, and no operation is in two of them."""
    documented = {f"{m.upper()} {p}" for p, ops in doc["paths"].items() for m in ops}
    owners: dict[str, list[str]] = {}
    for name in parts():
        for op in part_operations(name):
            owners.setdefault(op, []).append(name)
    assert set(owners) == documented, f"in no part: {documented - set(owners)}; not documented: {set(owners) - documented}"
    assert not {op: names for op, names in owners.items() if len(names) > 1}


@pytest.mark.parametrize("part", sorted(parts()))
def test_every_route_answers_per_the_document(doc, part):
    """Every operation of each part is exercised by the tests of its folder: tests/app/<part>/openapi_routes.py's
    ``exercise(ex)`` on a fake ROS worker, or the real gateway's test its ``EXERCISED_BY`` names for the
    operations its ``elsewhere(op)`` gives.  Every status a request got is documented for its operation."""
    try:
        routes = importlib.import_module(f"tests.app.{part}.openapi_routes")
    except ModuleNotFoundError as e:
        pytest.fail(f"tests/app/{part}/openapi_routes.py: exercise(ex) must answer the routes of its spec ({e})")
    with FakeWorker() as fw:
        fw.set_graph(list(ROBOT))
        fw.samples[TEMPERATURE] = data_sample(TEMPERATURE, "sensor_msgs/msg/Temperature", {"temperature": 93.5})
        fw.type_infos["sensor_msgs/msg/Temperature"] = {"schema": {"type": "object"},
                                                        "default_value": {"temperature": 0.0}}
        # (no failure limit: this test sends more bad tokens from one address than it lets through)
        client = make_app(fw, allow_publish=True, allow_configurations=True, allow_fault_clear=True, api_token=TOKEN,
                          auth_failure_limit="", max_body_bytes=1024).test_client()
        ex = Exercise(doc, fw, client)
        routes.exercise(ex)
    own = part_operations(part)
    elsewhere = {op for op in own if getattr(routes, "elsewhere", lambda op: False)(op)}
    if elsewhere:  # the real gateway's test: it asserts that it answers exactly these (elsewhere())
        file, name = routes.EXERCISED_BY.split("::")
        defined = {node.name for node in ast.walk(ast.parse((REPO / file).read_text())) if isinstance(node, ast.FunctionDef)}
        assert name in defined, f"{routes.EXERCISED_BY}: no such test"
    assert own - elsewhere <= set(ex.seen), f"not exercised: {sorted(own - elsewhere - set(ex.seen))}"


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
