"""The core's routes (app/openapi/core.py) answer per the OpenAPI document: the server, discovery, the scoped
documents, medkit's routes not served here (501), ``/metrics``; run by tests/app/openapi/test_app_openapi.py."""

from __future__ import annotations

import re

from app.core import unimplemented
from app.core.entities import RELATIONS
from tests.app.openapi.answers import AUTH, ENTITY


def exercise(ex) -> None:
    ex.answer_all([("GET", "/api/v1/", {}), ("GET", "/api/v1/version-info", {}), ("GET", "/api/v1/health", {}),
                   ("GET", "/api/v1/docs", {}), ("GET", "/metrics", {})])
    for collection, relation in RELATIONS:
        base = f"/api/v1/{collection}"
        ex.answer_all([("GET", f"{base}/{ENTITY[collection] or 'nope'}/{relation}", {}),
                       ("GET", f"{base}/nope/{relation}", {}), ("GET", f"{base}/b.d/{relation}", {})])
    for collection, eid in ENTITY.items():
        base = f"/api/v1/{collection}"
        target = eid or "nope"
        ex.answer_all([("GET", f"{base}/docs", {}), ("GET", f"{base}/{target}/docs", {}),
                       ("GET", f"{base}/{target}/data/docs", {}), ("GET", base, {}), ("GET", f"{base}/{target}", {}),
                       ("GET", f"{base}/bad.id", {}), ("GET", f"{base}/nope", {})])
    # medkit's routes not served here: 501 whatever the ids (app/core/unimplemented.py); a write
    # is asked for its token first, as every write (app/auth/).
    for route, path, _ in unimplemented.paths():
        concrete = "/api/v1" + re.sub(r"\{[^}]+\}", "x1", path)
        r = ex.answer(route.method, concrete, headers=AUTH if route.method != "GET" else {})
        assert r.status_code == 501, (route.method, concrete, r.data)
    ex.fw.stop()
    for path in ("/api/v1/health", "/api/v1/apps", "/api/v1/apps/temp_sensor",
                 "/api/v1/components/test-robot/hosts", "/api/v1/apps/temp_sensor/docs"):
        ex.check("GET", path, ex.client.get(path))
    for collection, relation in RELATIONS:  # each relation answered, and refused both ways
        param = "{" + collection[:-1] + "_id}"
        expected = {400, 404} if collection == "areas" else {200, 400, 404}
        assert ex.seen[f"GET /{collection}/{param}/{relation}"] == expected
    assert ex.seen["GET /apps/{app_id}/data/docs"] == {200}
    assert ex.seen["GET /areas/{area_id}/docs"] == {404}
