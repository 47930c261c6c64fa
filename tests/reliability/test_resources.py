"""Scenario 7, resource bounds: memory, descriptors and caps over many mixed requests.

Small caps on purpose (``--max-pool-size 8``, ``--max-publishers 4``) and more
topics than they hold, read and written, so that the pool and the publisher
pool evict all the time.  RSS and open descriptors of the ROS worker and of
each HTTP worker are measured after a warm-up and again at the end; the
growth goes to the figures (goal: under 10 MB), the assertion is generous.
The caps are watched all along (``/health`` for the pool, the worker's
``stats`` for publishers).
"""

from __future__ import annotations

import json
import threading

from common.harness.procs import poll_until
from ipc.client import RosWorkerClient
from ipc.errors import IpcError
from tests.reliability import load
from tests.support.rospub import RosNode
from tests.support.rosworker import call_once

REQUESTS = load.scaled(5_000, 100_000)
WARMUP = load.scaled(1_000, 5_000)
CLIENTS = 16
POOL, PUBLISHERS = 8, 4
READ = [f"/resources/live{i}" for i in range(16)]
WRITE = [f"/resources/cmd{i}" for i in range(12)]
RSS_BOUND_MB = 40   # generous: the goal is < 10 MB, reported in the figures


def plan_for(host: str):
    base = f"/api/v1/components/{host}"

    def plan(rng) -> load.Req:
        r = rng.random()
        if r < 0.45:
            return load.Req("read", "GET", f"{base}/data{rng.choice(READ)}")
        if r < 0.65:
            body = json.dumps({"type": "std_msgs/msg/String",
                               "data": {"data": "x" * rng.randrange(1, 2000)}}).encode()
            return load.Req("write", "PUT", f"{base}/data{rng.choice(WRITE)}", body,
                       {"Content-Type": "application/json"})
        if r < 0.75:
            return load.Req("nonexistent", "GET", f"{base}/data/resources/nope{rng.randrange(10**6)}")
        if r < 0.85:
            return load.Req("listing", "GET", rng.choice(["/api/v1/apps", "/api/v1/functions",
                                                     "/api/v1/apps/res_pubs/data", f"{base}/data"]))
        if r < 0.92:
            return load.Req("error", "GET", rng.choice(["/api/v1/apps/nobody", "/api/v1/apps/%00",
                                                   f"{base}/data/1bad"]))
        return load.Req("health", "GET", "/api/v1/health")

    return plan


class CapWatch(threading.Thread):
    """Polls the ROS worker's ``stats`` for the largest publisher count it ever shows."""

    def __init__(self, runtime_dir: str):
        super().__init__(daemon=True)
        self.client = RosWorkerClient.for_runtime_dir(runtime_dir)
        self.stop_event = threading.Event()
        self.max_publishers = 0
        self.max_pool = 0

    def run(self) -> None:
        while not self.stop_event.wait(0.05):
            try:
                stats = self.client.call("stats", timeout=2)
            except IpcError:
                continue
            self.max_publishers = max(self.max_publishers, stats["details"]["publishers"])
            self.max_pool = max(self.max_pool, stats["data_provider"]["pool_size"])
        self.client.close()

    def stop(self) -> None:
        self.stop_event.set()
        self.join(10)


def snapshot(pid: int) -> dict:
    procs = load.gateway_procs(pid)
    return {"rosworker": (procs.rosworker.pid, load.rss_mb(procs.rosworker), load.fds(procs.rosworker)),
            "http": {p.pid: (load.rss_mb(p), load.fds(p)) for p in procs.http}}


def test_memory_descriptors_and_caps_hold_over_many_mixed_requests(gateways, nodes):
    nodes.append(RosNode({"node": "res_pubs", "publish": [
        {"topic": t, "type": "std_msgs/msg/Float64", "rate": 10, "counter": "data"} for t in READ]}))
    nodes.append(RosNode({"node": "res_listener", "subscribe": [
        {"topic": t, "type": "std_msgs/msg/String"} for t in WRITE[:4]]}))
    gw = gateways("--allow-publish", "--max-pool-size", str(POOL), "--max-publishers", str(PUBLISHERS),
                  "--log-level", "warning")
    host = gw.get("/components").json()["items"][0]["id"]
    poll_until(lambda: len(gw.get("/apps/res_pubs/data").json()["items"]) >= len(READ), 30,
               message="every read topic discovered")
    plan = plan_for(host)

    # Warm-up on a new connection per request, so that every HTTP worker (and each of its threads,
    # which opens its own socket to the ROS worker) has served before the baseline is taken.
    def fresh(rng) -> load.Req:
        req = plan(rng)
        req.headers = {**(req.headers or {}), "Connection": "close"}
        return req

    load.Load(gw.port, fresh, CLIENTS, total=WARMUP, seed=100).run(120)
    before = snapshot(gw.pid)
    churn_before = call_once(gw.runtime_dir, "stats")["details"]
    watch = CapWatch(gw.runtime_dir)
    watch.start()
    with load.HealthProbe(gw.port, interval=0.2) as probe:
        answers = load.Load(gw.port, plan, CLIENTS, total=REQUESTS, seed=1).run(load.scaled(300, 3600))
    watch.stop()
    churn = call_once(gw.runtime_dir, "stats")["details"]
    poll_until(lambda: (h := gw.get("/health").json())["x-medkit-data-provider"]["concurrent_cold_waits"] == 0
               and h["x-medkit-subscription-executor"]["queue_depth"] == 0, 15, message="idle")
    after = snapshot(gw.pid)

    worker_growth = after["rosworker"][1] - before["rosworker"][1]
    http_growth = {pid: after["http"][pid][0] - rss for pid, (rss, _) in before["http"].items()
                   if pid in after["http"]}
    subs = churn["evictions"]["lru"] - churn_before["evictions"]["lru"]
    pubs = churn["publishes_total"] - churn_before["publishes_total"]
    http_fds = ", ".join(f"{before['http'][p][1]}→{after['http'][p][1]}" for p in http_growth)
    http_mb = ", ".join(f"{g:+.1f}" for g in http_growth.values())
    load.record("resource bounds", answers, probe=probe, restarts=load.restarts_in(gw.output),
           rss_before={"rosworker": before["rosworker"][1],
                       "http_max": max(r for r, _ in before["http"].values())},
           rss_after={"rosworker": after["rosworker"][1],
                      "http_max": max(r for r, _ in after["http"].values())},
           note=f"{REQUESTS} requests after {WARMUP} warm-up; growth rosworker {worker_growth:+.1f} MB, "
                f"http {http_mb} MB; fds rosworker {before['rosworker'][2]}→{after['rosworker'][2]}, "
                f"http {http_fds}; max pool {watch.max_pool}/{POOL}, "
                f"max publishers {watch.max_publishers}/{PUBLISHERS}; {subs} subscriptions evicted (LRU), "
                f"{pubs} publishes on {len(WRITE)} topics; goal <10 MB per process "
                f"{'met' if max(worker_growth, *http_growth.values()) < 10 else 'MISSED'}")

    failed = [a for a in answers if isinstance(a.status, str) or a.problem]
    assert not failed, [(a.path, a.status, a.problem) for a in failed[:5]]
    writes = [a for a in answers if a.kind == "write"]
    assert writes and sum(a.key == "200" for a in writes) > 0.9 * len(writes), \
        {a.key for a in writes}
    # Nothing restarted, so the before/after figures compare the same processes.
    assert after["rosworker"][0] == before["rosworker"][0] and load.restarts_in(gw.output) == 0
    assert set(after["http"]) == set(before["http"])
    # Caps held all along.
    assert watch.max_publishers <= PUBLISHERS and watch.max_publishers > 0
    assert max(watch.max_pool, probe.max_of("x-medkit-data-provider", "pool_size")) <= POOL
    # Memory and descriptors are bounded (generous; the figures carry the real numbers).
    assert worker_growth < RSS_BOUND_MB, f"ROS worker RSS grew by {worker_growth:.1f} MB"
    assert all(g < RSS_BOUND_MB for g in http_growth.values()), http_growth
    assert after["rosworker"][2] <= before["rosworker"][2] + 8, (before["rosworker"], after["rosworker"])
    for pid, (_, fd_before) in before["http"].items():
        assert after["http"][pid][1] <= fd_before + 12, (pid, fd_before, after["http"][pid][1])
