"""Triggers through a real gateway, from real publishers whose every message the test chooses.

Each condition (path, NaN and infinities included) on a chosen sequence of
messages, one-shot and its event delivered to a stream opened after it
fired, lifetime and PUT, DELETE ending a live stream, who may write when a
token is set, a trigger made through one HTTP worker and streamed through
the other, one take per message however many triggers watch the topic.  At
the end, each on its own gateway: persistence across a ROS worker SIGKILL
and a gateway restart, and a 1 kHz topic with 50 triggers.
"""

from __future__ import annotations

import http.client
import itertools
import json
import os
import shutil
import signal
import sqlite3
import tempfile
import time

import psutil
import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.linepub import LinePublisher
from tests.support.rospub import RosNode
from tests.support.sse import EventStream

TOKEN = "trigger-secret-for-tests"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
_names = itertools.count(1)


@pytest.fixture(scope="module")
def gw(gateway):
    return gateway("--workers", "2", "--log-level", "warning", "--api-token", TOKEN)


class Topic:
    """A publisher of its own (one node, one topic) and the app the gateway shows for it."""

    def __init__(self, gw: Gateway, type_name: str = "std_msgs/msg/Float64"):
        n = next(_names)
        self.app = f"trig_node_{os.getpid()}_{n}"
        self.topic = f"/trig{n}/value"
        self.pub = LinePublisher(self.app, self.topic, type_name)
        self.gw = gw
        poll_until(lambda: gw.get(f"/apps/{self.app}").status_code == 200, 30, message=f"app {self.app}")
        self.base = f"/apps/{self.app}/triggers"
        self.resource = f"/api/v1/apps/{self.app}/data{self.topic}"

    def create(self, condition: dict, watch: bool = True, **fields) -> dict:
        r = requests.post(self.gw.api + self.base, json={"resource": self.resource, "trigger_condition": condition,
                                                         **fields}, headers=AUTH, timeout=10)
        assert r.status_code == 201, r.text
        if watch:
            self.pub.wait_subscribers(1)  # the ROS worker's subscription for triggers has matched
        return r.json()

    def stream(self, trigger: dict, **kw) -> EventStream:
        stream = EventStream(self.gw.port, trigger["event_source"], **kw)
        assert stream.status == 200, stream.body
        assert stream.headers["content-type"].startswith("text/event-stream")
        assert stream.headers["cache-control"] == "no-cache"
        return stream

    def close(self) -> None:
        self.pub.stop()


@pytest.fixture
def topic(gw):
    made = Topic(gw)
    yield made
    made.close()


def stats(gw) -> dict:
    return gw.get("/health").json()["x-medkit-streams"]


def test_on_change_fires_on_the_first_value_and_each_change_and_two_nan_are_no_change(gw, topic):
    trig = topic.create({"condition_type": "OnChange"}, multishot=True, lifetime=60)
    confirmed = stats(gw)["subscriptions_confirmed"]
    with topic.stream(trig) as stream:
        # The head came once the ROS worker had the stream's subscription (app/sse/channel.py).
        assert stats(gw)["subscriptions_confirmed"] > confirmed
        for value in (1.0, 1.0, 2.0, float("nan"), float("nan"), float("inf"), float("inf"), 3.0):
            topic.pub.send({"data": value})
        got = stream.take(5, timeout=10)
        assert [e["payload"] for e in got] == [{"data": 1.0}, {"data": 2.0}, {"data": "NaN"},
                                               {"data": "Infinity"}, {"data": 3.0}], stats(gw)
        assert all(e["timestamp"].endswith("Z") and "error" not in e for e in got)
        assert stream.collect(0.5) == []  # nothing more: the repeats did not fire


def test_enter_and_leave_range_fire_on_the_crossing_only_with_one_take_per_message(gw, topic):
    bounds = {"lower_bound": 0, "upper_bound": 10}
    enter = topic.create({"condition_type": "EnterRange", **bounds}, path="/data", multishot=True)
    leave = topic.create({"condition_type": "LeaveRange", **bounds}, path="/data", multishot=True)
    extra = [topic.create({"condition_type": "OnChangeTo", "target_value": -1.0}, path="/data", multishot=True)
             for _ in range(2)]
    # Without a path the value is the whole message ({"data": x}), which is in no range: never fires.
    extra.append(topic.create({"condition_type": "LeaveRange", **bounds}, multishot=True))
    before = stats(gw)["trigger_messages"]
    values = [5.0, 20.0, 15.0, 10.0, float("nan"), 3.0, 0.0, -0.5]
    with topic.stream(enter) as entered, topic.stream(leave) as left:
        for value in values:
            topic.pub.send({"data": value})
        assert [e["payload"]["data"] for e in entered.take(2, timeout=10)] == [10.0, 3.0], stats(gw)
        assert [e["payload"]["data"] for e in left.take(3, timeout=10)] == [20.0, "NaN", -0.5], stats(gw)
        assert entered.collect(0.3) == [] and left.collect(0.1) == []
    # One take and one evaluation per message, for five triggers on the topic.
    poll_until(lambda: stats(gw)["trigger_messages"] - before >= len(values), 10, message="messages counted")
    assert stats(gw)["trigger_messages"] - before == len(values)
    for trig in (enter, leave, *extra):
        assert requests.delete(topic.gw.api + f"{topic.base}/{trig['id']}", headers=AUTH, timeout=10).status_code == 204


def test_on_change_to_with_a_path_into_the_message(gw):
    temp = Topic(gw, "sensor_msgs/msg/Temperature")
    try:
        trig = temp.create({"condition_type": "OnChangeTo", "target_value": 50}, path="/temperature",
                           multishot=True)
        assert trig["path"] == "/temperature"
        with temp.stream(trig) as stream:
            for n, value in enumerate((10.0, 50.0, 50.0, 20.0, 50.0)):
                temp.pub.send({"temperature": value, "variance": float(n)})
            got = [e["payload"] for e in stream.take(2, timeout=10)]
            assert [(p["temperature"], p["variance"]) for p in got] == [(50.0, 1.0), (50.0, 4.0)]
            assert set(got[0]) == {"header", "temperature", "variance"}  # the message itself
            assert stream.collect(0.3) == []
        # A path the message does not have: no value, nothing evaluated, nothing fired.
        miss = temp.create({"condition_type": "OnChange"}, path="/nope/0", multishot=True)
        with temp.stream(miss) as stream:
            temp.pub.send({"temperature": 1.0})
            assert stream.collect(0.5) == []
    finally:
        temp.close()


def test_a_one_shot_fires_once_reaches_a_stream_opened_later_and_ends(gw, topic):
    trig = topic.create({"condition_type": "OnChange"}, lifetime=60)
    assert trig["multishot"] is False
    topic.pub.send({"data": 7.0})
    poll_until(lambda: gw.get(f"{topic.base}/{trig['id']}").json()["status"] == "terminated", 10,
               message="the one-shot trigger terminated")
    topic.pub.send({"data": 8.0})
    with topic.stream(trig) as stream:  # opened after it fired: its one event, then the end
        assert stream.next(timeout=5)["payload"] == {"data": 7.0}
        assert stream.next(timeout=5) is None
    r = gw.get(f"{topic.base}/{trig['id']}/events")
    assert r.status_code == 404 and r.json()["message"] == "Trigger expired or inactive"


def test_a_live_one_shot_stream_gets_the_event_and_ends(gw, topic):
    trig = topic.create({"condition_type": "EnterRange", "lower_bound": 0, "upper_bound": 1}, path="/data")
    with topic.stream(trig) as stream:
        for value in (5.0, 0.5, 5.0, 0.5):
            topic.pub.send({"data": value})
        assert stream.next(timeout=10)["payload"] == {"data": 0.5}
        assert stream.next(timeout=5) is None


def test_lifetime_ends_the_trigger_and_its_stream_and_put_counts_from_now(gw, topic):
    short = topic.create({"condition_type": "OnChange"}, multishot=True, lifetime=2)
    renewed = topic.create({"condition_type": "OnChange"}, multishot=True, lifetime=2)
    with topic.stream(short) as stream:
        r = requests.put(gw.api + f"{topic.base}/{renewed['id']}", json={"lifetime": 6}, headers=AUTH, timeout=10)
        assert r.status_code == 200 and r.json()["lifetime"] == 6
        started = time.monotonic()
        assert stream.ended(10)
        assert 1.0 <= time.monotonic() - started <= 8  # generous: it ends at its lifetime, not at once
    assert gw.get(f"{topic.base}/{short['id']}").status_code == 404
    assert gw.get(f"{topic.base}/{renewed['id']}").status_code == 200  # past its first lifetime
    poll_until(lambda: gw.get(f"{topic.base}/{renewed['id']}").status_code == 404, 15,
               message="the renewed trigger expired")


def test_delete_ends_a_live_stream_at_once(gw, topic):
    trig = topic.create({"condition_type": "OnChange"}, multishot=True)
    with topic.stream(trig) as stream:
        topic.pub.send({"data": 1.0})
        assert stream.next(timeout=10)["payload"] == {"data": 1.0}
        assert requests.delete(gw.api + f"{topic.base}/{trig['id']}", headers=AUTH, timeout=10).status_code == 204
        assert stream.ended(3)
    assert gw.get(f"{topic.base}/{trig['id']}").status_code == 404
    assert trig["id"] not in [t["id"] for t in gw.get(topic.base).json()["items"]]


def test_writes_need_the_token_reads_do_not(gw, topic):
    body = {"resource": topic.resource, "trigger_condition": {"condition_type": "OnChange"}}
    assert requests.post(gw.api + topic.base, json=body, timeout=10).status_code == 401
    assert requests.post(gw.api + topic.base, json=body, headers={"Authorization": "Bearer no"},
                         timeout=10).status_code == 401
    trig = topic.create({"condition_type": "OnChange"}, watch=False, multishot=True)
    url = gw.api + f"{topic.base}/{trig['id']}"
    assert requests.put(url, json={"lifetime": 5}, timeout=10).status_code == 401
    assert requests.delete(url, timeout=10).status_code == 401
    assert gw.get(f"{topic.base}/{trig['id']}").status_code == 200
    assert requests.delete(url, headers=AUTH, timeout=10).status_code == 204


def test_a_trigger_made_through_one_worker_streams_through_the_other(gw, topic):
    body = json.dumps({"resource": topic.resource, "trigger_condition": {"condition_type": "OnChange"},
                       "multishot": True})
    for attempt in range(40):
        conn = http.client.HTTPConnection("127.0.0.1", gw.port, timeout=10)
        conn.request("POST", "/api/v1" + topic.base, body=body, headers={"Content-Type": "application/json", **AUTH})
        r = conn.getresponse()
        trig = json.loads(r.read())
        assert r.status == 201, trig
        made_by = gw.worker_of(conn.sock.getsockname()[1])
        stream = topic.stream(trig)
        try:
            if gw.worker_of(stream.local_port) != made_by:
                topic.pub.wait_subscribers(1)
                topic.pub.send({"data": float(attempt)})
                assert stream.next(timeout=10)["payload"] == {"data": float(attempt)}
                return
        finally:
            stream.close()
            conn.close()
            requests.delete(gw.api + f"{topic.base}/{trig['id']}", headers=AUTH, timeout=10)
    pytest.fail("every stream landed on the worker that made its trigger")



def test_hostile_trig_commands_are_refused_by_the_ros_worker_and_never_fatal(gw):
    from ipc.errors import IpcError

    base = {"collection": "apps", "entity_id": "x", "resource": "/r", "source": "data", "target": "/trig_ok",
            "bytes": "array", "condition": {"condition_type": "OnChange"}}
    client = gw.rosworker_client()
    try:
        for bad, code in [({"target": "1bad"}, "invalid-topic"), ({"target": "/a//b"}, "invalid-topic"),
                          ({"source": "faults"}, "bad-request"), ({"condition": {"condition_type": "EnterRange"}},
                                                                  "bad-request"),
                          ({"condition": None}, "bad-request"), ({"path": "x"}, "bad-request"),
                          ({"path": "/~9"}, "bad-request"), ({"lifetime": -1}, "bad-request"),
                          ({"lifetime": 2**40}, "bad-request"), ({"multishot": 1}, "bad-request"),
                          ({"bytes": "hex"}, "bad-request"), ({"collection": 5}, "bad-request"),
                          ({"target": None}, "bad-request")]:
            with pytest.raises(IpcError) as err:
                client.call("trig_create", {**base, **bad}, 5)
            assert err.value.code == code, (bad, err.value)
        for cmd in ("trig_get", "trig_open", "trig_delete", "trig_update"):
            with pytest.raises(IpcError) as err:
                client.call(cmd, {"collection": "apps", "entity_id": "x", "id": ["trig_"], "lifetime": 5}, 5)
            assert err.value.code == "no-such-trigger"
        made = client.call("trig_create", base, 5)
        assert made["status"] == "active" and made["target"] == "/trig_ok"
        client.call("trig_delete", {"collection": "apps", "entity_id": "x", "id": made["id"]}, 5)
    finally:
        client.close()
    assert gw.get("/health").json()["x-medkit-subscription-executor"]["worker_alive"]

# ---- on gateways of their own -------------------------------------------------------------------------------
def first_event(topic: Topic, stream: EventStream, values: list[float], rounds: int = 10) -> dict:
    """Publish ``values`` in turn (each a change) until the stream delivers an event; that event."""
    for n in range(rounds * len(values)):
        topic.pub.send({"data": values[n % len(values)]})
        try:
            return stream.next(timeout=2)
        except AssertionError:
            continue  # not matched yet: the next value is a change too
    raise AssertionError(f"no event after {rounds * len(values)} messages")


def listed(gw: Gateway, base: str) -> list[dict]:
    """The app's triggers, once a new ROS worker's graph poll has found the app again (404 before)."""
    answer = poll_until(lambda: (r := gw.get(base)).status_code == 200 and r, 30,
                        message=f"{base} listed by a new ROS worker")
    return answer.json()["items"]


@pytest.fixture
def dirs():
    """A runtime dir and a state dir kept across the gateways of one test (the triggers' rows live in the
    state dir's store)."""
    runtime_dir = tempfile.mkdtemp(prefix="sovd-trig-")
    state_dir = tempfile.mkdtemp(prefix="sovd-trig-state-")
    os.chmod(runtime_dir, 0o700)
    yield runtime_dir, state_dir
    shutil.rmtree(runtime_dir, ignore_errors=True)
    shutil.rmtree(state_dir, ignore_errors=True)


def gateway_on(dirs, workers: str = "1") -> Gateway:
    runtime_dir, state_dir = dirs
    return Gateway("--workers", workers, "--log-level", "warning", "--state-dir", state_dir,
                   runtime_dir=runtime_dir)


def stored_ids(state_dir: str) -> set[str]:
    db = sqlite3.connect(f"file:{os.path.join(state_dir, 'faults.db')}?mode=ro", uri=True)
    try:
        return {row[0] for row in db.execute("SELECT id FROM triggers")}
    finally:
        db.close()


def test_triggers_survive_a_ros_worker_sigkill_and_persistent_ones_a_gateway_restart(dirs):
    gw = gateway_on(dirs, "2")
    topic = None
    try:
        topic = Topic(gw)
        body = {"resource": topic.resource, "trigger_condition": {"condition_type": "OnChange"}, "multishot": True}
        kept = requests.post(gw.api + topic.base, json={**body, "persistent": True, "lifetime": 600}, timeout=10).json()
        lost = requests.post(gw.api + topic.base, json=body, timeout=10).json()
        assert kept["persistent"] is True and lost["persistent"] is False
        assert stored_ids(dirs[1]) == {kept["id"], lost["id"]}  # one row each, written before the 201
        old = gw.rosworker_pid()
        os.kill(old, signal.SIGKILL)
        poll_until(lambda: gw.rosworker_pid() != old and gw.get("/health").json()[
            "x-medkit-subscription-executor"]["worker_alive"], 30, message="the ROS worker restarted")
        ids = {t["id"] for t in listed(gw, topic.base)}
        assert ids == {kept["id"], lost["id"]}  # a worker restart keeps them all
        with EventStream(gw.port, kept["event_source"]) as stream:
            # The killed worker's subscription stays matched for a while (DDS), so a first message
            # may go before the new one has matched: send changing values until one is delivered.
            assert first_event(topic, stream, [4.0, 4.5, 4.25])["payload"]["data"] in (4.0, 4.5, 4.25)
        gw.stop()
        gw = gateway_on(dirs, "2")
        items = listed(gw, topic.base)
        assert [t["id"] for t in items] == [kept["id"]]  # a new gateway: the persistent one only
        assert items[0]["lifetime"] == 600 and items[0]["trigger_condition"] == {"condition_type": "OnChange"}
        poll_until(lambda: stored_ids(dirs[1]) == {kept["id"]}, 10, message="the other's row deleted")
        with EventStream(gw.port, kept["event_source"]) as stream:
            assert first_event(topic, stream, [5.0, 5.5, 5.25])["payload"]["data"] in (5.0, 5.5, 5.25)
    finally:
        gw.stop()
        if topic is not None:
            topic.close()


def test_a_persistent_trigger_is_restored_before_its_topic_exists(dirs):
    gw = gateway_on(dirs)
    topic = None
    try:
        topic = Topic(gw)
        kept = requests.post(gw.api + topic.base, json={
            "resource": topic.resource, "trigger_condition": {"condition_type": "OnChangeTo", "target_value": 9.0},
            "path": "/data",
            "multishot": True, "persistent": True}, timeout=10).json()
        gw.stop()
        topic.close()  # the publisher is gone while the gateway starts
        gw = gateway_on(dirs)
        client = gw.rosworker_client()
        try:
            trig = client.call("trig_get", {"collection": "apps", "entity_id": topic.app, "id": kept["id"]}, 5)
        finally:
            client.close()
        assert trig["status"] == "active"
        topic.pub = LinePublisher(topic.app, topic.topic, "std_msgs/msg/Float64")  # the publisher comes back
        poll_until(lambda: gw.get(f"/apps/{topic.app}").status_code == 200, 30, message="the app is back")
        with EventStream(gw.port, kept["event_source"]) as stream:
            assert stream.status == 200
            topic.pub.wait_subscribers(1)
            topic.pub.send({"data": 9.0})
            assert stream.next(timeout=10)["payload"] == {"data": 9.0}
    finally:
        gw.stop()
        if topic is not None:
            topic.close()


def test_a_damaged_store_restores_only_the_sound_persistent_triggers_and_imports_an_old_triggers_json(dirs):
    runtime_dir, state_dir = dirs
    good = {"id": "trig_00000000000000aa", "collection": "apps", "entity_id": "someone", "resource": "/r",
            "source": "data", "target": "/trig_store/value", "bytes": "array", "path": "/data",
            "condition": {"condition_type": "OnChange"}, "multishot": True, "persistent": True, "lifetime": None,
            "created_at_ns": 1, "client": "", "status": "active", "expires_at_ns": None}
    bad = [{**good, "id": "trig_00000000000000b1", "lifetime": "x"},
           {**good, "id": "trig_00000000000000b2", "condition": {"condition_type": "Sometimes"}},
           {**good, "id": "trig_00000000000000b3", "path": "no-slash"},
           {**good, "id": "trig_00000000000000b4", "persistent": False},
           {**good, "id": "trig_00000000000000b5", "expires_at_ns": 5},
           {**good, "id": "trig_00000000000000b6", "source": "faults"},
           {**good, "id": "trig_00000000000000b7", "multishot": "yes"},
           {**good, "id": "trig_00000000000000b8",
            "condition": {"condition_type": "OnChangeTo", "target_value": "x" * 5000}},  # past the limit
           {k: v for k, v in good.items() if k != "target"} | {"id": "trig_00000000000000b9"}]
    db = sqlite3.connect(os.path.join(state_dir, "faults.db"))
    db.execute("CREATE TABLE triggers (id TEXT PRIMARY KEY, doc TEXT NOT NULL)")
    rows = [(t["id"], json.dumps(t)) for t in [*bad, good]]
    db.executemany("INSERT INTO triggers VALUES (?, ?)", [*rows, ("trig_00000000000000ba", "junk{"),
                                                           ("trig_00000000000000bb", "7")])
    db.commit()
    db.close()
    old = {**good, "id": "trig_00000000000000cc", "path": ""}  # an older gateway's file: imported once
    with open(os.path.join(runtime_dir, "triggers.json"), "w") as fh:
        json.dump({"triggers": [old, {**old, "id": "trig_00000000000000cd", "persistent": False}, "junk"]}, fh)
    gw = gateway_on(dirs)
    try:
        client = gw.rosworker_client()
        try:
            items = client.call("trig_list", {"collection": "apps", "entity_id": "someone"}, 5)["items"]
        finally:
            client.close()
        assert sorted(t["id"] for t in items) == [good["id"], old["id"]]
        assert gw.get("/health").json()["x-medkit-subscription-executor"]["worker_alive"]
        poll_until(lambda: stored_ids(state_dir) == {good["id"], old["id"]}, 10,
                   message="the unsound rows deleted, the imported one written")
        assert not os.path.exists(os.path.join(runtime_dir, "triggers.json"))
        assert os.path.exists(os.path.join(runtime_dir, "triggers.json.imported"))
    finally:
        gw.stop()


def test_a_1khz_topic_with_50_triggers_costs_one_take_per_message_and_counts_what_a_slow_reader_drops():
    app, rate = "trig_fast", 1000
    node = RosNode({"node": app, "namespace": "/tf", "publish": [
        {"topic": "counter", "type": "std_msgs/msg/Float64", "rate": rate, "counter": "data",
         "depth": 100}]}, timeout=60)
    gw = Gateway("--workers", "2", "--log-level", "warning")
    try:
        poll_until(lambda: gw.get(f"/apps/{app}").status_code == 200, 30, message="the fast app")
        base = f"/apps/{app}/triggers"
        body = {"resource": f"/api/v1/apps/{app}/data/tf/counter", "trigger_condition": {"condition_type": "OnChange"},
                "multishot": True}
        triggers = [requests.post(gw.api + base, json=body, timeout=10).json() for _ in range(50)]
        assert all(t.get("status") == "active" for t in triggers), [t for t in triggers if t.get("status") != "active"][:2]
        reader = EventStream(gw.port, triggers[0]["event_source"])
        stalled = EventStream(gw.port, triggers[1]["event_source"], recv_buffer=4096)  # never read
        worker = psutil.Process(gw.rosworker_pid())
        try:
            first = reader.next(timeout=10)["payload"]["data"]
            before, cpu0, t0 = stats(gw), sum(worker.cpu_times()[:2]), time.monotonic()
            time.sleep(3)
            after, cpu1, t1 = stats(gw), sum(worker.cpu_times()[:2]), time.monotonic()
            took = after["trigger_messages"] - before["trigger_messages"]
            fired = after["trigger_events"] - before["trigger_events"]
            assert 0 < took <= rate * (t1 - t0) * 1.2 + 100  # at most one take per message published
            assert fired == 50 * took or abs(fired - 50 * took) <= 50 * 2  # each trigger fires on each change
            frames = after["trigger_frames"] - before["trigger_frames"]
            assert abs(frames - took) <= 2  # one frame a message crossed to the HTTP workers, for all 50
            assert (cpu1 - cpu0) / (t1 - t0) < 1.8  # generous: bounded, not a hang or a spin on two cores
            events = reader.collect(1.0)
            values = [e["payload"]["data"] for e in events]
            assert values == sorted(values) and values[0] > first  # in order, and current
            poll_until(lambda: stats(gw)["frames_dropped"] > 0, 20, message="the stalled reader's drops counted")
        finally:
            reader.close()
            stalled.close()
    finally:
        gw.stop()
        node.stop()
