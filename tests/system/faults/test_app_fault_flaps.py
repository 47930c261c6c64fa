"""A fault does not flap while its status arrives on time; occurrences are counted as medkit counts them.

One gateway for the module: STALE after 2.5 s of silence, confirmed after 3 failing reports, healed after
2 passing ones, and ``debug_sleep`` (a ROS thread that is busy for a while, as under load).  The
statuses come from real ``/diagnostics`` publishers in other processes (``common/harness/diagpub.py``).
"""

from __future__ import annotations

import threading
import uuid

import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.sse import sse_events

TOKEN = "fault-flap-token-0123"
STALE_S = 2.5  # five times the slowest publisher's period: only a busy ROS thread could make one stale


@pytest.fixture(scope="module")
def gw(gateway):
    return gateway("--fault-confirm-count", "3", "--fault-confirm-s", "60", "--fault-heal-count", "2",
                   "--fault-stale-s", str(STALE_S), "--allow-fault-clear", "--api-token", TOKEN,
                   "--debug-commands")


def fault(gw: Gateway, code: str) -> dict | None:
    return next((f for f in gw.get("/faults?status=all").json()["items"] if f["fault_code"] == code), None)


def wait_status(gw: Gateway, code: str, status: str, timeout: float = 20.0) -> dict:
    poll_until(lambda: (fault(gw, code) or {}).get("status") == status, timeout, message=f"{code} {status}")
    return fault(gw, code)


def busy_ros_thread(gw: Gateway, seconds: float) -> None:
    """The ROS thread does something else for ``seconds`` (the reports wait in the subscription's queue)."""
    client = gw.rosworker_client()
    try:
        client.call("debug_sleep", {"seconds": seconds}, timeout=seconds + 10)
    finally:
        client.close()


def test_a_status_re_published_every_half_second_stays_one_confirmed_occurrence(gw, diag):
    """medkit's assertion: repeated reports advance last_occurred, never occurrence_count, and a status that
    keeps arriving is never "stale": not even when the ROS thread was busy for longer than fault_stale_s
    (its reports wait in the subscription's queue meanwhile).  A flap would show on the fault stream as
    fault_updated events (to CRITICAL "stale" and back)."""
    tag = uuid.uuid4().hex[:6]
    name, code = f"calibrator_{tag}: occurrence probe", f"CALIBRATOR_{tag.upper()}_OCCURRENCE_PROBE"
    mine: list[dict] = []
    with requests.get(f"{gw.api}/faults/stream", stream=True, timeout=60) as stream:
        def read() -> None:
            try:
                for event in sse_events(stream):
                    if event is not None and event["data"]["fault"]["fault_code"] == code:
                        mine.append(event)
            except Exception:  # noqa: BLE001 - the test closed the stream: the reading ends
                return

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        pub = diag(f"calibrator_{tag}", rate=2)
        pub.set([{"name": name, "level": 2, "message": "probe failing"}])
        first = wait_status(gw, code, "CONFIRMED")
        for _ in range(5):  # five times the ROS thread is away for longer than the stale time (a flap
            busy_ros_thread(gw, STALE_S + 1)  # came after about every other one of them)
            last = fault(gw, code)["last_occurred"]
            poll_until(lambda last=last: fault(gw, code)["last_occurred"] > last + 0.9, 10,
                       message="two more reports taken after the busy spell")
        # a flap shows at the first tick after a busy spell and ends with the next report taken: both came
        poll_until(lambda: mine, 10, message="the stream's events")
    now = fault(gw, code)
    assert now["status"] == "CONFIRMED" and now["occurrence_count"] == 1
    assert now["severity"] == 2 and now["severity_label"] == "ERROR" and now["description"] == "probe failing"
    assert now["first_occurred"] == first["first_occurred"] and now["last_occurred"] > first["last_occurred"]
    assert [e["event"] for e in mine] == ["fault_confirmed"], [(e["event"], e["data"]["fault"]["description"])
                                                               for e in mine]


def test_a_healed_then_cleared_fault_reported_again_counts_two_occurrences(gw, diag):
    """medkit counts raise edges: a new fault (1) and a failing report after a clear (+1); failing again
    after it healed is the same occurrence."""
    tag = uuid.uuid4().hex[:6]
    name, code = f"recount_{tag}: probe", f"RECOUNT_{tag.upper()}_PROBE"
    pub = diag(f"recount_{tag}", rate=5)
    failing = [{"name": name, "level": 2, "message": "failing"}]
    pub.set(failing)
    assert wait_status(gw, code, "CONFIRMED")["occurrence_count"] == 1
    pub.set([{"name": name, "level": 0, "message": "ok"}])
    assert wait_status(gw, code, "HEALED")["occurrence_count"] == 1
    pub.set(failing)
    assert wait_status(gw, code, "CONFIRMED")["occurrence_count"] == 1   # healed, failing again: the same one
    r = requests.delete(f"{gw.api}/apps/recount_{tag}/faults/{code}", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=10)
    assert r.status_code == 204, r.text
    again = wait_status(gw, code, "CONFIRMED")                            # cleared, reported again: a new one
    assert again["occurrence_count"] == 2
    last = again["last_occurred"]
    poll_until(lambda: fault(gw, code)["last_occurred"] > last + 1, 10, message="more reports")
    assert fault(gw, code)["occurrence_count"] == 2                       # reports that go on count nothing


def test_the_status_filters_are_medkit_s(gw, diag):
    """medkit's transport: pending is PREFAILED only; healed is HEALED and PREPASSED; cleared adds CLEARED;
    without a filter, PREFAILED and CONFIRMED."""
    tag = uuid.uuid4().hex[:6]
    name, code = f"filters_{tag}: probe", f"FILTERS_{tag.upper()}_PROBE"
    pub = diag(f"filters_{tag}", rate=2)  # two reports a second: each state can be seen

    def listed(status: str | None) -> bool:
        path = "/faults" if status is None else f"/faults?status={status}"
        return any(f["fault_code"] == code for f in gw.get(path).json()["items"])

    pub.set([{"name": name, "level": 2, "message": "failing"}], rate=10)
    wait_status(gw, code, "CONFIRMED")
    assert [listed(s) for s in (None, "pending", "confirmed", "healed", "cleared")] == [True, False, True, False,
                                                                                       False]

    def while_prepassed() -> dict | None:
        """The filters' answers, when the fault was PREPASSED before and after them (it only heals next)."""
        if fault(gw, code)["status"] != "PREPASSED":
            return None
        answers = {s: listed(s) for s in (None, "pending", "confirmed", "healed", "cleared", "all")}
        return answers if fault(gw, code)["status"] == "PREPASSED" else None

    pub.set([{"name": name, "level": 0, "message": "ok"}], rate=2)
    assert poll_until(while_prepassed, 20, interval=0.1, message="PREPASSED") == {
        None: False, "pending": False, "confirmed": False, "healed": True, "cleared": True, "all": True}
    wait_status(gw, code, "HEALED")
    assert {s: listed(s) for s in (None, "pending", "healed", "cleared", "all")} == {
        None: False, "pending": False, "healed": True, "cleared": True, "all": True}
