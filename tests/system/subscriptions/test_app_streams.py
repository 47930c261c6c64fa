"""Cyclic subscriptions streamed over SSE through a real gateway, from real publishers.

Cadence, payloads equal in shape to a GET, expiry, DELETE and PUT on a live
stream, a HEAD that opens nothing, who may change a subscription when a token
is set, a subscription made through one HTTP worker and streamed through the
other, a slow reader and what it holds in the kernel, 200 streams at once.
Faults (a ROS worker SIGKILL mid-stream, SIGTERM with open streams, a retime
whose ``updated`` event is lost) are at the end, each on its own gateway.
"""

from __future__ import annotations

import http.client
import json
import os
import re
import selectors
import signal
import time

import psutil
import pytest
import requests

from app.sse.stream import STREAM_BUFFER_BYTES, STREAM_SNDBUF
from app.subscriptions.hub import SILENT_CHECK, StreamHub
from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from ipc.errors import IpcError
from tests.support.metrics import families, value
from tests.support.rospub import RosNode
from tests.support.sse import EventStream

TOPIC = "/s/temperature"
APP = "streamer"
BASE = f"/apps/{APP}/cyclic-subscriptions"
STAMP = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z$")


def robot_spec() -> dict:
    return {"node": APP, "namespace": "/s", "publish": [
        {"topic": "temperature", "type": "sensor_msgs/msg/Temperature", "rate": 20,
         "value": {"temperature": 20.5}, "counter": "variance"},
        {"topic": "camera", "type": "sensor_msgs/msg/Image", "rate": 10,
         "value": {"height": 480, "width": 640, "encoding": "rgb8", "step": 1920,
                   "data": {"__fill__": [9, 640 * 480 * 3]}}},
    ]}


FLAGS = ("--workers", "2", "--log-level", "warning")


def sees_the_robot(gw: Gateway) -> Gateway:
    poll_until(lambda: gw.get(f"/apps/{APP}/data{TOPIC}").json()["x-medkit"]["status"] == "data", 30,
               message="the robot's data")
    return gw


def start_gateway(*args: str) -> Gateway:
    """A gateway of the test's own (stopped by the test)."""
    return sees_the_robot(Gateway(*FLAGS, *args))


@pytest.fixture(scope="module")
def robot():
    node = RosNode(robot_spec(), timeout=60)
    yield node
    node.stop()


SEND_TIMEOUT = 3  # --stream-send-timeout of the module's gateway: stalled readers are cut after it


@pytest.fixture(scope="module")
def gw(robot, gateway):
    return sees_the_robot(gateway(*FLAGS, "--stream-send-timeout", str(SEND_TIMEOUT)))


def subscribe(gw, interval: str = "normal", duration: int = 120, resource: str | None = None) -> dict:
    r = requests.post(gw.api + BASE, json={"resource": resource or f"/api/v1/apps/{APP}/data{TOPIC}",
                                           "interval": interval, "duration": duration}, timeout=10)
    assert r.status_code == 201, r.text
    return r.json()


def open_stream(gw, sub: dict, **kw) -> EventStream:
    stream = EventStream(gw.port, sub["event_source"], **kw)
    assert stream.status == 200, stream.body
    return stream


def test_frames_carry_what_a_get_answers_at_each_intervals_cadence(gw):
    get = gw.get(f"/apps/{APP}/data{TOPIC}").json()
    for interval, seconds, low, high in (("fast", 2.0, 15, 60), ("normal", 3.0, 6, 22), ("slow", 3.0, 3, 10)):
        sub = subscribe(gw, interval)
        with open_stream(gw, sub) as stream:
            assert stream.headers["content-type"].startswith("text/event-stream")
            assert stream.headers["cache-control"] == "no-cache"
            assert stream.headers["x-accel-buffering"] == "no"
            events = stream.collect(seconds)
        assert low <= len(events) <= high, (interval, len(events))
        for event in events:
            assert STAMP.match(event["timestamp"]), event["timestamp"]
            payload = event["payload"]
            assert set(payload) == set(get)
            assert set(payload["x-medkit"]) == set(get["x-medkit"])
            assert payload["id"] == TOPIC and payload["x-medkit"]["entity_id"] == APP
            assert payload["x-medkit"]["status"] == "data"
            assert set(payload["data"]) == set(get["data"])
        counters = [e["payload"]["data"]["variance"] for e in events]
        assert counters == sorted(counters) and counters[-1] > counters[0]   # the latest value, live
        assert requests.delete(gw.api + f"{BASE}/{sub['id']}", timeout=10).status_code == 204


def test_base64_resources_stream_compact_images(gw):
    sub = subscribe(gw, "normal", resource=f"/api/v1/apps/{APP}/data/s/camera?bytes=base64")
    with open_stream(gw, sub) as stream:
        event = stream.next(timeout=10)
    assert isinstance(event["payload"]["data"]["data"], str)   # one base64 string, not 921,600 integers
    assert event["payload"]["data"]["width"] == 640


def test_expiry_ends_the_stream_and_forgets_the_subscription(gw):
    sub = subscribe(gw, "fast", duration=2)
    with open_stream(gw, sub) as stream:
        assert stream.next(timeout=5) is not None
        assert stream.ended(timeout=10)
    assert requests.get(gw.api + f"{BASE}/{sub['id']}", timeout=10).status_code == 404
    assert all(s["id"] != sub["id"] for s in requests.get(gw.api + BASE, timeout=10).json()["items"])


def test_delete_ends_a_live_stream_at_once(gw):
    sub = subscribe(gw, "slow")
    with open_stream(gw, sub) as stream:
        assert stream.next(timeout=5) is not None
        assert requests.delete(gw.api + f"{BASE}/{sub['id']}", timeout=10).status_code == 204
        assert stream.ended(timeout=3)
    assert requests.get(gw.api + f"{BASE}/{sub['id']}", timeout=10).status_code == 404


def test_a_new_interval_applies_to_an_open_stream(gw):
    sub = subscribe(gw, "slow")
    with open_stream(gw, sub) as stream:
        slow = stream.collect(2.0)
        r = requests.put(gw.api + f"{BASE}/{sub['id']}", json={"interval": "fast", "duration": 60}, timeout=10)
        assert r.status_code == 200 and r.json()["interval"] == "fast" and r.json()["duration"] == 60
        fast = stream.collect(2.0)
    assert len(slow) <= 7 and len(fast) >= 15, (len(slow), len(fast))
    requests.delete(gw.api + f"{BASE}/{sub['id']}", timeout=10)


def _sub_gets(ros) -> int:
    """How many ``sub_get`` commands the ROS worker has run."""
    return ros.call("stats")["details"]["commands"].get("sub_get", {}).get("count", 0)


def _streams_open(gw) -> float:
    return value(families(gw.url), "sovd_http_streams_open")


def test_a_head_of_an_event_stream_answers_its_headers_and_opens_nothing(gw):
    """Issue 18, defect 1: each HEAD opened a stream whose body was never iterated, so nothing
    closed it; after the DELETE every such stream asked the ROS worker for its subscription
    every couple of seconds, for ever."""
    sub = subscribe(gw, "slow")
    for _ in range(50):
        r = requests.head(gw.url + sub["event_source"], timeout=10)
        assert r.status_code == 200 and r.content == b""
        assert r.headers["content-type"].startswith("text/event-stream")
        assert r.headers["cache-control"] == "no-cache" and r.headers["x-accel-buffering"] == "no"
    assert _streams_open(gw) == 0        # the gauge moves in the request itself: no wait needed
    with open_stream(gw, sub) as stream:  # a GET beside them opens exactly one
        assert stream.next(timeout=5) is not None
        assert _streams_open(gw) == 1
        assert requests.delete(gw.api + f"{BASE}/{sub['id']}", timeout=10).status_code == 204
        assert stream.ended(timeout=3)
    poll_until(lambda: _streams_open(gw) == 0, 10, message="the stream given back")
    # A stream left open after its subscription ended is looked up every SILENT_CHECK seconds.
    # Nothing may happen here, so this watches for a fixed while: three such rounds.
    ros = gw.rosworker_client()
    try:
        before = _sub_gets(ros)
        until = time.monotonic() + 3 * SILENT_CHECK + 1
        while time.monotonic() < until:
            assert _streams_open(gw) == 0
            assert _sub_gets(ros) == before, "a stream nobody reads still looks up its subscription"
            time.sleep(0.5)
    finally:
        ros.close()


TOKEN = "streams-test-token-0123456789"


def test_with_an_api_token_only_its_holder_makes_changes_or_ends_subscriptions(robot):
    """Issue 18: DELETE and PUT needed no token, so anyone who could list the ids could end another
    client's stream.  With a token, POST, PUT and DELETE need it (401 without or wrong, and
    nothing changes); reads, the event stream among them, stay as open as data reads."""
    gw = start_gateway("--api-token", TOKEN)
    try:
        auth = {"Authorization": f"Bearer {TOKEN}"}
        collection = gw.api + BASE
        body = {"resource": f"/api/v1/apps/{APP}/data{TOPIC}", "interval": "slow", "duration": 60}
        for headers, status, code in (({}, 401, "unauthorized"), ({"Authorization": "Bearer wrong"}, 401, "unauthorized"),
                                      ({"Authorization": f"Basic {TOKEN}"}, 401, "unauthorized")):
            r = requests.post(collection, json=body, headers=headers, timeout=10)
            assert r.status_code == status and r.json()["error_code"] == code, r.text
        assert r.headers["WWW-Authenticate"].startswith("Bearer")
        assert requests.get(collection, timeout=10).json()["items"] == []      # nothing was made
        r = requests.post(collection, json=body, headers=auth, timeout=10)
        assert r.status_code == 201, r.text
        sub = r.json()
        url = f"{collection}/{sub['id']}"
        assert requests.get(url, timeout=10).status_code == 200                  # reads need no token
        with open_stream(gw, sub) as stream:
            assert "payload" in stream.next(timeout=5)
            for headers, status in (({}, 401), ({"Authorization": "Bearer wrong"}, 401)):
                assert requests.put(url, json={"interval": "fast"}, headers=headers, timeout=10).status_code == status
                assert requests.delete(url, headers=headers, timeout=10).status_code == status
            assert requests.get(url, timeout=10).json()["interval"] == "slow"   # unchanged, and alive:
            assert "payload" in stream.next(timeout=5)
            r = requests.put(url, json={"interval": "normal"}, headers=auth, timeout=10)
            assert r.status_code == 200 and r.json()["interval"] == "normal"
            assert requests.delete(url, headers=auth, timeout=10).status_code == 204
            assert stream.ended(timeout=3)
    finally:
        gw.stop()


def test_a_subscription_made_through_one_worker_streams_through_another(gw):
    body = json.dumps({"resource": f"/api/v1/apps/{APP}/data{TOPIC}", "interval": "normal", "duration": 60})
    for _ in range(40):
        conn = http.client.HTTPConnection("127.0.0.1", gw.port, timeout=10)
        conn.request("POST", "/api/v1" + BASE, body=body, headers={"Content-Type": "application/json"})
        r = conn.getresponse()
        sub = json.loads(r.read())
        assert r.status == 201, sub
        made_by = gw.worker_of(conn.sock.getsockname()[1])   # the connection is still open
        stream = open_stream(gw, sub)
        try:
            streamed_by = gw.worker_of(stream.local_port)
            if streamed_by != made_by:
                event = stream.next(timeout=5)
                assert event["payload"]["id"] == TOPIC
                return
        finally:
            stream.close()
            conn.close()
            requests.delete(gw.api + f"{BASE}/{sub['id']}", timeout=10)
    pytest.fail("every stream landed on the worker that made its subscription")


def _rss(gw) -> int:
    return sum(p.memory_info().rss for p in psutil.Process(gw.pid).children(recursive=True)
               if "gunicorn" in " ".join(p.cmdline()) and p.ppid() != gw.pid)


def test_a_slow_reader_neither_slows_the_others_nor_grows_memory(gw):
    camera = subscribe(gw, "fast", resource=f"/api/v1/apps/{APP}/data/s/camera?bytes=base64")
    temperature = subscribe(gw, "normal")
    dropped_before = gw.get("/health").json()["x-medkit-streams"]["frames_dropped"]
    stalled = [open_stream(gw, camera, recv_buffer=4096) for _ in range(3)]   # they never read
    try:
        rss_before = _rss(gw)
        with open_stream(gw, temperature) as reader:
            events = reader.collect(6.0)
        rss_after = _rss(gw)
        assert len(events) >= 15, len(events)      # ~30 at normal: not held up by the stalled ones
        gaps = [b - a for a, b in zip(reader.arrivals, reader.arrivals[1:], strict=False)]
        assert max(gaps) < 2.0, gaps                # generous: a hang catcher, not a timing test
        assert rss_after - rss_before < 64 * 2**20, (rss_before, rss_after)
        poll_until(lambda: gw.get("/health").json()["x-medkit-streams"]["frames_dropped"] > dropped_before,
                   10, message="dropped frames counted")
        # A reader that takes no frame for the send timeout is disconnected: its connection is not
        # held for ever.  (Reading now, each finds the end of its stream after what was buffered.)
        for s in stalled:
            assert s.ended(timeout=SEND_TIMEOUT + 20), "a stalled reader was never disconnected"
    finally:
        for s in stalled:
            s.close()
        for sub in (camera, temperature):
            requests.delete(gw.api + f"{BASE}/{sub['id']}", timeout=10)


def _send_queue(server_port: int, client_port: int) -> int | None:
    """Bytes the kernel holds to send on the server's end of a loopback connection (tx_queue of
    /proc/net/tcp: written by the server, not yet acknowledged by the client), None if it is gone."""
    with open("/proc/net/tcp") as fh:
        for line in fh.read().splitlines()[1:]:
            fields = line.split()
            local, remote = (int(f.rsplit(":", 1)[1], 16) for f in fields[1:3])
            if (local, remote) == (server_port, client_port):
                return int(fields[4].split(":")[0], 16)
    return None


def test_what_a_reader_that_never_reads_holds_in_the_kernel_is_bounded(gw):
    """Issue 18: a stalled reader of an image stream held 3 MB in the kernel's send queue while
    the stream's buffer was said to hold "4 frames"; the connection's SO_SNDBUF now bounds it."""
    camera = subscribe(gw, "fast", resource=f"/api/v1/apps/{APP}/data/s/camera?bytes=base64")
    stalled = open_stream(gw, camera, recv_buffer=4096)     # it never reads: frames are ~1.2 MB each
    try:
        port = stalled.local_port
        poll_until(lambda: (_send_queue(gw.port, port) or 0) >= 16 * 1024, 10, message="bytes queued")
        # The queue fills within a frame or two; watch it until the stalled reader is cut (SEND_TIMEOUT).
        peak, until = 0, time.monotonic() + SEND_TIMEOUT - 0.5
        while time.monotonic() < until and (queued := _send_queue(gw.port, port)) is not None:
            peak = max(peak, queued)
            time.sleep(0.05)
        assert 16 * 1024 <= peak <= 2 * STREAM_SNDBUF + 64 * 1024, peak   # Linux doubles SO_SNDBUF
    finally:
        stalled.close()
        requests.delete(gw.api + f"{BASE}/{camera['id']}", timeout=10)


def test_a_streams_buffer_is_bounded_in_bytes_as_well_as_frames():
    """The hub's side of a slow reader, alone (no socket: the hub is not started): four small
    frames are kept, but of megabyte frames only the newest."""
    hub = StreamHub("/nonexistent", lookup=lambda stream: {})
    sub = {"id": "sub_0123456789abcdef", "collection": "apps", "entity_id": APP, "topic": TOPIC,
           "key": b"d|fast|array|/s/temperature|", "interval": "fast", "expires_at_ns": time.time_ns() + 10**10}
    small, large = hub.stream(sub), hub.stream(sub)
    for n in range(10):
        small.push(b"%d" % n * 100)
        large.push(b"%d" % n * (STREAM_BUFFER_BYTES // 2 + 1))
    assert [f[:1] for f in small.frames] == [b"6", b"7", b"8", b"9"] and small.buffered == 400
    assert [f[:1] for f in large.frames] == [b"9"] and large.buffered == STREAM_BUFFER_BYTES // 2 + 1
    assert hub.counters["frames_dropped"] == 6 + 9


def test_two_hundred_streams_at_once(gw):
    sub = subscribe(gw, "normal")
    streams = [open_stream(gw, sub) for _ in range(200)]
    selector = selectors.DefaultSelector()
    try:
        for s in streams:
            s.sock.setblocking(False)
            selector.register(s.sock, selectors.EVENT_READ, s)
        started = time.monotonic()
        health_times = []
        while time.monotonic() - started < 4.0:
            for key, _ in selector.select(timeout=0.2):
                stream = key.data
                try:
                    data = stream.sock.recv(65536)
                except BlockingIOError:
                    continue
                stream._raw += data
                stream._dechunk()
                stream._parse()
            if len(health_times) < 4 and time.monotonic() - started > len(health_times):
                t = time.monotonic()
                assert gw.get("/health", timeout=5).status_code == 200
                health_times.append(time.monotonic() - t)
        counts = sorted(len(s.events) for s in streams)
        assert counts[0] >= 8, counts[:10]                # ~20 each at normal over 4 s
        assert max(health_times) < 2.0, health_times      # a hang catcher
        poll_until(lambda: gw.get("/health").json()["x-medkit-streams"]["open_streams"] >= 200, 10,
                   message="the open streams counted in /health")
    finally:
        for s in streams:
            s.close()
        requests.delete(gw.api + f"{BASE}/{sub['id']}", timeout=10)


def _holder(gw, stream: EventStream) -> int | None:
    """The pid of the HTTP worker that serves ``stream``'s connection."""
    for worker in gw.http_workers():
        if any(c.raddr and c.raddr.port == stream.local_port for c in worker.net_connections("tcp")):
            return worker.pid
    return None


def test_health_sums_both_workers_streams_as_the_metrics_do_and_the_ros_worker_never_sees_them(gw):
    """Issue 19: x-medkit-streams' open streams and frames are the HTTP workers' own Prometheus
    metrics, summed from the multiprocess directory as a scrape sums them; the ROS worker's
    ``stats`` answer has none of them and it takes no ``streams_report`` any more."""
    sub = subscribe(gw, "fast")
    streams: list[EventStream] = []
    holders: set[int | None] = set()
    try:
        while len(holders) < 2 and len(streams) < 40:  # new connections until each worker serves one
            streams.append(open_stream(gw, sub))
            holders.add(_holder(gw, streams[-1]))
        assert holders == {w.pid for w in gw.http_workers()}, holders
        for stream in streams:
            assert "payload" in stream.next(timeout=10)

        def agreed():
            health = gw.get("/health").json()["x-medkit-streams"]
            scraped = families(gw.url)
            ok = health["open_streams"] == value(scraped, "sovd_http_streams_open") == len(streams)
            return (health, scraped) if ok else None
        health, scraped = poll_until(agreed, 15, message="both workers' streams in /health and /metrics")
        assert len(streams) <= health["frames_sent"] \
            <= value(scraped, "sovd_http_stream_frames_sent", "sovd_http_stream_frames_sent_total")
        ros = gw.rosworker_client()
        try:
            answer = ros.call("stats", timeout=5)["streams"]
            assert not {"open_streams", "frames_sent", "frames_dropped"} & set(answer), answer
            with pytest.raises(IpcError) as info:
                ros.call("streams_report", {"pid": 1, "open_streams": 5, "frames_sent": 0, "frames_dropped": 0},
                         timeout=5)
            assert info.value.code == "unknown-command"
        finally:
            ros.close()
    finally:
        for stream in streams:
            stream.close()
        requests.delete(gw.api + f"{BASE}/{sub['id']}", timeout=10)
    poll_until(lambda: gw.get("/health").json()["x-medkit-streams"]["open_streams"] == 0, 15,
               message="the closed streams gone from /health")


def test_streams_go_on_through_a_ros_worker_sigkill(robot):
    gw = start_gateway()
    try:
        sub = subscribe(gw, "normal")
        with open_stream(gw, sub) as stream:
            assert "payload" in stream.next(timeout=5)
            os.kill(gw.rosworker_pid(), signal.SIGKILL)
            error = poll_until(lambda: (lambda e: e if e and "error" in e else None)(stream.next(timeout=10)),
                               15, interval=0, message="an error frame")
            assert error["error"]["vendor_code"] == "x-medkit-ros-worker-unavailable"
            assert STAMP.match(error["timestamp"])
            back = poll_until(lambda: (lambda e: e if e and "payload" in e else None)(stream.next(timeout=30)),
                              60, interval=0, message="data frames after the restart")
            assert back["payload"]["x-medkit"]["status"] in ("data", "metadata_only")
        assert requests.get(gw.api + f"{BASE}/{sub['id']}", timeout=10).status_code == 200  # it survived
    finally:
        gw.stop()


def test_sigterm_ends_every_open_stream_cleanly(robot):
    gw = start_gateway()
    children = psutil.Process(gw.pid).children(recursive=True)
    sub = subscribe(gw, "normal")
    streams = [open_stream(gw, sub) for _ in range(6)]
    try:
        for s in streams:
            assert s.next(timeout=5) is not None
        gw.signal(signal.SIGTERM)
        for s in streams:
            assert s.ended(timeout=15)
            last = s.events[-1]
            assert last["error"]["vendor_code"] == "x-medkit-gateway-shutdown", last
        assert gw.proc.wait(30) == 0
        assert not [c for c in children if c.is_running() and c.status() != psutil.STATUS_ZOMBIE]
    finally:
        for s in streams:
            s.close()
        gw.stop()


def test_a_stream_whose_subscription_did_not_survive_a_restart_ends(robot):
    """A ROS worker that comes back without the subscription (its restart state lost it): the stream
    is told so and ends, instead of staying open and silent."""
    gw = start_gateway()
    try:
        sub = subscribe(gw, "normal")
        state = os.path.join(gw.runtime_dir, "restart-state.json")
        poll_until(lambda: sub["id"] in open(state).read(), 5, message="the subscription saved")
        with open_stream(gw, sub) as stream:
            assert "payload" in stream.next(timeout=5)
            # Frozen first: a live worker rewrites its state whenever the graph or the pool
            # changes (with the subscription in it), which would undo the edit before the kill.
            pid = gw.rosworker_pid()
            os.kill(pid, signal.SIGSTOP)
            saved = json.load(open(state))
            saved["subscriptions"] = []
            with open(state + ".new", "w") as fh:
                json.dump(saved, fh)
            os.replace(state + ".new", state)
            os.kill(pid, signal.SIGKILL)
            assert stream.ended(timeout=40)
            last = stream.events[-1]
            assert last["error"]["error_code"] == "resource-not-found", last
            assert last["error"]["message"] == "Subscription not found"
    finally:
        gw.stop()


def _payloads_per_second(stream: EventStream) -> int:
    return sum(1 for e in stream.collect(1.0) if "payload" in e)


def test_a_retime_whose_updated_event_was_lost_still_reaches_the_open_stream(robot):
    """Issue 18, defect 4: a PUB socket drops what it sends while a SUB is not connected, so
    the ``updated`` event of a retime made right after a ROS worker restart can be lost.  Here
    it is lost for sure: the HTTP worker holding the stream is stopped (SIGSTOP) before the
    ROS worker is killed, so it cannot reconnect before the retime is made, straight over IPC.
    The stream must still move to the new key (the silence check's ``sub_get`` says it)."""
    gw = start_gateway()
    ros = gw.rosworker_client()
    worker = None
    try:
        sub = subscribe(gw, "slow")
        state = os.path.join(gw.runtime_dir, "restart-state.json")
        poll_until(lambda: sub["id"] in open(state).read(), 5, message="the subscription saved")
        args = {"collection": "apps", "entity_id": APP, "id": sub["id"]}
        with open_stream(gw, sub) as stream:
            assert "payload" in stream.next(timeout=5)
            worker = gw.worker_of(stream.local_port)
            old = gw.rosworker_pid()
            os.kill(worker, signal.SIGSTOP)
            os.kill(old, signal.SIGKILL)
            poll_until(lambda: ros.call("ping", timeout=0.5)["pid"] != old, 40, interval=0.1,
                       message="the new ROS worker")
            assert ros.call("sub_get", args)["interval"] == "slow"       # restored from its state
            assert ros.call("sub_update", {**args, "interval": "fast"})["interval"] == "fast"
            os.kill(worker, signal.SIGCONT)
            worker = None
            # fast is 20 frames a second, slow 2: wait (generously) for a second that is fast.
            poll_until(lambda: _payloads_per_second(stream) >= 10, 30, interval=0,
                       message="frames at the new interval")
        assert gw.get(f"{BASE}/{sub['id']}").json()["interval"] == "fast"
    finally:
        if worker is not None:
            os.kill(worker, signal.SIGCONT)
        ros.close()
        gw.stop()
