"""Fixtures the fault tests of this folder share."""

from __future__ import annotations

import pytest

from bench.diagpub import DiagPub


@pytest.fixture
def diag():
    """``diag(node, namespace="/", rate=10)``: a real ``/diagnostics`` publisher (bench/diagpub.py), once the
    gateway's subscription has matched it (no report is lost to discovery); stopped after the test."""
    started: list[DiagPub] = []

    def make(node: str, namespace: str = "/", rate: float = 10) -> DiagPub:
        pub = DiagPub(node, namespace, rate)
        started.append(pub)
        return pub.matched()

    yield make
    for pub in started:
        pub.stop()
