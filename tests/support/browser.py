"""Debian's chromium, driven by playwright, for the dashboard's tests (tests/system/test_ui.py).

playwright's own browser download cannot be reached here, so playwright drives
the ``chromium`` package (``/usr/bin/chromium``; ``SOVD_CHROMIUM`` names another)
over CDP.  The flags keep it headless and off the network: without them chromium
tries to reach Google's update and sync services.  Under CI (``CI=true``) a
missing chromium or playwright fails the tests (``.ci/run`` installs chromium);
elsewhere they are skipped.

:class:`Watch` records what must not happen on a page: console errors, uncaught
exceptions, requests that fail, and HTTP error answers, except those a test
provokes on purpose (:meth:`Watch.allow`).  Events are delivered on the test's
thread while it waits in a playwright call.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
from collections.abc import Iterator

import pytest

CHROMIUM = os.environ.get("SOVD_CHROMIUM", "/usr/bin/chromium")
IN_CI = os.environ.get("CI", "").lower() == "true"
ARGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--disable-default-apps", "--disable-extensions", "--no-first-run", "--no-default-browser-check",
        "--metrics-recording-only", "--mute-audio")
_STATUS_IN_CONSOLE = re.compile(r"status of (\d{3})")


def require_chromium() -> None:
    """Fail (under CI) or skip (elsewhere) when chromium or playwright is missing."""
    problem = None
    if not (os.access(CHROMIUM, os.X_OK) or shutil.which(CHROMIUM)):
        problem = f"chromium is not installed at {CHROMIUM} (apt-get install chromium)"
    else:
        try:
            import playwright.sync_api  # noqa: F401
        except ImportError:
            problem = "playwright is not installed (pip install -e '.[test]')"
    if problem:
        if IN_CI:
            pytest.fail(problem + "; .ci/run installs chromium")
        pytest.skip(problem)


@contextlib.contextmanager
def launch() -> Iterator:
    """A headless chromium (playwright ``Browser``), closed at the end."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=list(ARGS), timeout=60_000)
        try:
            yield browser
        finally:
            browser.close()


@contextlib.contextmanager
def headless_browser(expect_timeout_ms: int) -> Iterator:
    """:func:`launch` once chromium is there (:func:`require_chromium`), with playwright's ``expect`` waiting up to
    ``expect_timeout_ms`` (a loaded 2-core machine is slow; no timing is asserted)."""
    require_chromium()
    from playwright.sync_api import expect

    expect.set_options(timeout=expect_timeout_ms)
    with launch() as browser:
        yield browser


class Watch:
    """The problems of one page: console errors, page errors, failed requests, HTTP errors."""

    def __init__(self, page):
        self.page = page
        self.problems: list[str] = []
        self.allowed: set[tuple[str, int]] = set()   # (method, status) a test provokes
        self.requests: list[str] = []                 # every URL the page asked for
        self.active = True
        page.on("console", self._console)
        page.on("pageerror", lambda exc: self._add(f"uncaught exception: {exc}"))
        page.on("requestfailed", self._failed)
        page.on("response", self._response)
        page.on("request", lambda req: self.active and self.requests.append(req.url))

    def allow(self, method: str, status: int) -> None:
        """Answers with this status to this method are expected from now on (a test provokes them)."""
        self.allowed.add((method, status))

    def _failed(self, req) -> None:
        # net::ERR_ABORTED is the page's own doing (a navigation, or a fetch it aborted), never an answer.
        if "ERR_ABORTED" not in str(req.failure):
            self._add(f"request failed: {req.method} {req.url} ({req.failure})")

    def _add(self, text: str) -> None:
        if self.active:
            self.problems.append(text)

    def _console(self, msg) -> None:
        if msg.type != "error":
            return
        status = _STATUS_IN_CONSOLE.search(msg.text)
        # Chromium logs every error answer as "Failed to load resource: ... status of 401".
        if status and any(int(status.group(1)) == s for _, s in self.allowed):
            return
        self._add(f"console error: {msg.text} at {msg.location}")

    def _response(self, response) -> None:
        if response.status >= 400 and (response.request.method, response.status) not in self.allowed:
            self._add(f"HTTP {response.status}: {response.request.method} {response.url}")

    def stop(self) -> list[str]:
        """Stop recording (before the page is left on purpose); what was recorded."""
        self.active = False
        return list(self.problems)
