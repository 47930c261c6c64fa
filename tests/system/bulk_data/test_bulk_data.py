"""Bulk data through the real gateway (issue 32): fault recordings and medkit's bulk-data routes.

Real publishers in other processes, a real ``/diagnostics`` publisher (WARN, then ERROR, confirms a
fault), the real ``sovd-gateway``; the recording is downloaded over HTTP, read back with ``mcap``'s
reader and decoded with ``mcap-ros2-support`` (nothing of the gateway's own code reads it), and its
messages are compared with what the publishers sent: consecutive counters, exact fields.
"""

from __future__ import annotations

import io
import json
import os
import signal
import time
from datetime import datetime

import pytest
import requests
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from common.harness.procs import poll_until
from tests.support.rospub import publisher, unique_topic

pytestmark = pytest.mark.timeout(300)

DURATION_S, AFTER_S = 2.0, 0.5
RATE_HZ = 50
UPLOAD_CAP = 64 * 1024


def _ms(text: str) -> float:
    return datetime.fromisoformat(text.replace("Z", "+00:00")).timestamp()


@pytest.fixture(scope="module")
def robot():
    """Two recorded topics (nested types: Header and Time, Vector3) and one that is not recorded."""
    temp, cmd, other = unique_topic("robot/temperature"), unique_topic("robot/cmd_vel"), unique_topic("robot/x")
    pubs = [publisher("temp_sensor", temp, "sensor_msgs/msg/Temperature",
                      {"variance": 0.25, "header": {"frame_id": "probe"}}, rate=RATE_HZ, counter="temperature"),
            publisher("driver", cmd, "geometry_msgs/msg/Twist", {"angular": {"z": 0.5}}, rate=RATE_HZ,
                      counter="linear.x"),
            publisher("other", other, "std_msgs/msg/Float64", {"data": 1.0}, rate=10)]
    yield {"temp": temp, "cmd": cmd, "other": other}
    for pub in pubs:
        pub.stop()


@pytest.fixture(scope="module")
def gw(robot, gateway):
    return gateway("--fault-rosbag-enabled", "--fault-rosbag-topics", f"{robot['temp']},{robot['cmd']}",
                   "--fault-rosbag-duration-s", str(DURATION_S), "--fault-rosbag-duration-after-s", str(AFTER_S),
                   "--allow-fault-clear", "--allow-bulk-data", "--bulk-data-categories", "calibration,firmware",
                   "--bulk-data-max-upload-size", str(UPLOAD_CAP))


@pytest.fixture
def fault(gw, diag):
    """``fault(node, *names)``: a real diagnostics publisher that reports WARN, then ERROR for each status
    name (confirming them); the recording's descriptor once it is listed under the node's app."""
    def make(node: str, *names: str) -> dict:
        pub = diag(node)
        known(gw, node)
        full = 2 * RATE_HZ * DURATION_S * 0.95  # the ring holds the whole window of both topics before the fault
        poll_until(lambda: gw.get("/health").json()["x-medkit-bulk-data"]["rosbag_buffer_messages"] >= full, 30,
                   message="the ring buffer full")
        pub.set([{"name": f"{node}: {n}", "level": 1, "message": "warm"} for n in names])
        pub.set([{"name": f"{node}: {n}", "level": 2, "message": "hot"} for n in names])
        return poll_until(lambda: gw.get(f"/apps/{node}/bulk-data/rosbags").json()["items"], 20,
                          message="a recording listed")[0]
    return make


def known(gw, node: str) -> None:
    """Wait until the gateway's graph knows the node: its first status is then attributed to it (a status
    that comes before its node is known may be put on another /diagnostics publisher)."""
    poll_until(lambda: gw.get(f"/apps/{node}").status_code == 200, 30, message=f"the app {node}")


def _read(blob: bytes) -> tuple[object, dict[str, list], list]:
    """(header, {topic: [(log_time, publish_time, decoded)]}, schemas) of an MCAP file, with mcap's own reader."""
    reader = make_reader(io.BytesIO(blob), decoder_factories=[DecoderFactory()])
    out: dict[str, list] = {}
    for _schema, channel, message, decoded in reader.iter_decoded_messages():
        out.setdefault(channel.topic, []).append((message.log_time, message.publish_time, decoded))
    summary = reader.get_summary()
    return reader.get_header(), out, summary


def _consecutive(values: list[float]) -> bool:
    return all(b == a + 1 for a, b in zip(values, values[1:], strict=False))


def test_a_confirmed_fault_gets_a_recording_of_what_led_up_to_it(gw, robot, fault):
    rec = fault("motor", "overheat")
    assert rec["mimetype"] == "application/x-mcap" and rec["x-medkit"]["fault_codes"] == ["MOTOR_OVERHEAT"]
    assert rec["id"] == rec["x-medkit"]["recording_id"] and rec["id"].startswith("fault_MOTOR_OVERHEAT_")
    assert sorted(rec["x-medkit"]["topics"]) == sorted([robot["temp"], robot["cmd"]])
    # the span it covers: the window before the fault, then duration_after_s after it
    assert rec["x-medkit"]["duration_sec"] >= DURATION_S + AFTER_S - 0.3, rec
    confirmed = _ms(rec["creation_date"])

    # The fault's detail lists it as medkit's rosbag snapshot, under the entity asked.
    detail = gw.get("/apps/motor/faults/MOTOR_OVERHEAT").json()
    bags = [s for s in detail["environment_data"]["snapshots"] if s["type"] == "rosbag"]
    assert bags == [{"type": "rosbag", "name": f"rosbag_{rec['id']}",
                     "bulk_data_uri": f"/apps/motor/bulk-data/rosbags/{rec['id']}", "size_bytes": rec["size"],
                     "duration_sec": rec["x-medkit"]["duration_sec"], "format": "mcap",
                     "x-medkit": {"topics": rec["x-medkit"]["topics"], "messages": rec["x-medkit"]["messages"],
                                  "captured_at": rec["creation_date"]}}]

    r = requests.get(gw.api + bags[0]["bulk_data_uri"], timeout=30)
    assert r.status_code == 200 and len(r.content) == rec["size"] == int(r.headers["Content-Length"])
    assert r.headers["Content-Type"] == "application/x-mcap" and r.headers["Accept-Ranges"] == "bytes"
    assert r.headers["Content-Disposition"] == f'attachment; filename="{rec["id"]}.mcap"'
    header, topics, summary = _read(r.content)
    assert header.profile == "ros2"
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    assert summary.chunk_indexes and {c.compression for c in summary.chunk_indexes} == {"zstd"}
    temperature = next(s for s in summary.schemas.values() if s.name == "sensor_msgs/msg/Temperature").data.decode()
    assert "\nMSG: std_msgs/Header\n" in temperature and "\nMSG: builtin_interfaces/Time\n" in temperature

    # Exactly what was published: every message in order, counters without a gap, the other fields as set.
    temps, cmds = topics[robot["temp"]], topics[robot["cmd"]]
    assert [m.variance for _, _, m in temps] == [0.25] * len(temps)
    assert {m.header.frame_id for _, _, m in temps} == {"probe"}
    assert _consecutive([m.temperature for _, _, m in temps]), [m.temperature for _, _, m in temps]
    assert [m.angular.z for _, _, m in cmds] == [0.5] * len(cmds) and _consecutive([m.linear.x for _, _, m in cmds])
    assert robot["other"] not in topics
    for messages in (temps, cmds):
        received = [t / 1e9 for t, _, _ in messages]
        assert received == sorted(received)
        # duration_s before the confirmation (the window is by receive time), and duration_after_s after it
        assert confirmed - DURATION_S - 0.3 <= received[0] <= confirmed - DURATION_S + 0.5, (received[0], confirmed)
        assert received[-1] > confirmed  # what came after it too (a loaded machine may delay the publishers)
        assert all(0 < p <= t + 1e8 for t, p, _ in messages)  # publish time: the publisher's source time
        assert len(messages) >= RATE_HZ * (DURATION_S + AFTER_S) * 0.7

    # Resumable: the second half with Range and If-Range, then both halves are the file.
    half = rec["size"] // 2
    first = requests.get(gw.api + bags[0]["bulk_data_uri"], headers={"Range": f"bytes=0-{half - 1}"}, timeout=30)
    rest = requests.get(gw.api + bags[0]["bulk_data_uri"], timeout=30,
                        headers={"Range": f"bytes={half}-", "If-Range": r.headers["ETag"]})
    assert (first.status_code, rest.status_code) == (206, 206)
    assert rest.headers["Content-Range"] == f"bytes {half}-{rec['size'] - 1}/{rec['size']}"
    assert first.content + rest.content == r.content
    past = requests.get(gw.api + bags[0]["bulk_data_uri"], headers={"Range": f"bytes={rec['size']}-"}, timeout=30)
    assert past.status_code == 416 and past.headers["Content-Range"] == f"bytes */{rec['size']}"

    # On disk: 0600 in <state_dir>/rosbags, nothing else there.
    path = os.path.join(gw.state_dir, "rosbags", rec["id"] + ".mcap")
    assert os.stat(path).st_mode & 0o777 == 0o600 and open(path, "rb").read() == r.content
    # Scoped like faults: the host component sees it, an app without the fault does not.
    host = gw.host()
    assert rec["id"] in [i["id"] for i in gw.get(f"/components/{host}/bulk-data/rosbags").json()["items"]]
    assert gw.get("/apps/temp_sensor/bulk-data/rosbags").json()["items"] == []
    assert gw.get(f"/apps/temp_sensor/bulk-data/rosbags/{rec['id']}").status_code == 404
    # medkit's older URL: the fault code is its newest recording.
    assert requests.get(gw.api + "/apps/motor/bulk-data/rosbags/MOTOR_OVERHEAT", timeout=30).content == r.content
    health = gw.get("/health").json()["x-medkit-bulk-data"]
    assert health["rosbag_recordings_written"] >= 1 and health["rosbag_write_errors"] == 0
    assert health["rosbag_topics_recorded"] == 2 and health["rosbag_disk_bytes"] >= rec["size"]
    metrics = requests.get(gw.url + "/metrics", timeout=10).text
    assert "sovd_ros_rosbag_recordings_written_total" in metrics and "sovd_ros_rosbag_buffer_bytes" in metrics


def test_a_recorded_topic_read_over_http_is_subscribed_once(gw, robot):
    import rclpy
    from rclpy.node import Node

    for topic in (robot["temp"], robot["cmd"]):
        data = poll_until(lambda t=topic: gw.get(f"/components/{gw.host()}/data{t}").json().get("data"), 15)
        assert data
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        node = Node("sub_counter", context=ctx)

        def gateway_subs(topic: str) -> int:
            return sum(1 for i in node.get_subscriptions_info_by_topic(topic) if i.node_name == "sovd_gateway_sub")

        poll_until(lambda: gateway_subs(robot["temp"]) >= 1, 15)
        time.sleep(1.0)  # discovery of a second one would show within this
        assert gateway_subs(robot["temp"]) == 1 and gateway_subs(robot["cmd"]) == 1
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)
    # the pooled read goes on serving fresh values through the shared subscription
    first = gw.get(f"/components/{gw.host()}/data{robot['temp']}").json()["data"]["temperature"]
    poll_until(lambda: gw.get(f"/components/{gw.host()}/data{robot['temp']}").json()["data"]["temperature"] > first,
               5)


def test_a_burst_shares_one_recording_and_a_fault_keeps_its_newest(gw, fault):
    rec = fault("pump", "pressure", "flow")
    assert rec["x-medkit"]["fault_codes"] == ["PUMP_FLOW", "PUMP_PRESSURE"]
    assert len(gw.get("/apps/pump/bulk-data/rosbags").json()["items"]) == 1
    for code in ("PUMP_FLOW", "PUMP_PRESSURE"):
        snaps = gw.get(f"/apps/pump/faults/{code}").json()["environment_data"]["snapshots"]
        assert [s["bulk_data_uri"] for s in snaps if s["type"] == "rosbag"] == [
            f"/apps/pump/bulk-data/rosbags/{rec['id']}"]
    # fault_rosbag_max_bags_per_fault 1: cleared and failing again, PUMP_FLOW keeps its newest recording only;
    # the burst's recording stays while PUMP_PRESSURE keeps it.
    evicted = gw.get("/health").json()["x-medkit-bulk-data"]["rosbag_evicted"]
    assert requests.delete(gw.api + "/apps/pump/faults/PUMP_FLOW", timeout=10).status_code == 204
    # the fault's publisher goes on reporting ERROR: a new occurrence, confirmed, recorded
    newest = poll_until(lambda: [i for i in gw.get("/apps/pump/bulk-data/rosbags").json()["items"]
                                 if i["id"] != rec["id"]], 20, message="a second recording")[0]
    assert newest["x-medkit"]["fault_codes"] == ["PUMP_FLOW"]
    items = {i["id"]: i["x-medkit"]["fault_codes"] for i in gw.get("/apps/pump/bulk-data/rosbags").json()["items"]}
    assert items == {rec["id"]: ["PUMP_PRESSURE"], newest["id"]: ["PUMP_FLOW"]}
    assert gw.get("/health").json()["x-medkit-bulk-data"]["rosbag_evicted"] == evicted  # nothing deleted yet
    assert requests.delete(gw.api + "/apps/pump/faults/PUMP_PRESSURE", timeout=10).status_code == 204
    third = poll_until(lambda: [i for i in gw.get("/apps/pump/bulk-data/rosbags").json()["items"]
                                if i["id"] not in (rec["id"], newest["id"])], 20, message="a third recording")[0]
    assert third["x-medkit"]["fault_codes"] == ["PUMP_PRESSURE"]
    poll_until(lambda: rec["id"] not in {i["id"] for i in gw.get("/apps/pump/bulk-data/rosbags").json()["items"]},
               10, message="the first recording deleted")
    assert not os.path.exists(os.path.join(gw.state_dir, "rosbags", rec["id"] + ".mcap"))
    assert gw.get("/health").json()["x-medkit-bulk-data"]["rosbag_evicted"] == evicted + 1
    assert requests.get(f"{gw.api}/apps/pump/bulk-data/rosbags/{rec['id']}", timeout=10).status_code == 404


def test_uploads_to_a_category_are_listed_downloaded_and_deleted(gw):
    base = f"{gw.api}/components/{gw.host()}/bulk-data"
    assert requests.get(base, timeout=10).json() == {"items": ["rosbags", "calibration", "firmware"]}
    body = os.urandom(40_000)
    r = requests.post(base + "/calibration", timeout=30, files={"file": ("../../motor cal.bin", body,
                                                                         "application/octet-stream")},
                      data={"description": "v2.1", "metadata": json.dumps({"version": "2.1"})})
    assert r.status_code == 201, r.text
    item = r.json()
    assert item["name"] == "motor cal.bin" and item["size"] == len(body) and item["x-medkit"] == {"version": "2.1"}
    assert r.headers["Location"] == f"/api/v1/components/{gw.host()}/bulk-data/calibration/{item['id']}"
    assert requests.get(base + "/calibration", timeout=10).json()["items"] == [item]
    got = requests.get(f"{base}/calibration/{item['id']}", timeout=10)
    assert got.content == body and got.headers["Content-Disposition"] == 'attachment; filename="motor cal.bin"'
    # past the cap: 413, and nothing is kept
    big = requests.post(base + "/firmware", timeout=30, files={"file": ("fw.bin", os.urandom(UPLOAD_CAP + 1))})
    assert big.status_code == 413 and big.json()["error_code"] == "payload-too-large"
    assert requests.get(base + "/firmware", timeout=10).json()["items"] == []
    # names that try to leave the storage directory
    for path in ("/calibration/..%2F..%2Fetc%2Fpasswd", "/..%2Fcalibration", "/calibration/%2E%2E", "/calibration/.x"):
        bad = requests.get(base + path, timeout=10)
        assert bad.status_code == 400 and bad.json()["error_code"] == "invalid-parameter", (path, bad.text)
        assert requests.delete(base + path, timeout=10).status_code == 400
    assert requests.get(base + "/nope", timeout=10).json()["error_code"] == "resource-not-found"
    assert requests.post(base + "/rosbags", files={"file": ("x", b"x")}, timeout=10).status_code == 400
    assert requests.delete(f"{base}/calibration/{item['id']}", timeout=10).status_code == 204
    assert requests.delete(f"{base}/calibration/{item['id']}", timeout=10).status_code == 404
    assert requests.get(base + "/calibration", timeout=10).json()["items"] == []
    root = os.path.join(gw.state_dir, "bulk_data")
    assert not os.listdir(os.path.join(root, ".incoming")) and os.stat(root).st_mode & 0o777 == 0o700


_token = st.text(alphabet=st.characters(codec="latin-1"), max_size=40)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(boundary=st.one_of(st.just("b0und"), _token), preamble=st.binary(max_size=200),
       parts=st.lists(st.tuples(_token, st.one_of(st.none(), _token), st.binary(max_size=3000),
                                st.binary(max_size=100)), max_size=4),
       epilogue=st.sampled_from([b"--b0und--\r\n", b"--b0und", b"", b"--b0und--garbage", b"\r\n--b0und--\r\n"]),
       declared=st.sampled_from(["b0und", "other", ""]))
def test_hostile_multipart_bodies_get_a_clear_answer(gw, boundary, preamble, parts, epilogue, declared):
    """Whatever the body, the answer is the contract's (201, 400, 413 or 415 with JSON), never a 500, and no
    half-received file is left or listed."""
    body = preamble
    for name, filename, data, headers in parts:
        disposition = f'form-data; name="{name}"' + (f'; filename="{filename}"' if filename is not None else "")
        body += f"--{boundary}\r\nContent-Disposition: {disposition}\r\n".encode("latin-1") + headers + b"\r\n\r\n"
        body += data + b"\r\n"
    body += epilogue
    base = f"{gw.api}/components/{gw.host()}/bulk-data/firmware"
    content_type = "multipart/form-data" + (f"; boundary={declared}" if declared else "")
    r = requests.post(base, data=body, headers={"Content-Type": content_type}, timeout=30)
    assert r.status_code in (201, 400, 413, 415), (r.status_code, r.text)
    assert r.headers["Content-Type"] == "application/json" and "error_code" in r.json() or r.status_code == 201
    if r.status_code == 201:
        assert requests.delete(f"{base}/{r.json()['id']}", timeout=10).status_code == 204
    assert not os.listdir(os.path.join(gw.state_dir, "bulk_data", ".incoming"))


def test_a_sigkill_mid_write_leaves_no_listed_partial_file(robot, diag):
    from common.harness.gateway import Gateway

    gw = Gateway("--fault-rosbag-enabled", "--fault-rosbag-topics", robot["temp"], "--fault-rosbag-duration-s", "1",
                 "--fault-rosbag-duration-after-s", "0", "--debug-commands")
    try:
        folder = os.path.join(gw.state_dir, "rosbags")
        pub = diag("hull")
        known(gw, "hull")
        time.sleep(1.5)
        pub.set([{"name": "hull: breach", "level": 2, "message": "wet"}])
        done = poll_until(lambda: gw.get("/apps/hull/bulk-data/rosbags").json()["items"], 20)[0]
        client = gw.rosworker_client()
        try:
            client.call("bulk_debug_pause", {"seconds": 30}, 5)
        finally:
            client.close()
        old = gw.rosworker_pid()
        pub.set([{"name": "hull: leak", "level": 2, "message": "wet"}])
        partial = poll_until(lambda: [n for n in os.listdir(folder) if n.endswith(".mcap.tmp")], 20,
                             interval=0.01, message="a recording being written")[0]
        assert gw.get("/apps/hull/bulk-data/rosbags").json()["items"] == [done]  # never listed while written
        os.kill(old, signal.SIGKILL)
        poll_until(lambda: gw.rosworker_pid() != old and gw.get("/health").json()[
            "x-medkit-subscription-executor"]["worker_alive"], 30, message="a restarted ROS worker")
        assert partial not in os.listdir(folder)  # removed at start
        assert sorted(os.listdir(folder)) == [done["id"] + ".mcap"]
        assert gw.get("/apps/hull/bulk-data/rosbags").json()["items"] == [done]  # the index, rebuilt
        got = requests.get(f"{gw.api}/apps/hull/bulk-data/rosbags/{done['id']}", timeout=10)
        assert got.status_code == 200 and len(got.content) == done["size"]
    finally:
        gw.stop()


def test_an_unwritable_storage_directory_fails_the_recording_alone(robot, diag, tmp_path):
    from common.harness.gateway import Gateway

    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    gw = Gateway("--fault-rosbag-enabled", "--fault-rosbag-topics", robot["temp"], "--fault-rosbag-duration-s", "1",
                 "--fault-rosbag-duration-after-s", "0", "--fault-rosbag-storage-path", str(blocker / "rosbags"),
                 "--bulk-data-storage-dir", str(blocker / "files"), "--bulk-data-categories", "logs",
                 "--allow-bulk-data")
    try:
        pub = diag("keel")
        known(gw, "keel")
        time.sleep(1.5)
        pub.set([{"name": "keel: crack", "level": 2, "message": "bad"}])
        poll_until(lambda: gw.get("/health").json()["x-medkit-bulk-data"]["rosbag_write_errors"] >= 1, 20,
                   message="a counted write error")
        # the fault is there all the same
        poll_until(lambda: gw.get("/apps/keel/faults/KEEL_CRACK").status_code == 200, 20, message="the fault")
        assert gw.get("/apps/keel/bulk-data/rosbags").json() == {"items": []}
        assert gw.get(f"/components/{gw.host()}/data{robot['temp']}").json()["data"]["variance"] == 0.25
        up = requests.post(f"{gw.api}/apps/keel/bulk-data/logs", files={"file": ("a.log", b"x")}, timeout=10)
        assert up.status_code == 500 and "could not be stored" in up.json()["message"], up.text
        assert "worker_alive" in gw.get("/health").json()["x-medkit-subscription-executor"]
    finally:
        gw.stop()
