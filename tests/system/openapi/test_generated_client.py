"""A client generated from our ``/api/v1/docs`` works against the real gateway.

medkit's clients are generated with openapi-python-client from its published
spec; here the same generator builds a client from the document the running
gateway serves (into a tmp dir), and that client lists, reads and fails
through the real ``sovd-gateway`` and a real ROS publisher.  Every answer must
parse into the generated models, and the models must give back the very JSON
that was sent (nothing dropped, nothing misread).  The module and model names
are the ones code written against medkit's generated client imports.
"""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import requests

from app.core.entities import host_component_id
from common.harness.procs import poll_until
from tests.support.rospub import publisher

BIN = Path(sys.executable).parent
HOST_ID = host_component_id(os.uname().nodename)
TEMP = "/powertrain/engine/temperature"
PACKAGE = "sovd_generated_client"


@pytest.fixture(scope="module")
def robot():
    node = publisher("temp_sensor", "temperature", "sensor_msgs/msg/Temperature",
                     {"temperature": 93.5, "variance": 0.5, "header": {"frame_id": "engine"}},
                     namespace="/powertrain/engine")
    yield node
    node.stop()


@pytest.fixture(scope="module")
def gw(robot, gateway):
    return gateway()


@pytest.fixture(scope="module")
def sdk(gw, tmp_path_factory):
    """The generated package, imported from a tmp dir (and forgotten afterwards)."""
    tmp = tmp_path_factory.mktemp("generated")
    spec = tmp / "openapi.json"
    spec.write_bytes(requests.get(gw.api + "/docs", timeout=15).content)
    # The generator formats its output with ruff, which it looks up on PATH.
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    done = subprocess.run([str(BIN / "openapi-python-client"), "generate", "--path", str(spec),
                           "--output-path", str(tmp / PACKAGE), "--meta", "none"],
                          capture_output=True, text=True, timeout=120, env=env, cwd=tmp)
    output = done.stdout + done.stderr
    assert done.returncode == 0, output
    # Any warning means a part of the document was skipped: a route or model missing in clients.
    assert "Warning" not in output and "Error" not in output, output
    sys.path.insert(0, str(tmp))
    try:
        yield importlib.import_module(PACKAGE)
    finally:
        sys.path.remove(str(tmp))
        for name in [m for m in sys.modules if m == PACKAGE or m.startswith(PACKAGE + ".")]:
            del sys.modules[name]


@pytest.fixture(scope="module")
def client(sdk, gw):
    with sdk.Client(base_url=gw.api, raise_on_unexpected_status=True, timeout=15.0) as c:
        poll_until(lambda: "temp_sensor" in {i["id"] for i in requests.get(gw.api + "/apps", timeout=5)
                                             .json()["items"]}, 30, interval=0.1, message="app temp_sensor")
        yield c


def api(sdk, tag: str, operation: str):
    return importlib.import_module(f"{PACKAGE}.api.{tag}.{operation}")


def call(sdk, client, tag: str, operation: str, model: str, status: int = 200, **kwargs):
    """Call one generated operation; its answer parses into ``model`` and gives back the JSON sent."""
    response = api(sdk, tag, operation).sync_detailed(client=client, **kwargs)
    assert response.status_code == status, response.content
    parsed = response.parsed
    assert type(parsed).__name__ == model
    assert parsed.to_dict() == json.loads(response.content)
    return parsed


def test_the_generated_names_are_medkits(sdk):
    tmp = Path(sdk.__file__).parent
    discovery = {p.stem for p in (tmp / "api" / "discovery").glob("*.py")}
    # The imports of medkit's Python client (ros2_medkit_client/api/discovery.py).
    assert {"get_app", "get_app_host", "get_area", "get_component", "get_function", "list_app_dependencies",
            "list_apps", "list_area_components", "list_area_contains", "list_areas",
            "list_component_dependencies", "list_component_hosts", "list_components", "list_function_hosts",
            "list_functions", "list_subareas", "list_subcomponents"} <= discovery
    data = {p.stem for p in (tmp / "api" / "data").glob("*.py")}
    assert {"list_app_data", "get_app_data_item", "put_app_data_item"} <= data
    models = importlib.import_module(f"{PACKAGE}.models")
    for name in ("GenericError", "ComponentList", "ComponentListItem", "AppList", "AppDetail", "FunctionList",
                 "XMedkitApp", "XMedkitCollection", "DataList", "DataValue", "DataWriteRequest", "HealthStatus",
                 "RootOverview", "VersionInfo"):
        assert hasattr(models, name), name


def test_discovery_lists_and_reads(sdk, client):
    components = call(sdk, client, "discovery", "list_components", "ComponentList")
    assert [c.id for c in components.items] == [HOST_ID]
    apps = call(sdk, client, "discovery", "list_apps", "AppList")
    temp = next(a for a in apps.items if a.id == "temp_sensor")
    assert temp.x_medkit.ros2.node == "/powertrain/engine/temp_sensor"
    assert temp.x_medkit.component_id == HOST_ID
    assert call(sdk, client, "discovery", "list_areas", "AreaList").items == []
    call(sdk, client, "discovery", "list_functions", "FunctionList")
    app = call(sdk, client, "discovery", "get_app", "AppDetail", app_id="temp_sensor")
    assert app.is_located_on == f"/api/v1/components/{HOST_ID}"
    component = call(sdk, client, "discovery", "get_component", "ComponentDetail", component_id=HOST_ID)
    assert component.hosts == f"/api/v1/components/{HOST_ID}/hosts"
    function = call(sdk, client, "discovery", "get_function", "FunctionDetail", function_id="powertrain")
    assert function.x_medkit.hosts == ["temp_sensor"]


def test_relations(sdk, client):
    hosts = call(sdk, client, "discovery", "list_component_hosts", "AppList", component_id=HOST_ID)
    assert "temp_sensor" in [a.id for a in hosts.items] and hosts.x_medkit.total_count == len(hosts.items)
    located = call(sdk, client, "discovery", "get_app_host", "ComponentList", app_id="temp_sensor")
    assert [c.id for c in located.items] == [HOST_ID]
    (host,) = located.items  # medkit's test_hateoas: the host has id, name and href
    assert host.name and host.href == f"/api/v1/components/{HOST_ID}" and host.type_ == "component"
    assert located.field_links["app"] == "/api/v1/apps/temp_sensor"  # `_links`, as the generator names it
    func_hosts = call(sdk, client, "discovery", "list_function_hosts", "AppList", function_id="powertrain")
    assert [a.id for a in func_hosts.items] == ["temp_sensor"]
    for operation, model, kwargs in (("get_app_area", "AreaList", {"app_id": "temp_sensor"}),
                                     ("list_app_dependencies", "AppList", {"app_id": "temp_sensor"}),
                                     ("list_subcomponents", "ComponentList", {"component_id": HOST_ID}),
                                     ("list_component_dependencies", "ComponentList", {"component_id": HOST_ID})):
        empty = call(sdk, client, "discovery", operation, model, **kwargs)
        assert empty.items == [] and empty.x_medkit.total_count == 0, operation


def test_data_list_and_read(sdk, client):
    listing = call(sdk, client, "data", "list_app_data", "DataList", app_id="temp_sensor")
    assert TEMP in [i.id for i in listing.items]

    def sample():
        value = call(sdk, client, "data", "get_app_data_item", "DataValue", app_id="temp_sensor",
                     data_id=TEMP.lstrip("/"))  # the generator percent-encodes the slashes
        return value if value.x_medkit.status.value == "data" else None

    value = poll_until(sample, 30, interval=0.1, message="a sample of " + TEMP)
    assert value.id == TEMP
    assert value.data.to_dict()["temperature"] == 93.5
    assert value.x_medkit.ros2.type_ == "sensor_msgs/msg/Temperature"


def test_server_routes(sdk, client):
    health = call(sdk, client, "server", "get_health", "HealthStatus")
    assert health.x_medkit_subscription_executor.worker_alive is True
    root = call(sdk, client, "server", "get_root", "RootOverview")
    assert "GET /api/v1/components/{component_id}/hosts" in root.endpoints
    call(sdk, client, "server", "get_version_info", "VersionInfo")
    docs = call(sdk, client, "server", "get_app_docs", "GetAppDocsResponse200", app_id="temp_sensor")
    assert "/apps/temp_sensor/is-located-on" in docs.to_dict()["paths"]


@pytest.mark.parametrize("tag, operation, status, kwargs, message, parameters", [
    ("discovery", "get_app", 404, {"app_id": "nope"}, "Entity not found", {"entity_id": "nope"}),
    ("discovery", "get_component", 400, {"component_id": "temp_sensor"},
     "Invalid entity type for route: expected Component, got App",
     {"entity_id": "temp_sensor", "expected_type": "Component", "actual_type": "App"}),
    ("discovery", "list_component_hosts", 404, {"component_id": "nope"}, "Component not found",
     {"component_id": "nope"}),
    ("discovery", "list_area_contains", 404, {"area_id": "nope"}, "Area not found", {"area_id": "nope"}),
    ("data", "list_app_data", 400, {"app_id": "a.b"}, "Invalid entity ID",
     {"entity_id": "a.b", "details": "Entity ID contains invalid character: '.'. Only alphanumeric, "
                                     "underscore and hyphen are allowed"}),
])
def test_errors_parse_as_generic_error(sdk, client, tag, operation, status, kwargs, message, parameters):
    error = call(sdk, client, tag, operation, "GenericError", status=status, **kwargs)
    assert error.message == message
    assert error.parameters.to_dict() == parameters
