"""The operations family's routes (app/operations/spec.py) answer per the OpenAPI document.  ``GET .../status``
answers here from the fake ROS worker (run by tests/app/openapi/test_app_openapi.py); the routes under
``/operations`` answer from real servers, so they are exercised through the real gateway (EXERCISED_BY)."""

from __future__ import annotations

EXERCISED_BY = "tests/system/operations/test_operations.py::test_answers_follow_the_openapi_document"


def elsewhere(operation: str) -> bool:
    """Whether ``"GET /apps/{app_id}/operations"`` ... is EXERCISED_BY's, not this module's."""
    return "/operations" in operation


def exercise(ex) -> None:
    # GET .../status: ready (a plain node, the host component), notReady (a managed node not active), 404
    ex.fw.replies = {**getattr(ex.fw, "replies", {}), "lifecycle_state": {"managed": True, "state": "inactive"}}
    for path, answer in (("/api/v1/components/test-robot/status", "ready"),
                         ("/api/v1/apps/temp_sensor/status", "notReady"),
                         ("/api/v1/apps/nope/status", None), ("/api/v1/components/nope/status", None)):
        r = ex.answer("GET", path)
        assert (r.status_code, r.get_json().get("status")) == ((200, answer) if answer else (404, None)), path
