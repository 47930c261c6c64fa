"""The dashboard's routes (app/core/ui.py) and its static files (app/ui/), without a browser.

What a browser makes of the page is tests/system/ui/test_ui.py; here: the redirect, the
security headers, the JSON 404s, that the API's routes are untouched, that the
page has nothing inline that the Content-Security-Policy would have to allow,
and that a package build ships every file of app/ui/.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import pytest

from app.core.ui import SECURITY_HEADERS, UI_DIR
from common.harness.procs import REPO
from tests.support.fakeworker import make_app


@pytest.fixture
def client(tmp_path):
    return make_app(runtime_dir=str(tmp_path)).test_client()


def _has_security_headers(r) -> None:
    csp = r.headers["Content-Security-Policy"]
    assert "default-src 'self'" in csp and "unsafe-inline" not in csp and "unsafe-eval" not in csp
    assert r.headers["X-Content-Type-Options"] == "nosniff"
    for name, value in SECURITY_HEADERS.items():
        assert r.headers[name] == value


def test_root_redirects_relatively_to_the_ui(client):
    r = client.get("/")
    assert r.status_code == 302
    assert r.headers["Location"] == "ui/"   # relative: a path prefix in front of the gateway is kept
    _has_security_headers(r)
    r = client.get("/ui")
    assert r.status_code == 308 and r.headers["Location"] == "ui/"


def test_index_and_assets_are_served_with_security_headers(client):
    r = client.get("/ui/")
    assert r.status_code == 200 and r.mimetype == "text/html"
    assert b'<script type="module" src="js/main.js">' in r.data
    _has_security_headers(r)
    r = client.get("/ui/js/main.js")
    assert r.status_code == 200 and r.mimetype in ("text/javascript", "application/javascript")
    _has_security_headers(r)
    assert client.get("/ui/dashboard.css").mimetype == "text/css"
    assert client.get("/ui/favicon.svg").mimetype == "image/svg+xml"


@pytest.mark.parametrize("path", ["/ui/nope.js", "/ui/../routes/ui.py", "/ui/%2e%2e/routes/ui.py",
                                  "/ui/js/../../routes/ui.py", "/ui//etc/passwd", "/nope"])
def test_what_is_not_there_is_a_json_404(client, path):
    r = client.get(path)
    assert r.status_code == 404
    body = r.get_json()
    assert body["error_code"] == "resource-not-found" and body["parameters"]["status"] == 404


def test_the_api_is_untouched(client):
    r = client.get("/api/v1/nope")
    assert r.status_code == 404 and r.get_json()["parameters"]["path"] == "/api/v1/nope"
    assert "Content-Security-Policy" not in r.headers   # the UI's headers are the UI's
    r = client.put("/ui/")
    assert r.status_code == 405 and r.get_json()["error_code"]


class _Inline(HTMLParser):
    """Collects what a strict CSP would block: inline scripts, event handler attributes, inline styles."""

    def __init__(self):
        super().__init__()
        self.problems: list[str] = []
        self._in_script = False

    def handle_starttag(self, tag, attrs):
        names = dict(attrs)
        for name, _ in attrs:
            if name.startswith("on") or name == "style":
                self.problems.append(f"<{tag} {name}=...>")
        if tag == "script":
            self._in_script = True
            if not names.get("src"):
                self.problems.append("<script> without src")
        if tag == "style":
            self.problems.append("<style>")
        for name in ("src", "href"):
            value = names.get(name) or ""
            if re.match(r"^(https?:)?//|^/", value):
                self.problems.append(f"absolute URL {value!r}")

    def handle_endtag(self, tag):
        if tag == "script":
            self._in_script = False

    def handle_data(self, data):
        if self._in_script and data.strip():
            self.problems.append("inline script text")


def test_the_page_has_nothing_inline_and_only_relative_urls():
    parser = _Inline()
    parser.feed((UI_DIR / "index.html").read_text())
    assert parser.problems == []


def test_the_scripts_never_parse_text_as_html_or_code():
    for path in sorted((UI_DIR / "js").glob("*.js")):
        text = path.read_text()
        for banned in ("innerHTML", "outerHTML", "insertAdjacentHTML", "document.write", "eval(",
                       "new Function", "localStorage", "sessionStorage", "http://", "https://"):
            assert banned not in text, f"{path.name}: {banned}"
        # Every module it imports is there (a missing one fails only in a browser otherwise).
        for name in re.findall(r'from "\./([a-z]+\.js)"', text):
            assert (UI_DIR / "js" / name).is_file(), f"{path.name} imports {name}"


def test_a_package_build_ships_every_file_of_the_ui(tmp_path):
    """The same step a wheel build runs (build_py), from pyproject.toml's package-data."""
    out = tmp_path / "lib"
    proc = subprocess.run([sys.executable, "-c", "from setuptools import setup; setup()", "-q", "build_py",
                           "--build-lib", str(out)], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    shipped = {p.relative_to(out / "app" / "ui") for p in (out / "app" / "ui").rglob("*") if p.is_file()}
    ours = {Path(os.path.relpath(p, UI_DIR)) for p in UI_DIR.rglob("*") if p.is_file()}
    assert ours and shipped == ours
