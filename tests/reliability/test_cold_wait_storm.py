"""Scenario 2, cold-wait storm: more cold callers than ``cold_wait_cap``, on silent publishers.

Silent publishers exist in the graph but publish every 1000 s, so every read
of their topics is cold and waits the whole sample timeout.  In each round
many callers read distinct silent topics at the same moment: ``cold_wait_cap``
of them wait (and get metadata_only at the timeout), the rest are shed at
once with 503 ``x-medkit-cold-wait-cap-exceeded`` and ``Retry-After``.
Meanwhile a warm topic is read in a loop and ``/health`` is polled: neither
is ever stuck behind the waiting callers.
"""

from __future__ import annotations

import json
import threading

import requests

from common.harness.procs import poll_until
from tests.reliability import load
from tests.support.rospub import RosNode, publisher, unique_topic

CAP = 4
SAMPLE_TIMEOUT = 3.0
CALLERS = load.scaled(24, 60)
ROUNDS = load.scaled(2, 10)
SILENT = [f"/coldwait/silent{i}" for i in range(CALLERS)]
WARM = "/coldwait/warm"


def sample_info(req, status, headers, body):
    doc = json.loads(body)
    if status == 200:
        return doc["x-medkit"]["status"], doc["x-medkit"].get("reason")
    return doc


def test_excess_cold_callers_are_shed_at_once_while_warm_reads_and_health_stay_fast(gateways, nodes):
    nodes.append(RosNode({"node": "cw_silent", "publish": [
        {"topic": t, "type": "std_msgs/msg/String", "rate": 0.001} for t in SILENT]}))
    nodes.append(publisher("cw_warm", WARM, "std_msgs/msg/Float64", rate=20, counter="data"))
    # Every caller is served at once: the default 2 workers x 1000 connections hold them all.
    gw = gateways("--cold-wait-cap", str(CAP), "--sample-timeout", str(SAMPLE_TIMEOUT),
                  "--log-level", "warning")
    host = gw.get("/components").json()["items"][0]["id"]
    base = f"/api/v1/components/{host}/data"
    poll_until(lambda: len(gw.get("/apps/cw_silent/data").json()["items"]) >= CALLERS, 30,
               message="every silent topic discovered")
    poll_until(lambda: gw.get(f"/components/{host}/data{WARM}").json()["x-medkit"]["status"] == "data",
               30, message="warm topic has data")
    rss_before = load.memory(gw.pid)

    cold: list = []
    warm_load = load.Load(gw.port, lambda rng: load.Req("warm", "GET", base + WARM), 2, inspect=sample_info)
    with load.HealthProbe(gw.port, interval=0.05) as probe:
        warm_load.start()
        for round_no in range(ROUNDS):
            barrier = threading.Barrier(CALLERS)

            def caller(topic: str, barrier: threading.Barrier, kind: str) -> None:
                client = load.Client(gw.port)
                barrier.wait(10)
                cold.append(load.call(client, load.Req(kind, "GET", base + topic), sample_info))
                client.close()

            threads = [threading.Thread(target=caller, args=(t, barrier, f"round{round_no}"), daemon=True)
                       for t in SILENT]
            for t in threads:
                t.start()
            for t in threads:
                t.join(SAMPLE_TIMEOUT + 30)
            assert not any(t.is_alive() for t in threads), "a cold caller hung"
            poll_until(lambda: gw.get("/health").json()["x-medkit-data-provider"]["concurrent_cold_waits"] == 0,
                       10, message="cold waiters released")
        warm_load.stop()
        warm = warm_load.join(30)
    rss_after = load.memory(gw.pid)
    load.record("cold-wait storm", cold + warm, probe=probe, restarts=load.restarts_in(gw.output),
           rss_before=rss_before, rss_after=rss_after,
           note=f"{ROUNDS} rounds x {CALLERS} cold callers, cap {CAP}, {len(warm)} warm reads")

    problems = [a for a in cold + warm if a.problem or isinstance(a.status, str)]
    assert not problems, [(a.path, a.status, a.problem) for a in problems[:5]]
    for round_no in range(ROUNDS):
        answers = [a for a in cold if a.kind == f"round{round_no}"]
        waited = [a for a in answers if a.status == 200]
        shed = [a for a in answers if a.status == 503]
        assert len(waited) + len(shed) == CALLERS, [a.key for a in answers]
        # Exactly the cap waits; the waiters get metadata_only when the timeout passes.
        assert len(waited) == CAP, [a.key for a in answers]
        assert all(a.info == ("metadata_only", "timeout") for a in waited), [a.info for a in waited]
        # The excess is shed at once: long before a waiter's timeout (a hang catcher, not a benchmark).
        for a in shed:
            assert a.key == "503 x-medkit-cold-wait-cap-exceeded"
            assert a.info["parameters"]["cold_wait_cap"] == CAP
            assert a.info["parameters"]["topic"] in SILENT
            assert a.elapsed < SAMPLE_TIMEOUT * 0.8, f"shed after {a.elapsed:.2f} s"
        assert all(a.elapsed >= SAMPLE_TIMEOUT * 0.9 for a in waited)
    # Warm reads went on while callers waited, and each answered with data, never behind a waiter.
    assert warm and all(a.status == 200 and a.info == ("data", None) for a in warm)
    assert max(a.elapsed for a in warm) < SAMPLE_TIMEOUT * 0.8
    first = min(a.started for a in cold)
    during = [a for a in warm if first <= a.started and a.finished <= first + SAMPLE_TIMEOUT * 0.9]
    assert len(during) >= 5, "warm reads stalled while cold callers waited"
    # /health never waited either, and never saw more waiters than the cap.
    assert probe.samples and all(s[2] == 200 for s in probe.samples)
    assert probe.worst_ms() < SAMPLE_TIMEOUT * 800
    assert probe.max_of("x-medkit-data-provider", "concurrent_cold_waits") <= CAP
    assert load.restarts_in(gw.output) == 0


def test_a_shed_read_leaves_the_pool_as_it_was(gateways, nodes):
    """A read refused at the cap must not evict a pooled topic or subscribe: under load such
    refused reads evicted the warm topics faster than new subscriptions got a first message,
    and warm reads were refused too (test_storm, most warm reads 503 on a busy machine)."""
    warm, other, silent = unique_topic("warm"), unique_topic("other"), unique_topic("silent")
    nodes.append(RosNode({"node": "shed_pubs", "publish": [
        {"topic": warm, "type": "std_msgs/msg/Float64", "rate": 20, "counter": "data"},
        {"topic": other, "type": "std_msgs/msg/Float64", "rate": 20, "counter": "data"},
        {"topic": silent, "type": "std_msgs/msg/String", "rate": 0.001}]}))
    # Room for two topics; one reader may wait for a first message.
    gw = gateways("--max-pool-size", "2", "--cold-wait-cap", "1", "--sample-timeout", "20",
                  "--log-level", "warning")
    host = gw.host()

    def read(topic: str) -> requests.Response:
        return gw.get(f"/components/{host}/data{topic}", timeout=30)

    poll_until(lambda: {warm, other, silent} <= {i["id"] for i in gw.get("/apps/shed_pubs/data").json()["items"]},
               30, message="the three topics discovered")
    poll_until(lambda: read(warm).json()["x-medkit"]["status"] == "data", 30, message="warm topic has data")
    client = gw.rosworker_client()
    waited: list = []
    waiter = threading.Thread(target=lambda: waited.append(read(silent)), daemon=True)
    try:
        waiter.start()
        poll_until(lambda: gw.get("/health").json()["x-medkit-data-provider"]["concurrent_cold_waits"] == 1,
                   15, message="the silent read waits: the cap is reached")
        assert set(client.call("pool", timeout=5)["topics"]) == {warm, silent}

        shed = read(other)
        assert shed.status_code == 503, shed.text
        assert shed.json()["vendor_code"] == "x-medkit-cold-wait-cap-exceeded"
        assert shed.json()["parameters"]["topic"] == other
        # Nothing changed: the warm topic is still pooled and still answers with data.
        assert set(client.call("pool", timeout=5)["topics"]) == {warm, silent}
        again = read(warm)
        assert again.status_code == 200, again.text
        assert again.json()["x-medkit"]["status"] == "data"
        assert client.call("stats", timeout=5)["details"]["evictions"]["lru"] == 0
    finally:
        waiter.join(30)
        client.close()
    assert waited and waited[0].json()["x-medkit"]["status"] == "metadata_only"
