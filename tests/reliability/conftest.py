"""The reliability suite: scale, per-test time limits, shared fixtures and the figures table.

``make reliability`` (``SOVD_RELIABILITY=long``) runs the long form of every
scenario and prints the figures table; ``make test`` leaves this folder out (its
time on 2 cores), and ``pytest tests/reliability`` alone runs the short form.  The
table is printed at the end of every session that ran a scenario (also in
the short form) and written as JSON to ``$TMPDIR/sovd-reliability-figures-<mode>.json``,
never into the repository.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import pytest

from common.harness.gateway import Gateway
from tests.reliability import load

HERE = Path(__file__).parent
# Whole-test limits (pytest-timeout): a hang fails the test instead of the session.
TEST_TIMEOUT = load.scaled(240, 1800)


def pytest_collection_modifyitems(config, items):
    for item in items:
        if HERE in Path(str(item.path)).parents and item.get_closest_marker("timeout") is None:
            item.add_marker(pytest.mark.timeout(TEST_TIMEOUT))


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    if not load.FIGURES:
        return
    path = os.path.join(tempfile.gettempdir(), f"sovd-reliability-figures-{load.MODE}.json")
    try:
        with open(path, "w") as fh:
            json.dump(load.FIGURES, fh, indent=1, default=str)
    except OSError as exc:
        path = f"(not written: {exc})"
    terminalreporter.write_sep("=", f"reliability figures ({load.MODE} form)")
    terminalreporter.write_line(load.table(load.FIGURES))
    terminalreporter.write_line(f"figures as JSON: {path}")


@pytest.fixture
def gateways():
    """Start gateways with ``gateways(*flags, env=...)``; all are stopped at the end of the test."""
    started: list[Gateway] = []

    def start(*flags: str, **kw) -> Gateway:
        gw = Gateway(*flags, **kw)
        started.append(gw)
        return gw

    yield start
    for gw in started:
        gw.stop()


