"""What the many-streams scenarios share: the streams they open, the readers, and what must hold after.

A scenario publishes ``topics`` of an app, opens one cyclic subscription a topic
(:func:`open_streams`), reads their event sources with ``bench/sseload.py``
client processes (:func:`read`) while a :class:`~tests.reliability.load.HealthProbe`
polls, and then checks :func:`assert_held`.
"""

from __future__ import annotations

import json
import sys

import requests

from common.harness.procs import Proc, poll_until
from tests.reliability.load import restarts_in
from tests.support.rospub import RosNode


def publishers(app: str, topics: list[str]) -> RosNode:
    """One node ``app`` publishing a Float64 counter at 10 Hz on every topic."""
    return RosNode({"node": app, "publish": [
        {"topic": t, "type": "std_msgs/msg/Float64", "rate": 10, "counter": "data"} for t in topics]})


def open_streams(gw, app: str, topics: list[str], interval: str, duration: int, streams: int) -> list[str]:
    """Once every topic has data: one subscription a topic; ``streams`` event-source paths, round robin."""
    for topic in topics:
        poll_until(lambda t=topic: gw.get(f"/apps/{app}/data{t}").json()["x-medkit"]["status"] == "data",
                   30, message=f"data on {topic}")
    subs = []
    for topic in topics:
        r = requests.post(f"{gw.api}/apps/{app}/cyclic-subscriptions", timeout=10, json={
            "resource": f"/api/v1/apps/{app}/data{topic}", "interval": interval, "duration": duration})
        assert r.status_code == 201, r.text
        subs.append(r.json())
    return [subs[i % len(subs)]["event_source"] for i in range(streams)]


def read(gw, paths: list[str], open_for: float, measure_from: float, *, clients: int, period: float,
         connect_rate: int, grace: float) -> dict:
    """``paths`` split over ``clients`` reader processes; their figures summed (``grace``: s past ``open_for``
    a reader may take to report)."""
    procs = [Proc([sys.executable, "-m", "bench.sseload", json.dumps({
        "port": gw.port, "paths": paths[i::clients], "period": period, "open_for": open_for,
        "measure_from": measure_from, "connect_rate": connect_rate})], name=f"sseload{i}")
        for i in range(clients)]
    outs = []
    for p in procs:
        outs.append(json.loads(p.wait_line(lambda s: s.startswith("{"), open_for + grace)))
        p.stop()
    return {k: sum(o[k] for o in outs) for k in ("opened", "failed", "errors", "delivered", "expected")} | {
        "per_stream_min": min(o["per_stream_min"] for o in outs),
        "lateness_p99_ms": max(o["lateness_ms"]["p99"] for o in outs)}


def delivered_ratio(got: dict) -> float:
    return got["delivered"] / got["expected"] if got["expected"] else 0.0


def assert_held(gw, got: dict, streams: int, peak: int, probe) -> None:
    """Every stream opened and fed, counted while it ran, ``/health`` answering, no ROS worker restart."""
    assert got["opened"] == streams and got["failed"] == 0 and got["errors"] == 0, got
    assert got["per_stream_min"] > 0, got           # no stream starved
    assert delivered_ratio(got) > 0.8, got          # generous: delivery targets are the bench's
    assert peak >= streams * 0.9, peak              # the streams were counted while they ran
    assert probe.samples and all(s[2] == 200 for s in probe.samples)
    assert probe.worst_ms() < 5000                  # a hang catcher
    assert restarts_in(gw.output) == 0
