"""PUT {entity}/data/{data_id}: permissions, body checks, the publish command and its errors."""

from __future__ import annotations

import io

import pytest
from flask.testing import EnvironBuilder

from ipc.errors import IpcError
from tests.support.fakeworker import make_app

URL = "/api/v1/apps/controller/data/body/lights/cmd"
BODY = {"type": "std_msgs/msg/Bool", "data": {"data": True}}
TOKEN = "s3cret-token-0123456789"


pytestmark = pytest.mark.fakeworker(allow_publish=True)


def no_ros_traffic(fw):
    return [c for c, _, _ in fw.requests if c in ("publish", "graph")] == []


def nothing_published(fw):
    """A body is checked after the entity (medkit's order), so the graph was asked; nothing more."""
    return fw.calls("publish") == []


def test_publish(client, fw):
    r = client.put(URL, json=BODY)
    assert r.status_code == 200, r.data
    assert r.get_json() == {"id": "/body/lights/cmd", "data": {"data": True},
                            "x-medkit": {"ros2": {"topic": "/body/lights/cmd", "type": "std_msgs/msg/Bool"},
                                         "entity_id": "controller", "status": "published",
                                         "subscriber_count": 1, "unmatched_subscriber_count": 0}}
    assert fw.calls("publish") == [{"topic": "/body/lights/cmd", "type": "std_msgs/msg/Bool",
                                    "data": {"data": True}}]


@pytest.mark.parametrize("path", ["body%2Flights%2Fcmd", "body/lights/cmd", "/body/lights/cmd"])
def test_publish_data_id_spellings(client, fw, path):
    assert client.put("/api/v1/components/test-robot/data/" + path, json=BODY).status_code == 200
    assert fw.calls("publish")[-1]["topic"] == "/body/lights/cmd"


def test_publishing_disabled_is_403(fw):
    client = make_app(fw).test_client()
    r = client.put(URL, json=BODY)
    assert r.status_code == 403
    body = r.get_json()
    assert body["error_code"] == "forbidden"
    assert "allow-publish" in body["parameters"]["details"]
    assert no_ros_traffic(fw)


def test_token_missing_is_401_with_www_authenticate(fw):
    client = make_app(fw, allow_publish=True, api_token=TOKEN).test_client()
    for headers in ({}, {"Authorization": "Basic dXNlcjpwYXNz"}, {"Authorization": "Bearer "}):
        r = client.put(URL, json=BODY, headers=headers)
        assert r.status_code == 401
        assert r.headers["WWW-Authenticate"].startswith("Bearer")
        assert r.get_json()["error_code"] == "unauthorized"
    assert no_ros_traffic(fw)


def test_wrong_token_is_401(fw):
    """A bad token is medkit's 401 invalid_token (it was 403 before identities: issue 31)."""
    client = make_app(fw, allow_publish=True, api_token=TOKEN).test_client()
    for wrong in ("nope", TOKEN + "x", TOKEN[:-1], "ünïcode"):
        r = client.put(URL, json=BODY, headers={"Authorization": f"Bearer {wrong}"})
        assert r.status_code == 401
        assert r.headers["WWW-Authenticate"].startswith("Bearer")
        assert (r.get_json()["error_code"], r.get_json()["error"]) == ("unauthorized", "invalid_token")
    assert no_ros_traffic(fw)


def test_right_token_publishes(fw):
    client = make_app(fw, allow_publish=True, api_token=TOKEN).test_client()
    r = client.put(URL, json=BODY, headers={"Authorization": f"bearer {TOKEN}"})
    assert r.status_code == 200
    assert len(fw.calls("publish")) == 1


def test_token_does_not_guard_reads(fw):
    client = make_app(fw, allow_publish=True, api_token=TOKEN).test_client()
    assert client.get("/api/v1/apps/controller/data/body/lights/cmd").status_code == 200


@pytest.mark.parametrize("raw, message", [
    (b"not json", "JSON"),
    (b"", "JSON"),
    (b'{"type": "std_msgs/msg/Bool", "data": {"data": true}', "JSON"),
    (b"[1, 2]", "JSON object"),
    (b'"text"', "JSON object"),
])
def test_body_not_json(client, fw, raw, message):
    r = client.put(URL, data=raw, content_type="application/json")
    assert r.status_code == 400
    body = r.get_json()
    assert body["error_code"] == "invalid-request"
    assert message in body["message"]
    assert nothing_published(fw)


@pytest.mark.parametrize("raw", [
    b'{"type": "std_msgs/msg/Float64", "data": {"data": Infinity}}',
    b'{"type": "std_msgs/msg/Float64", "data": {"data": -Infinity}}',
    b'{"type": "std_msgs/msg/Float64MultiArray", "data": {"data": [1.0,NaN]}}',
    b'{"type": "std_msgs/msg/Float64", "data": {"data": 1e999}}',
    b'{"type": "std_msgs/msg/Float64", "data": {"data": -1e400}}',
])
def test_non_finite_json_literals_are_refused_with_the_right_spelling(client, fw, raw):
    r = client.put(URL, data=raw, content_type="application/json")
    assert r.status_code == 400
    body = r.get_json()
    assert body["error_code"] == "invalid-request" and "JSON" in body["message"]
    assert '"NaN", "Infinity", "-Infinity"' in body["parameters"]["details"]
    assert nothing_published(fw)


def test_other_invalid_json_gets_no_non_finite_hint(client, fw):
    r = client.put(URL, data=b'{"type": "std_msgs/msg/String", "data": {"data": "NaN" x}}',
                   content_type="application/json")
    assert r.status_code == 400
    assert "Infinity" not in r.get_json()["parameters"]["details"]


def test_non_finite_strings_and_null_are_passed_to_the_worker(client, fw):
    data = {"ranges": [1.5, "NaN", "Infinity", "-Infinity", None], "range_max": "Infinity"}
    r = client.put(URL, json={"type": "sensor_msgs/msg/LaserScan", "data": data})
    assert r.status_code == 200, r.data
    assert r.get_json()["data"] == data
    assert fw.calls("publish")[-1]["data"] == data


@pytest.mark.parametrize("body, message", [
    ({"data": {"data": True}}, "type: missing required field"),
    ({"type": 5, "data": {}}, "type: must be a string"),
    ({"type": None, "data": {}}, "type: must be a string"),
    ({"type": "std_msgs/msg/Bool"}, "data: missing required field"),
    ({"type": "std_msgs/msg/Bool", "data": 5}, "data: must be an object"),
    ({"type": "std_msgs/msg/Bool", "data": [True]}, "data: must be an object"),
    ({"type": "std_msgs/msg/Bool", "data": None}, "data: must be an object"),
])
def test_missing_or_wrong_fields(client, fw, body, message):
    r = client.put(URL, json=body)
    assert r.status_code == 400
    got = r.get_json()
    assert got["error_code"] == "invalid-request"
    assert got["message"] == message
    assert nothing_published(fw)


@pytest.mark.parametrize("type_name", [
    "std_msgs/Bool", "std_msgs/msg/Bool/extra", "std_msgs/srv/Bool", "/msg/Bool", "std_msgs/msg/",
    "std_msgs//Bool", "", "std msgs/msg/Bool", "std_msgs/msg/Bo-ol", "std_msgs/msg/" + "B" * 300,
])
def test_invalid_type_format(client, fw, type_name):
    r = client.put(URL, json={"type": type_name, "data": {}})
    assert r.status_code == 400
    body = r.get_json()
    assert body["error_code"] == "invalid-parameter"
    assert body["message"] == "Invalid message type format"
    assert set(body["parameters"]) == {"details", "type"}
    assert nothing_published(fw)


@pytest.mark.parametrize("type_name", ["Std_msgs/msg/Bool", "std_msgs/msg/bool", "std_msgs/msg/Bo_ol"])
def test_type_names_rosidl_refuses_are_refused_before_the_ros_worker(client, fw, type_name):
    """The HTTP side checks with the ROS worker's rule (ipc/topics.py): upper-case packages and
    lower-case or ``_``-containing message names never reach it."""
    r = client.put(URL, json={"type": type_name, "data": {}})
    assert r.status_code == 400
    body = r.get_json()
    assert body["error_code"] == "invalid-parameter"
    assert body["message"] == "Invalid message type format"
    assert nothing_published(fw)


def test_unknown_entity_is_404(client, fw):
    r = client.put("/api/v1/apps/ghost/data/body/lights/cmd", json=BODY)
    assert r.status_code == 404 and r.get_json()["error_code"] == "entity-not-found"
    assert fw.calls("publish") == []


def test_invalid_entity_id_is_400(client, fw):
    r = client.put("/api/v1/apps/gh.ost/data/body/lights/cmd", json=BODY)
    assert r.status_code == 400 and r.get_json()["message"] == "Invalid entity ID"
    assert no_ros_traffic(fw)


def test_body_too_large_is_413(fw):
    client = make_app(fw, allow_publish=True, max_body_bytes=1024).test_client()
    big = {"type": "std_msgs/msg/String", "data": {"data": "x" * 2000}}
    r = client.put(URL, json=big)
    assert r.status_code == 413
    body = r.get_json()
    assert body["error_code"] == "payload-too-large"
    assert body["parameters"]["max_body_bytes"] == 1024
    assert nothing_published(fw)


def chunked_put(app, payload: bytes):
    """Dispatch a PUT whose body has no Content-Length (a chunked upload, as gunicorn passes it)."""
    builder = EnvironBuilder(app=app, path=URL, method="PUT", content_type="application/json")
    environ = builder.get_environ()
    environ.pop("CONTENT_LENGTH", None)
    environ.update({"wsgi.input": io.BytesIO(payload), "wsgi.input_terminated": True,
                    "HTTP_TRANSFER_ENCODING": "chunked"})
    with app.request_context(environ) as ctx:
        assert ctx.request.content_length is None
        return app.full_dispatch_request()


def test_chunked_body_too_large_is_413(fw):
    app = make_app(fw, allow_publish=True, max_body_bytes=1024)
    response = chunked_put(app, b'{"type": "std_msgs/msg/String", "data": {"data": "'
                           + b"x" * 5000 + b'"}}')
    assert response.status_code == 413
    assert response.get_json()["error_code"] == "payload-too-large"
    assert nothing_published(fw)


def test_chunked_body_within_limit_publishes(fw):
    app = make_app(fw, allow_publish=True, max_body_bytes=1024)
    response = chunked_put(app, b'{"type": "std_msgs/msg/Bool", "data": {"data": true}}')
    assert response.status_code == 200
    assert len(fw.calls("publish")) == 1


@pytest.mark.parametrize("code, status, error_code", [
    ("type-not-installed", 400, "invalid-request"),
    ("invalid-data", 400, "invalid-request"),
    ("invalid-type", 400, "invalid-parameter"),
    ("publish-failed", 500, "vendor-error"),
])
def test_worker_publish_errors(client, fw, code, status, error_code):
    fw.errors["publish"] = IpcError(code, f"the worker explains: {code}", {"type": "std_msgs/msg/Bool"})
    r = client.put(URL, json=BODY)
    assert r.status_code == status
    body = r.get_json()
    assert body["error_code"] == error_code
    assert body["message"] == f"the worker explains: {code}"


def test_publish_is_never_resent_after_a_timeout(fw):
    fw.silent.add("publish")
    client = make_app(fw, allow_publish=True, ipc_timeout=0.3).test_client()
    r = client.put(URL, json=BODY)
    assert r.status_code == 504
    body = r.get_json()
    assert body["error_code"] == "not-responding"
    assert "may or may not" in body["message"]
    assert len(fw.calls("publish")) == 1


def test_publish_without_worker_is_503(tmp_path):
    client = make_app(runtime_dir=str(tmp_path), allow_publish=True).test_client()
    r = client.put(URL, json=BODY)
    assert r.status_code == 503 and r.headers["Retry-After"] == "2"


def test_other_methods_are_405_json(client):
    for method in ("POST", "DELETE", "PATCH"):
        r = client.open(URL, method=method)
        assert r.status_code == 405
        body = r.get_json()
        assert body["error_code"] == "invalid-request"
        assert set(r.headers["Allow"].split(", ")) >= {"GET", "PUT"}
