"""Faults left in the store by nodes that are not on the graph (rosworker/faults/left.py): a gateway
that opens a state dir an earlier run wrote says so, in its log and in /health, until the node is back."""

from __future__ import annotations

import shutil
import tempfile

import pytest

from common.harness.diagpub import DiagPub
from common.harness.gateway import Gateway
from common.harness.procs import poll_until

FAST = ("--fault-confirm-count", "1", "--fault-heal-count", "1")


@pytest.fixture
def state_dir():
    path = tempfile.mkdtemp(prefix="sovd-state-left-")
    yield path
    shutil.rmtree(path, ignore_errors=True)


def section(gw: Gateway) -> dict:
    return gw.get("/health").json()["x-medkit-faults"]


def sources(gw: Gateway) -> dict[str, list[str]]:
    return {f["fault_code"]: f["reporting_sources"] for f in gw.get("/faults").json()["items"]}


def test_faults_of_absent_nodes_are_told_until_their_node_is_back(state_dir):
    ghost = DiagPub("ghost_driver", rate=5)
    here = DiagPub("here_driver", rate=5)
    back = None
    try:
        failing = [{"name": "ghost_driver: motor", "level": 2, "message": "hot"}]
        gw = Gateway(*FAST, "--fault-stale-s", "0", "--state-dir", state_dir)
        try:
            # The nodes known first, so that each status is put on its own node (one that comes before
            # its node is known may be put on another /diagnostics publisher).
            for app in ("ghost_driver", "here_driver"):
                poll_until(lambda a=app: gw.get(f"/apps/{a}").status_code == 200, 30, message=f"the app {app}")
            ghost.set(failing)
            here.set([{"name": "here_driver: motor", "level": 2, "message": "hot"}])
            poll_until(lambda: sources(gw) == {"GHOST_DRIVER_MOTOR": ["/ghost_driver"],
                                               "HERE_DRIVER_MOTOR": ["/here_driver"]}, 30,
                       message="both faults confirmed, each from its node")
            for pub in (ghost, here):
                pub.set([], publish=False)   # nothing reports from here on: each record is written once
            poll_until(lambda: section(gw)["store_pending"] == 0, 10, message="written")
            assert section(gw)["left_by_absent_nodes"] == 0 and section(gw)["absent_nodes"] == []
        finally:
            gw.stop()
        ghost.stop()   # an earlier run's node: gone before the next gateway starts
        gw = Gateway(*FAST, "--fault-stale-s", "5", "--state-dir", state_dir)
        try:
            # Told once the ghost is off the graph (it leaves it as its process ends), from 5 s on.
            poll_until(lambda: section(gw)["left_by_absent_nodes"] == 1, 60, message="the left fault told")
            assert section(gw)["absent_nodes"] == ["/ghost_driver"]    # never the node that is here
            line = gw.wait_line(lambda text: "not on the ROS graph" in text, 10)
            assert "1 active fault loaded from" in line and "faults.db" in line
            assert "reported by a node that is not on the ROS graph" in line and "(/ghost_driver)" in line
            assert "--state-dir" in line and "--allow-fault-clear" in line
            # The node is back and reports again: the fault is this robot's again.
            back = DiagPub("ghost_driver", rate=5)
            poll_until(lambda: gw.get("/apps/ghost_driver").status_code == 200, 30, message="the node back")
            back.set(failing)
            poll_until(lambda: section(gw)["left_by_absent_nodes"] == 0, 30, message="the node back")
            assert section(gw)["absent_nodes"] == []
        finally:
            gw.stop()
    finally:
        for pub in (ghost, here, back):
            if pub is not None:
                pub.stop()
