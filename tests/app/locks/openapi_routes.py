"""The locks' routes (app/locks/spec.py) answer per the OpenAPI document (the fake ROS worker holds
rosworker/locks/' table); run by tests/app/openapi/test_app_openapi.py."""

from __future__ import annotations

from tests.app.openapi.answers import AUTH


def exercise(ex) -> None:
    for base in ("/api/v1/apps/temp_sensor/locks", "/api/v1/components/test-robot/locks"):
        me = {**AUTH, "X-Client-Id": "tester"}
        lock = ex.answer("POST", base, json={"lock_expiration": 60, "scopes": ["data"]}, headers=me).get_json()
        ex.answer("POST", base, json={"lock_expiration": 60}, headers={**AUTH, "X-Client-Id": "other"})  # 409
        ex.answer("POST", base, json={"lock_expiration": 0}, headers=me)  # 400
        ex.answer("GET", base, headers={"X-Client-Id": "tester"})
        ex.answer("GET", f"{base}/{lock['id']}")
        ex.answer("GET", f"{base}/lock_999")  # 404
        ex.answer("PUT", f"{base}/{lock['id']}", json={"lock_expiration": 30}, headers=me)
        ex.answer("PUT", f"{base}/{lock['id']}", json={"lock_expiration": 30}, headers={**AUTH, "X-Client-Id": "x"})
        ex.answer("DELETE", f"{base}/{lock['id']}", headers={**AUTH, "X-Client-Id": "x"})  # 403
        ex.answer("DELETE", f"{base}/{lock['id']}", headers=me)
