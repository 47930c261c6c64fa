"""Scenario: many live streams at once (cyclic subscriptions over SSE), then all of them gone.

Short form (``make test``): 300 streams for 10 s; long form (``make
reliability``): the full 1,000 for 30 s.  10 topics at ``normal`` (5 frames/s
each), read by two client processes (``bench/sseload.py``), while a
probe polls ``/health``.

Nothing may crash or hang: every stream opens and gets its frames (a
generous share: delivery and lateness targets are the bench's), ``/health``
keeps answering, the ROS worker is never restarted, and once the clients are
gone every stream is given back (``open_streams`` 0) and the HTTP workers'
memory is what it was give or take.
"""

from __future__ import annotations

import json
import sys

import requests

from common.harness.procs import Proc, poll_until
from tests.reliability.load import HealthProbe, memory, record, restarts_in, scaled
from tests.support.rospub import RosNode

STREAMS = scaled(300, 1000)
SECONDS = scaled(10, 30)
TOPICS = [f"/streams/t{i}" for i in range(10)]
APP = "stream_pubs"


def read(gw, paths: list[str], open_for: float, measure_from: float) -> dict:
    procs = [Proc([sys.executable, "-m", "bench.sseload", json.dumps({
        "port": gw.port, "paths": paths[i::2], "period": 0.2, "open_for": open_for,
        "measure_from": measure_from, "connect_rate": 200})], name=f"sseload{i}") for i in range(2)]
    outs = []
    for p in procs:
        outs.append(json.loads(p.wait_line(lambda s: s.startswith("{"), open_for + 120)))
        p.stop()
    return {k: sum(o[k] for o in outs) for k in ("opened", "failed", "errors", "delivered", "expected")} | {
        "per_stream_min": min(o["per_stream_min"] for o in outs),
        "lateness_p99_ms": max(o["lateness_ms"]["p99"] for o in outs)}


def test_many_streams_hold_and_are_all_given_back(gateways, nodes):
    nodes.append(RosNode({"node": APP, "publish": [
        {"topic": t, "type": "std_msgs/msg/Float64", "rate": 10, "counter": "data"} for t in TOPICS]}))
    gw = gateways("--workers", "2", "--max-subscriptions", "100", "--log-level", "warning")
    for topic in TOPICS:
        poll_until(lambda t=topic: gw.get(f"/apps/{APP}/data{t}").json()["x-medkit"]["status"] == "data",
                   30, message=f"data on {topic}")
    subs = []
    for topic in TOPICS:
        r = requests.post(f"{gw.api}/apps/{APP}/cyclic-subscriptions", timeout=10, json={
            "resource": f"/api/v1/apps/{APP}/data{topic}", "interval": "normal", "duration": 600})
        assert r.status_code == 201, r.text
        subs.append(r.json())
    paths = [subs[i % len(subs)]["event_source"] for i in range(STREAMS)]
    rss_before = memory(gw.pid)
    measure_from = 3.0 + STREAMS / 400
    with HealthProbe(gw.port, interval=0.1) as probe:
        got = read(gw, paths, measure_from + SECONDS, measure_from)
        peak = max((b["x-medkit-streams"]["open_streams"] for b in probe.bodies()), default=0)
    poll_until(lambda: gw.get("/health").json()["x-medkit-streams"]["open_streams"] == 0, 15,
               message="every stream given back")
    rss_after = memory(gw.pid)
    ratio = got["delivered"] / got["expected"] if got["expected"] else 0.0
    record("streams", probe=probe, restarts=restarts_in(gw.output), rss_before=rss_before,
           rss_after=rss_after, requests=got["opened"],
           statuses={"200 text/event-stream": got["opened"], "failed": got["failed"]},
           note=f"{STREAMS} streams on {len(TOPICS)} topics at normal for {SECONDS} s: "
                f"{ratio:.1%} of scheduled frames delivered, p99 lateness {got['lateness_p99_ms']:.0f} ms, "
                f"peak open_streams {peak}")
    assert got["opened"] == STREAMS and got["failed"] == 0 and got["errors"] == 0, got
    assert got["per_stream_min"] > 0, got           # no stream starved
    assert ratio > 0.8, got                         # generous: delivery targets are the bench's
    assert peak >= STREAMS * 0.9, peak              # the streams were counted while they ran
    assert probe.samples and all(s[2] == 200 for s in probe.samples)
    assert probe.worst_ms() < 5000                  # a hang catcher
    assert restarts_in(gw.output) == 0
    grew = (rss_after["http_sum"] or 0) - (rss_before["http_sum"] or 0)
    assert grew < 100, (rss_before, rss_after)      # MB, over both HTTP workers
