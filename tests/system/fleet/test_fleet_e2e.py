"""Operating it in a fleet, through a real gateway (2 gevent workers, the real ROS worker, a real robot).

One gateway with rate limiting, CORS, the access log and the debug routes on:

- ``/metrics`` sums both HTTP workers (prometheus_client's multiprocess mode),
  its counters move with the requests made, the ROS worker's and the
  supervisor's series are there; an event stream shows in the stream metrics
  and carries the CORS headers;
- the rate limit is one limit over both workers, and a limited client does
  not hold up another;
- one ``grep <request id>`` of the output finds the access line and the ROS
  worker's line of one slow request, and the HTTP worker's error line;
- route labels stay bounded under a storm of random paths;
- last, with the ROS worker SIGKILLed: a scrape still answers, at once, with
  ``sovd_ros_worker_up 0``; then the restart is counted.

Each test speaks as clients of its own (``X-Forwarded-For`` from 127.0.0.1,
a trusted proxy by default), so their rate-limit buckets do not mix.
"""

from __future__ import annotations

import http.client
import json
import random
import signal
import statistics
import threading
import time
import uuid

import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.metrics import parse, value
from tests.support.rospub import RosNode
from tests.support.sse import EventStream

APP = "fleet_robot"
TOPIC = "/fleet/temperature"
SILENT = "/fleet/silent"       # in the graph, never publishes: a read waits the whole sample timeout
UI = "http://ui.example:8080"
RATE, BURST = 2, 20            # --rate-limit: per client
SAMPLE_TIMEOUT = 0.8


def client(n: int) -> dict[str, str]:
    """Headers of client number ``n`` behind the (trusted, loopback) proxy."""
    return {"X-Forwarded-For": f"10.{n // 65536 % 256}.{n // 256 % 256}.{n % 256}"}


@pytest.fixture(scope="module")
def robot():
    node = RosNode({"node": APP, "namespace": "/fleet", "publish": [
        {"topic": "temperature", "type": "sensor_msgs/msg/Temperature", "rate": 20,
         "value": {"temperature": 21.5}, "counter": "variance"},
        {"topic": "silent", "type": "std_msgs/msg/String", "rate": 0.001}]}, timeout=60)
    yield node
    node.stop()


@pytest.fixture(scope="module")
def gw(robot, gateway):
    gw = gateway("--workers", "2", "--rate-limit", f"{RATE}/{BURST}", "--cors-origins", UI,
                 "--access-log", "--debug-commands", "--sample-timeout", str(SAMPLE_TIMEOUT), exit_code=0)
    poll_until(lambda: gw.get(f"/apps/{APP}/data{TOPIC}", headers=client(1))
               .json()["x-medkit"]["status"] == "data", 30, interval=0.3, message="the robot's data")
    return gw


def scrape(gw: Gateway, timeout: float = 10) -> dict:
    r = requests.get(gw.url + "/metrics", timeout=timeout)
    assert r.status_code == 200
    assert "X-RateLimit-Limit" not in r.headers  # never limited
    return parse(r.text)


def grep(gw: Gateway, predicate, timeout: float = 10) -> str:
    """The first output line that matches, waiting for it (the whole output, not a queue)."""
    def found():
        return next((line for line in list(gw.output) if predicate(line)), None)
    return poll_until(found, timeout, interval=0.05, message="a matching output line")


def worker_connections(gw: Gateway) -> dict[int, http.client.HTTPConnection]:
    """One kept-alive connection to each of the two HTTP workers (pid → connection)."""
    found: dict[int, http.client.HTTPConnection] = {}
    for n in range(200):
        conn = http.client.HTTPConnection("127.0.0.1", gw.port, timeout=10)
        conn.request("GET", "/api/v1/x-sovd-debug/worker", headers=client(1000 + n))
        pid = json.loads(conn.getresponse().read())["pid"]
        if pid in found:
            conn.close()
        else:
            found[pid] = conn
        if len(found) == 2:
            return found
    raise AssertionError("could not reach both HTTP workers")


def test_metrics_sum_both_workers_and_move_with_the_requests(gw):
    conns = worker_connections(gw)
    route = "/api/v1/x-sovd-debug/worker"
    before = scrape(gw)
    pids = []
    for i in range(30):  # 15 on each worker, each as a client of its own
        conn = list(conns.values())[i % 2]
        conn.request("GET", route, headers=client(2000 + i))
        pids.append(json.loads(conn.getresponse().read())["pid"])
    assert set(pids) == set(conns)
    after = scrape(gw)
    key = {"route": route, "method": "GET", "status": "200"}
    assert value(after, "sovd_http_requests", "sovd_http_requests_total", **key) \
        - value(before, "sovd_http_requests", "sovd_http_requests_total", **key) == 30
    hist = "sovd_http_request_duration_seconds"
    assert value(after, hist, hist + "_count", route=route) - value(before, hist, hist + "_count", route=route) == 30
    # The ROS worker's counters, asked at scrape time, move with reads too.
    reads = value(after, "sovd_ros_commands", "sovd_ros_commands_total", command="sample")
    for i in range(3):
        assert gw.get(f"/apps/{APP}/data{TOPIC}", headers=client(2100 + i)).status_code == 200
    again = scrape(gw)
    assert value(again, "sovd_ros_commands", "sovd_ros_commands_total", command="sample") - reads == 3
    assert value(again, "sovd_ros_worker_up") == 1
    assert value(again, "sovd_ros_pool_size") >= 1
    assert value(again, "sovd_supervisor_ros_worker_restarts", "sovd_supervisor_ros_worker_restarts_total") == 0
    assert value(again, "sovd_supervisor_ros_worker_seconds_since_start") > 0
    for conn in conns.values():
        conn.close()


def test_an_event_stream_shows_in_the_metrics_and_carries_the_cors_headers(gw):
    headers = {**client(3000), "Origin": UI}
    r = requests.post(f"{gw.api}/apps/{APP}/cyclic-subscriptions", headers=headers, timeout=10, json={
        "resource": f"/api/v1/apps/{APP}/data{TOPIC}", "interval": "fast", "duration": 30})
    assert r.status_code == 201, r.text
    assert r.headers["Access-Control-Allow-Origin"] == UI
    sub = r.json()
    sent_before = value(scrape(gw), "sovd_http_stream_frames_sent", "sovd_http_stream_frames_sent_total")
    with EventStream(gw.port, sub["event_source"], headers={**client(3001), "Origin": UI}) as stream:
        assert stream.status == 200
        assert stream.headers["access-control-allow-origin"] == UI
        assert stream.headers["access-control-allow-credentials"] == "true"
        assert stream.headers["content-type"].startswith("text/event-stream")
        for _ in range(3):
            assert "payload" in stream.next(timeout=10)
        assert value(scrape(gw), "sovd_http_streams_open") == 1
        # The hub adds its frame counts to the metrics once per ticker round (app/subscriptions/hub.py).
        poll_until(lambda: value(scrape(gw), "sovd_http_stream_frames_sent", "sovd_http_stream_frames_sent_total")
                   - sent_before >= 3, 5, message="the three frames counted in the metrics")
    poll_until(lambda: value(scrape(gw), "sovd_http_streams_open") == 0, 10, message="the stream closed")
    requests.delete(f"{gw.api}/apps/{APP}/cyclic-subscriptions/{sub['id']}", headers=client(3002), timeout=10)


def test_one_limit_over_both_workers(gw):
    conns = worker_connections(gw)
    me = client(4000)
    statuses: dict[int, list[int]] = {pid: [] for pid in conns}
    started = time.monotonic()
    for i in range(60):  # alternately through each worker, as one client
        pid, conn = list(conns.items())[i % 2]
        conn.request("GET", "/api/v1/version-info", headers=me)
        response = conn.getresponse()
        response.read()
        statuses[pid].append(response.status)
        if response.status == 429:
            assert int(response.getheader("Retry-After")) >= 1
            assert response.getheader("X-RateLimit-Remaining") == "0"
    elapsed = time.monotonic() - started
    allowed = sum(s.count(200) for s in statuses.values())
    # One bucket: its burst plus what it refilled meanwhile (two buckets would allow twice that).
    assert BURST <= allowed <= BURST + int(RATE * elapsed) + 1, (allowed, elapsed)
    assert all(429 in s for s in statuses.values()), "both workers refuse the client over its limit"
    assert all(set(s) <= {200, 429} for s in statuses.values())
    for conn in conns.values():
        conn.close()


def test_request_ids_show_both_sides_of_a_slow_request(gw):
    rid = f"slow-{uuid.uuid4().hex[:12]}"
    started = time.monotonic()
    r = gw.get(f"/apps/{APP}/data{SILENT}", headers={**client(5000), "X-Request-Id": rid})
    assert time.monotonic() - started >= SAMPLE_TIMEOUT * 0.9
    assert r.json()["x-medkit"]["reason"] == "timeout"
    assert r.headers["X-Request-Id"] == rid
    # `journalctl -u sovd-gateway | grep <id>`: the access line and the ROS worker's own line.
    access = grep(gw, lambda line: f"request={rid}" in line and "GET /api/v1/apps/" in line)
    assert " 200 " in access and "10.0.19.136" in access  # the real client, not the proxy
    ros = grep(gw, lambda line: f"[request {rid}]" in line)
    assert "rosworker[" in ros and f"slow command: sample {SILENT}" in ros and "timeout" in ros
    # An error of the HTTP worker carries the id of its request too.
    fail_id = f"fail-{uuid.uuid4().hex[:12]}"
    r = gw.get("/x-sovd-debug/fail", headers={**client(5001), "X-Request-Id": fail_id})
    assert r.status_code == 500 and r.json()["error_code"] == "internal-error"
    assert "Traceback" not in r.text
    line = grep(gw, lambda line: "ERROR" in line and f"[request {fail_id}]" in line)
    assert "Unhandled error on GET /api/v1/x-sovd-debug/fail" in line


def test_a_limited_client_does_not_hold_up_another(gw):
    flooder = client(6000)
    stop = threading.Event()
    flood_statuses: list[int] = []

    def flood():
        conn = http.client.HTTPConnection("127.0.0.1", gw.port, timeout=10)
        while not stop.is_set():
            conn.request("GET", "/api/v1/version-info", headers=flooder)
            response = conn.getresponse()
            response.read()
            flood_statuses.append(response.status)
        conn.close()

    threads = [threading.Thread(target=flood) for _ in range(2)]
    for t in threads:
        t.start()
    try:
        poll_until(lambda: flood_statuses.count(429) > 100, 20, message="the flooder is limited")
        calm = http.client.HTTPConnection("127.0.0.1", gw.port, timeout=10)
        times, codes = [], []
        for _ in range(BURST - 5):  # within the calm client's own burst
            t0 = time.monotonic()
            calm.request("GET", f"/api/v1/apps/{APP}/data{TOPIC}", headers=client(6001))
            response = calm.getresponse()
            response.read()
            times.append(time.monotonic() - t0)
            codes.append(response.status)
        calm.close()
    finally:
        stop.set()
        for t in threads:
            t.join(15)
    assert codes == [200] * (BURST - 5)
    assert max(times) < 5.0, times  # a hang catcher; the figure below is for the reader
    print(f"\ncalm client under a flood of {len(flood_statuses)} requests ({flood_statuses.count(429)} refused):"
          f" p50 {statistics.median(times) * 1000:.2f} ms, max {max(times) * 1000:.2f} ms")


def test_route_labels_stay_bounded_under_a_storm_of_random_paths(gw):
    rng = random.Random(14)
    words = ["apps", "components", "functions", "areas", "data", "docs", APP, "x", "..", "%2F", "cyclic-subscriptions",
             "events", "sub_0123456789abcdef", "health", "metrics"]
    randoms = set()
    conn = http.client.HTTPConnection("127.0.0.1", gw.port, timeout=10)
    for i in range(300):
        segments = [rng.choice(words) if rng.random() < 0.6 else uuid.uuid4().hex[:rng.randint(1, 12)]
                    for _ in range(rng.randint(1, 6))]
        randoms.update(s for s in segments if len(s) >= 6 and s not in words)
        path = "/api/v1/" + "/".join(segments)
        conn.request(rng.choice(["GET", "GET", "PUT", "DELETE", "BREW"]), path, headers=client(7000 + i))
        conn.getresponse().read()
    conn.close()
    families = scrape(gw)
    routes = {s.labels["route"] for s in families["sovd_http_requests"].samples}
    methods = {s.labels["method"] for s in families["sovd_http_requests"].samples}
    assert not [r for r in routes if any(x in r for x in randoms)]  # templates, never what was sent
    assert all(r == "unmatched" or r.startswith("/") for r in routes)
    assert len(routes) < 40, routes
    assert methods <= {"GET", "HEAD", "POST", "PUT", "DELETE", "PATCH", "OPTIONS", "other"}


def test_a_dead_http_workers_live_gauges_leave_the_sums_and_its_counters_stay(gw):
    """gunicorn's child_exit hook marks a dead worker's files (prometheus_client's multiprocess docs)."""
    r = requests.post(f"{gw.api}/apps/{APP}/cyclic-subscriptions", headers=client(8000), timeout=10, json={
        "resource": f"/api/v1/apps/{APP}/data{TOPIC}", "interval": "fast", "duration": 60})
    assert r.status_code == 201, r.text
    with EventStream(gw.port, r.json()["event_source"], headers=client(8001)) as stream:
        assert "payload" in stream.next(timeout=10)
        before = scrape(gw)
        assert value(before, "sovd_http_streams_open") == 1
        holder = next(w for w in gw.http_workers()
                      if any(c.raddr and c.raddr.port == stream.local_port for c in w.net_connections("tcp")))
        counted = sum(s.value for s in before["sovd_http_requests"].samples if s.name == "sovd_http_requests_total")
        holder.send_signal(signal.SIGKILL)
        poll_until(lambda: len(gw.http_workers()) == 2 and holder.pid not in [w.pid for w in gw.http_workers()],
                   30, message="gunicorn replaced the killed worker")
        after = poll_until(lambda: (lambda f: f if value(f, "sovd_http_streams_open") == 0 else None)(scrape(gw)),
                           10, message="the dead worker's open streams left the sum")
    # Its counters stay in the sums: they never go backwards.
    assert sum(s.value for s in after["sovd_http_requests"].samples
               if s.name == "sovd_http_requests_total") >= counted


def test_a_scrape_while_the_ros_worker_is_down_answers_at_once_and_the_restart_is_counted(gw):
    old = gw.rosworker_pid()
    gw.rosworker().send_signal(signal.SIGKILL)
    worst = 0.0

    def down() -> bool:
        nonlocal worst
        t0 = time.monotonic()
        families = scrape(gw)
        worst = max(worst, time.monotonic() - t0)
        return value(families, "sovd_ros_worker_up") == 0 and "sovd_http_requests" in families

    poll_until(down, 10, interval=0.02, message="a scrape saying sovd_ros_worker_up 0")
    assert worst < 2.0 + 1.0, worst  # ipc_timeout (2 s) plus slack: never a hang

    def back() -> dict | None:
        families = scrape(gw)
        return families if value(families, "sovd_ros_worker_up") == 1 else None

    families = poll_until(back, 60, interval=0.2, message="the ROS worker back")
    assert gw.rosworker_pid() != old
    assert value(families, "sovd_supervisor_ros_worker_restarts", "sovd_supervisor_ros_worker_restarts_total") == 1
    assert value(families, "sovd_supervisor_ros_worker_seconds_since_start") < 60
