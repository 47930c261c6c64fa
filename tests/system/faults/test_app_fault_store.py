"""The fault store through the real gateway: restarts, a SIGKILL mid-burst, a corrupt file, max_faults."""

from __future__ import annotations

import os
import signal
import sqlite3
import stat
import tempfile
import threading
import time

import pytest
import requests

from common.harness.diagpub import DiagPub
from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.sse import sse_events

FAST = ("--fault-confirm-count", "1", "--fault-heal-count", "1", "--fault-stale-s", "0")


@pytest.fixture
def state_dir():
    path = tempfile.mkdtemp(prefix="sovd-state-test-")
    yield path
    import shutil

    shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def diag():
    started: list[DiagPub] = []

    def make(node: str, rate: float = 10) -> DiagPub:
        pub = DiagPub(node, "/", rate)
        started.append(pub)
        return pub

    yield make
    for pub in started:
        pub.stop()


def faults(gw: Gateway, status: str = "all") -> dict[str, dict]:
    return {f["fault_code"]: f for f in gw.get("/faults", params={"status": status}).json()["items"]}


def written(gw: Gateway) -> bool:
    section = gw.get("/health").json()["x-medkit-faults"]
    return section["store_pending"] == 0 and section["store_writes"] > 0


def integrity(path: str) -> str:
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return db.execute("PRAGMA integrity_check").fetchone()[0]
    finally:
        db.close()


def app_detail(gw) -> dict | None:
    r = gw.get("/apps/persist_driver/faults/PERSIST_MOTOR")
    return r.json() if r.status_code == 200 else None


def test_faults_survive_a_gateway_restart(state_dir, diag):
    pub = diag("persist_driver", rate=5)
    # its hardware_id names its node: no guess from the publishers of /diagnostics (another test's
    # publisher, gone but still in the graph, made the guess the topic on a loaded run)
    pub.set([{"name": "persist: motor", "level": 2, "message": "hot", "hardware_id": "/persist_driver",
              "values": {"t": "99"}}])
    gw = Gateway(*FAST, "--state-dir", state_dir)
    try:
        poll_until(lambda: faults(gw).get("PERSIST_MOTOR", {}).get("status") == "CONFIRMED", 20,
                   message="confirmed")
        pub.set([], publish=False)  # nothing reports from here on: the record stays as it is
        poll_until(lambda: written(gw), 10, message="written")
        before = faults(gw)["PERSIST_MOTOR"]
        detail_before = poll_until(lambda: app_detail(gw), 20, message="the app's fault detail")
    finally:
        gw.stop()
    gw = Gateway(*FAST, "--state-dir", state_dir)
    try:
        after = faults(gw)["PERSIST_MOTOR"]
        assert after == before
        # The app's detail answers once the new gateway's graph knows its node (404 before).
        detail = poll_until(lambda: app_detail(gw), 20, message="the app's fault detail after the restart")
        assert detail["environment_data"] == detail_before["environment_data"]
        assert detail["environment_data"]["snapshots"][0]["data"]["values"] == {"t": "99"}
    finally:
        gw.stop()
    assert integrity(os.path.join(state_dir, "faults.db")) == "ok"


def test_a_sigkill_of_the_ros_worker_mid_burst_loses_no_confirmed_fault(state_dir, diag):
    flipping = threading.Event()
    gw = Gateway(*FAST, "--state-dir", state_dir)
    try:
        steady = diag("kill_steady", rate=2)
        steady.set([{"name": f"kill steady {i}", "level": 2, "message": "bad"} for i in range(5)])
        codes = {f"KILL_STEADY_{i}" for i in range(5)}
        poll_until(lambda: codes <= {c for c, f in faults(gw).items() if f["status"] == "CONFIRMED"}, 20,
                   message="the steady faults confirmed")
        poll_until(lambda: written(gw), 10, message="written")
        steady.set([], publish=False)
        # the burst: 200 statuses flipping between ERROR and OK (each flip: 200 faults confirmed or
        # healed, so the store writes all the time), while the ROS worker is killed
        burst = diag("kill_burst", rate=50)
        flips = {"n": 0}

        def flip() -> None:
            while not flipping.is_set():
                flips["n"] += 1
                level = 2 if flips["n"] % 2 else 0
                try:
                    burst.set([{"name": f"kill burst {i}", "level": level, "message": "x"} for i in range(200)])
                except AssertionError:
                    return  # the test is over
        writes = gw.get("/health").json()["x-medkit-faults"]["store_writes"]
        flipper = threading.Thread(target=flip, daemon=True)
        flipper.start()
        poll_until(lambda: gw.get("/health").json()["x-medkit-faults"]["store_writes"] > writes + 3, 30,
                   message="the burst being written")
        old_pid = gw.rosworker_pid()
        os.kill(old_pid, signal.SIGKILL)
        flips_at_kill = flips["n"]
        assert integrity(os.path.join(state_dir, "faults.db")) == "ok"

        def restarted() -> bool:
            health = gw.get("/health").json()
            return health["x-medkit-subscription-executor"]["worker_alive"] and gw.rosworker_pid() != old_pid

        poll_until(restarted, 60, message="the ROS worker restarted")
        poll_until(lambda: gw.get("/faults").status_code == 200, 30, message="faults served again")
        after = faults(gw)
        assert {c for c in codes if after.get(c, {}).get("status") == "CONFIRMED"} == codes
        assert flips_at_kill >= 2  # the kill came mid-burst
    finally:
        flipping.set()
        gw.stop()
    assert integrity(os.path.join(state_dir, "faults.db")) == "ok"


def test_a_corrupt_store_is_moved_aside_and_the_gateway_starts_empty(state_dir):
    path = os.path.join(state_dir, "faults.db")
    with open(path, "wb") as fh:
        fh.write(b"this is not a database" * 1000)
    gw = Gateway(*FAST, "--state-dir", state_dir)
    try:
        section = gw.get("/health").json()["x-medkit-faults"]
        assert section["store_size"] == 0 and section["store_enabled"] is True
        assert section["moved_aside"].startswith(path + ".corrupt-")
        assert os.path.exists(section["moved_aside"])
        assert any("moved it aside" in line for line in gw.output)
        assert gw.get("/faults").json()["items"] == []
    finally:
        gw.stop()
    assert integrity(path) == "ok"


def test_max_faults_drops_the_oldest_healed_fault_first_and_then_refuses(state_dir, diag):
    gw = Gateway(*FAST, "--max-faults", "3", "--state-dir", state_dir)
    try:
        pub = diag("cap_driver", rate=5)
        pub.set([{"name": "cap one", "level": 2}, {"name": "cap two", "level": 2}, {"name": "cap three", "level": 2}])
        poll_until(lambda: len(faults(gw, "confirmed")) == 3, 20, message="three confirmed")
        pub.set([{"name": "cap one", "level": 0}, {"name": "cap two", "level": 2}, {"name": "cap three", "level": 2}])
        poll_until(lambda: faults(gw).get("CAP_ONE", {}).get("status") == "HEALED", 20, message="healed")
        pub.set([{"name": "cap two", "level": 2}, {"name": "cap three", "level": 2}, {"name": "cap four", "level": 2}])
        poll_until(lambda: "CAP_FOUR" in faults(gw), 20, message="the fourth fault")
        assert set(faults(gw)) == {"CAP_TWO", "CAP_THREE", "CAP_FOUR"}   # the healed one went
        pub.set([{"name": "cap two", "level": 2}, {"name": "cap three", "level": 2}, {"name": "cap four", "level": 2},
                 {"name": "cap five", "level": 2}])
        poll_until(lambda: gw.get("/health").json()["x-medkit-faults"]["refused"] > 0, 20, message="refused")
        assert "CAP_FIVE" not in faults(gw) and len(faults(gw)) == 3
    finally:
        gw.stop()


def test_clearing_is_off_by_default(state_dir, diag):
    gw = Gateway(*FAST, "--state-dir", state_dir)
    try:
        diag("noclear_driver").set([{"name": "noclear", "level": 2}])
        poll_until(lambda: "NOCLEAR" in faults(gw), 20, message="the fault")
        for url in (f"{gw.api}/faults", f"{gw.api}/apps/noclear_driver/faults",
                    f"{gw.api}/apps/noclear_driver/faults/NOCLEAR"):
            r = requests.delete(url, timeout=10)
            assert r.status_code == 403 and r.json()["error_code"] == "forbidden", url
            assert "--allow-fault-clear" in r.json()["parameters"]["details"]
        assert faults(gw)["NOCLEAR"]["status"] == "CONFIRMED"
    finally:
        gw.stop()


def test_the_store_s_files_are_the_service_user_s_alone(tmp_path):
    """faults.db, its -wal and -shm are 0600 and a state dir the gateway makes is 0700, whatever the umask;
    a file left 0644 by an older gateway is narrowed."""
    state_dir = tmp_path / "made-by-the-gateway"
    old_umask = os.umask(0o022)  # the gateway inherits it (make run, a shell): files would be 0644
    try:
        gw = Gateway("--state-dir", str(state_dir))
    finally:
        os.umask(old_umask)
    try:
        poll_until(lambda: all(os.path.exists(state_dir / f"faults.db{s}") for s in ("", "-wal", "-shm")), 10,
                   message="the store's files")
        assert stat.S_IMODE(os.stat(state_dir).st_mode) == 0o700
        for suffix in ("", "-wal", "-shm"):
            assert stat.S_IMODE(os.stat(state_dir / f"faults.db{suffix}").st_mode) == 0o600, suffix
    finally:
        gw.stop()
    for suffix in ("", "-wal", "-shm"):  # as an older gateway left them
        if os.path.exists(state_dir / f"faults.db{suffix}"):
            os.chmod(state_dir / f"faults.db{suffix}", 0o644)
    os.chmod(state_dir, 0o755)
    gw = Gateway("--state-dir", str(state_dir))
    try:
        for suffix in ("", "-wal", "-shm"):
            assert stat.S_IMODE(os.stat(state_dir / f"faults.db{suffix}").st_mode) == 0o600, suffix
        assert stat.S_IMODE(os.stat(state_dir).st_mode) == 0o755  # not made by the gateway: left as it is
    finally:
        gw.stop()


def _until(events, code: str, timeout: float = 40.0) -> dict:
    deadline = time.monotonic() + timeout
    for event in events:
        if event is not None and event["data"]["fault"]["fault_code"] == code:
            return event
        if time.monotonic() > deadline:
            break
    raise AssertionError(f"no event of {code} within {timeout} s")


def test_a_restarted_ros_worker_s_fault_events_reach_an_open_stream_and_a_reconnect_with_no_store(tmp_path, diag):
    """A store in memory only (an unwritable state dir): the event ids of a new ROS worker must still be
    above the old one's, or an open stream and a Last-Event-ID reconnect drop them as sent already."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    gw = Gateway(*FAST, "--state-dir", str(blocker / "state"))
    pub = diag("epoch_driver", rate=5)
    try:
        assert gw.get("/health").json()["x-medkit-faults"]["store_enabled"] is False
        with requests.get(f"{gw.api}/faults/stream", stream=True, timeout=30) as stream:
            events = sse_events(stream)
            # six events before the restart; then silence, so that the new worker hears only what follows
            pub.set([{"name": f"epoch_driver: before {i}", "level": 2, "message": "x"} for i in range(6)])
            seen = {}
            while len(seen) < 6:
                event = next(events)
                if event is not None:
                    seen[event["data"]["fault"]["fault_code"]] = event
            before = max(seen.values(), key=lambda e: e["id"])
            pub.set([], publish=False)
            old_pid = gw.rosworker_pid()
            os.kill(old_pid, signal.SIGKILL)
            poll_until(lambda: gw.rosworker_pid() != old_pid and gw.get("/health").json()[
                "x-medkit-subscription-executor"]["worker_alive"], 30, message="the ROS worker restarted")
            pub.set([{"name": "epoch_driver: after", "level": 2, "message": "y"}])
            after = _until(events, "EPOCH_DRIVER_AFTER")  # the open stream gets it
        assert after["id"] > before["id"]
        with requests.get(f"{gw.api}/faults/stream", stream=True, timeout=30,
                          headers={"Last-Event-ID": str(before["id"])}) as again:
            replayed = _until(sse_events(again), "EPOCH_DRIVER_AFTER")  # a reconnect from before the restart too
        assert replayed["id"] == after["id"]
    finally:
        pub.stop()
        gw.stop()
