"""Real responses checked against the OpenAPI document, and the parts the document is made of.

The document (app/openapi/) is the core's part, auth's, audit's and each family's spec.  Each part's
routes are exercised by the tests of its own folder: ``tests/app/<part>/openapi_routes.py`` has
``exercise(ex)``, which answers every operation of that part through :class:`Exercise` (a fake ROS worker
and an app of it; tests/app/openapi/test_app_openapi.py runs them all), or names with ``EXERCISED_BY`` the
test that answers them through the real gateway.  A new family needs no edit outside its folders.
"""

from __future__ import annotations

import re

import jsonschema

TOKEN = "s3cret-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
WRONG = {"Authorization": "Bearer wrong"}
PUT_BODY = {"type": "std_msgs/msg/Bool", "data": {"data": True}}
ENTITY = {"areas": None, "components": "test-robot", "apps": "temp_sensor", "functions": "powertrain"}
TEMPERATURE = "/powertrain/engine/temperature"


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


def parts() -> dict[str, dict]:
    """The document's parts as app/openapi/ puts them together: name -> its paths."""
    from app.audit import doc as audit_doc
    from app.auth import doc as auth_doc
    from app.core.family import discover
    from app.openapi import core

    found = {"core": {**core.paths(), **core.last_paths()}, "auth": auth_doc.paths(), "audit": audit_doc.paths()}
    found.update((family.name, family.spec.paths()) for family in discover() if family.spec is not None)
    return found


def part_operations(name: str) -> set[str]:
    """``"GET /apps/{app_id}/faults"`` ... of one part of the document."""
    return {f"{method.upper()} {path}" for path, ops in parts()[name].items() for method in ops}


class Exercise:
    """What a part's ``exercise(ex)`` gets: ``fw``, a fake ROS worker with the ROBOT graph and a sampled
    temperature; ``client``, a test client of an app of it that allows every write to the holder of
    ``TOKEN``; ``answer()``, which sends a request, checks the answer against the document and notes its
    operation and status in ``seen`` (``check()`` checks one without noting it)."""

    def __init__(self, doc, fw, client):
        self.doc, self.fw, self.client = doc, fw, client
        self.seen: dict[str, set[int]] = {}

    def answer(self, method: str, path: str, client=None, **kw):
        response = (client or self.client).open(path, method=method, **kw)
        self.seen.setdefault(check(self.doc, method, path, response), set()).add(response.status_code)
        return response

    def answer_all(self, requests, client=None) -> None:
        for method, path, kw in requests:
            self.answer(method, path, client, **kw)

    def note(self, method: str, path: str, response) -> None:
        """A response the part got itself (a stream's head), checked and noted."""
        self.seen.setdefault(check(self.doc, method, path, response), set()).add(response.status_code)

    def check(self, method: str, path: str, response) -> str:
        return check(self.doc, method, path, response)
