"""The logs' routes (app/logs/spec.py) answer per the OpenAPI document; run by
tests/app/openapi/test_app_openapi.py."""

from __future__ import annotations

from tests.app.openapi.answers import AUTH, ENTITY, WRONG


def exercise(ex) -> None:
    for collection in ("apps", "components", "functions"):
        base = f"/api/v1/{collection}/{ENTITY[collection]}/logs"
        ex.answer_all([
            ("GET", base, {}), ("GET", base + "?severity=loud", {}), ("GET", f"/api/v1/{collection}/nope/logs", {}),
            ("GET", base + "/configuration", {}), ("GET", f"/api/v1/{collection}/b.d/logs/configuration", {}),
            ("PUT", base + "/configuration", {"json": {"max_entries": 5}, "headers": AUTH}),
            ("PUT", base + "/configuration", {"json": {"max_entries": 0}, "headers": AUTH}),
            ("PUT", base + "/configuration", {"json": {"max_entries": 5}}),
            ("PUT", base + "/configuration", {"json": {}, "headers": WRONG}),
            ("PUT", base + "/configuration", {"data": b"{}", "content_type": "text/plain", "headers": AUTH}),
        ])
