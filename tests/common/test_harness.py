"""The test harness: a gateway it starts is the one it talks to, and ports are never shared between sessions.

CI once failed because a gateway started by another test took the port this one had been given,
and answered its health check: the test then talked to a gateway without the flags it had asked
for. The harness now checks that the listener is its own gateway's, and starts again on a new port.
"""

from __future__ import annotations

import orjson
import pytest

from common.harness import gateway as harness
from common.harness.procs import REPO, free_port
from tests.support.onepage import OnePage


@pytest.fixture
def impostor():
    """Answers every GET as a healthy gateway would, and counts them."""
    body = orjson.dumps({"status": "healthy", "x-medkit-subscription-executor": {"worker_alive": True}})
    with OnePage(body, "application/json") as server:
        yield server


def test_a_port_taken_by_another_server_is_given_up_for_a_new_one(impostor, monkeypatch):
    taken = impostor.port
    ports = iter([taken])
    monkeypatch.setattr(harness, "free_port", lambda: next(ports, None) or free_port())
    gw = harness.Gateway("--workers", "1")
    try:
        assert gw.port != taken
        assert impostor.hits >= 1, "the impostor on the first port was never asked: the case did not happen"
        hits = impostor.hits
        r = gw.get("/health")
        assert r.status_code == 200
        assert r.json().keys() > {"status", "x-medkit-subscription-executor"}, r.text
        assert impostor.hits == hits
    finally:
        gw.stop()


def test_two_sessions_are_never_given_the_same_port():
    """Each process hands out ports from a block it alone holds."""
    import subprocess
    import sys

    code = "from common.harness.procs import free_port; print(*(free_port() for _ in range(300)))"
    runs = [subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, cwd=REPO)
            for _ in range(3)]
    sets = [set(map(int, p.communicate(timeout=60)[0].split())) for p in runs]
    assert all(p.returncode == 0 for p in runs)
    assert all(len(s) >= 150 for s in sets), [len(s) for s in sets]  # a block is 200 ports, handed out in turn
    assert not (sets[0] & sets[1]) and not (sets[0] & sets[2]) and not (sets[1] & sets[2])
