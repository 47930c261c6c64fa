"""app/core/bodies.py: which Content-Types a JSON body may be declared with (the app, a fake ROS worker).

Through a real gateway and raw sockets (malformed chunked bodies, the limit,
415): tests/reliability/test_hostile_http.py; from a page of another origin in
chromium: tests/system/test_cross_site.py.
"""

from __future__ import annotations

import json

import pytest

SUBS = "/api/v1/apps/temp_sensor/cyclic-subscriptions"
DATA = "/api/v1/apps/controller/data/body/lights/cmd"
SUB = {"resource": "/api/v1/apps/temp_sensor/data/powertrain/engine/temperature", "interval": "normal",
       "duration": 60}
PUB = {"type": "std_msgs/msg/Bool", "data": {"data": True}}

pytestmark = pytest.mark.fakeworker(scope="module", allow_publish=True)


ACCEPTED = ["application/json", "application/json; charset=utf-8", "Application/JSON", "APPLICATION/JSON;charset=UTF-8",
            "application/json ; charset=utf-8", 'application/json; profile="x"']
REFUSED = [None, "", "text/plain", "text/plain; charset=utf-8", "application/x-www-form-urlencoded",
           "multipart/form-data; boundary=b", "application/jsonp", "application/json-patch+json",
           "application/problem+json", "text/json", "application/javascript", "json", "application/*",
           "application/json, text/plain", "text/plain; x=application/json"]


def send(client, method: str, path: str, body: dict, content_type: str | None):
    headers = {} if content_type is None else {"Content-Type": content_type}
    return client.open(path, method=method, data=json.dumps(body), headers=headers)


@pytest.mark.parametrize("content_type", ACCEPTED)
def test_json_with_any_parameters_and_in_any_case_is_accepted(client, fw, content_type):
    r = send(client, "POST", SUBS, SUB, content_type)
    assert r.status_code == 201, r.data
    r = send(client, "PUT", f"{SUBS}/{r.get_json()['id']}", {"interval": "fast"}, content_type)
    assert r.status_code == 200, r.data
    r = send(client, "PUT", DATA, PUB, content_type)
    assert r.status_code == 200, r.data
    assert len(fw.calls("publish")) == 1


@pytest.mark.parametrize("content_type", REFUSED)
def test_any_other_content_type_gets_415_and_reaches_nothing(client, fw, content_type):
    made = client.post(SUBS, json=SUB).get_json()["id"]
    with fw._lock:
        fw.requests.clear()
    for method, path, body in (("POST", SUBS, SUB), ("PUT", f"{SUBS}/{made}", {"interval": "fast"}),
                               ("PUT", DATA, PUB)):
        r = send(client, method, path, body, content_type)
        assert r.status_code == 415, (method, path, r.data)
        doc = r.get_json()
        assert doc["error_code"] == "invalid-request" and "Content-Type" in doc["message"], doc
        assert doc["parameters"]["content_type"] == (content_type or "")
        assert "application/json" in doc["parameters"]["details"]
    assert not any(fw.calls(cmd) for cmd in ("sub_create", "sub_update", "publish"))
