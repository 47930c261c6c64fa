"""Scenario 8, security through the whole gateway.

- the runtime dir is 0700 (a loose one is tightened), the socket and the
  lock files are not accessible to others;
- a second ``sovd-gateway`` or a stray ``sovd-rosworker`` on the same runtime
  dir refuses to start while the first gateway keeps serving under load, and
  the socket keeps answering for the first gateway's ROS worker;
- publishing is refused (403) unless enabled, and with an API token a PUT
  without it (401) or with a wrong one (403) is refused -- and in every
  refused case a real ROS subscriber in another process receives nothing,
  while the same PUT with the right token reaches it;
- the request body limit is enforced (413) and an oversized message is not
  published either.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import stat
import sys
import tempfile
import time
from pathlib import Path

from common.harness.procs import Proc, free_port, poll_until
from ipc import protocol
from ipc.client import RosWorkerClient
from tests.reliability.load import (
    Client,
    Load,
    Req,
    gateway_procs,
    problem,
    raw_exchange,
    record,
    restarts_in,
)
from tests.support.rospub import RosNode
from tests.support.rosworker import call_once

BIN = Path(sys.executable).parent
TOKEN = "reliability-token-0123456789abcdef"
CMD = "/security/cmd"
QUIET = 2.0  # seconds a refused message is given to show up at the subscriber anyway


def listener(nodes: list) -> RosNode:
    node = RosNode({"node": "sec_listener",
                    "subscribe": [{"topic": CMD, "type": "std_msgs/msg/String", "echo": True}]})
    nodes.append(node)
    return node


def heard(node: RosNode) -> list[str]:
    return [m["data"]["data"] for m in node.echoed() if m["topic"] == CMD]


def put(gw, host: str, text: str, headers: dict | None = None, path: str = CMD):
    body = json.dumps({"type": "std_msgs/msg/String", "data": {"data": text}}).encode()
    return Client(gw.port).request("PUT", f"/api/v1/components/{host}/data{path}", body,
                                   {"Content-Type": "application/json", **(headers or {})})


def test_runtime_dir_socket_and_locks_are_private():
    """Started by hand (the test helper would tighten the directory itself) on a 0755 directory."""
    loose = tempfile.mkdtemp(prefix="sovd-loose-")
    os.chmod(loose, 0o755)
    port = free_port()
    gw = Proc([str(BIN / "sovd-gateway"), "--bind", f"127.0.0.1:{port}", "--runtime-dir", loose,
               "--log-level", "warning"], name="sovd-gateway")
    try:
        client = Client(port, timeout=2)
        poll_until(lambda: client.get_json("/api/v1/health")[1]["x-medkit-subscription-executor"]["worker_alive"],
                   60, interval=0.2, message="gateway healthy")
        client.close()
        mode = stat.S_IMODE(os.stat(loose).st_mode)
        assert mode == 0o700, f"runtime dir is {mode:o}"
        sock = os.path.join(loose, protocol.SOCKET_NAME)
        assert stat.S_ISSOCK(os.stat(sock).st_mode)
        assert os.stat(sock).st_mode & 0o077 == 0, f"socket is {stat.S_IMODE(os.stat(sock).st_mode):o}"
        poll_until(lambda: os.path.exists(os.path.join(loose, "restart-state.json")), 10, message="pool list saved")
        for name in (protocol.LOCK_NAME, "supervisor.lock", "restart-state.json"):
            path = os.path.join(loose, name)
            assert os.stat(path).st_mode & 0o077 == 0, f"{name} is {stat.S_IMODE(os.stat(path).st_mode):o}"
        others = {n: stat.S_IMODE(os.stat(os.path.join(loose, n)).st_mode) for n in os.listdir(loose)}
        record("security: runtime dir", requests=0,
               note="dir 700 (was 755); " + ", ".join(f"{n} {m:o}" for n, m in sorted(others.items())))
    finally:
        assert gw.stop() == 0
        shutil.rmtree(loose, ignore_errors=True)


def test_second_gateway_and_stray_worker_refuse_while_the_first_serves(gateways, nodes):
    nodes.append(RosNode({"node": "sec_pub", "publish": [
        {"topic": "/security/live", "type": "std_msgs/msg/Float64", "rate": 20}]}))
    gw = gateways("--log-level", "warning")
    host = gw.get("/components").json()["items"][0]["id"]
    path = f"/api/v1/components/{host}/data/security/live"
    poll_until(lambda: gw.get(path[len("/api/v1"):]).json()["x-medkit"]["status"] == "data", 30,
               message="live data")
    first_worker = call_once(gw.runtime_dir, "ping")["pid"]
    load = Load(gw.port, lambda rng: Req("read", "GET", path), 4).start()
    try:
        second = Proc([str(BIN / "sovd-gateway"), "--bind", f"127.0.0.1:{free_port()}",
                       "--runtime-dir", gw.runtime_dir], name="second sovd-gateway")
        stray = Proc([str(BIN / "sovd-rosworker"), "--runtime-dir", gw.runtime_dir], name="stray rosworker")
        try:
            second_code = second.proc.wait(60)
            stray_code = stray.proc.wait(60)
        finally:
            second.stop()
            stray.stop()
        # The socket still belongs to the first gateway's ROS worker, which kept serving.
        assert call_once(gw.runtime_dir, "ping")["pid"] == first_worker == gateway_procs(gw.pid).rosworker.pid
        time.sleep(1.0)
    finally:
        load.stop()
    answers = load.join(30)
    record("security: second instance", answers, restarts=restarts_in(gw.output),
           note=f"second sovd-gateway exit {second_code}, stray sovd-rosworker exit {stray_code}")
    assert second_code != 0 and stray_code != 0, (second_code, stray_code)
    assert "another sovd-gateway" in "\n".join(second.output)
    assert answers and all(a.key == "200" for a in answers), {a.key for a in answers}
    assert restarts_in(gw.output) == 0 and gw.proc.poll() is None


def test_publishing_is_refused_unless_enabled_and_nothing_reaches_ros(gateways, nodes):
    node = listener(nodes)
    gw = gateways("--log-level", "warning")
    host = gw.get("/components").json()["items"][0]["id"]
    poll_until(lambda: CMD in {t["id"] for t in gw.get("/apps/sec_listener/data").json()["items"]}, 30,
               message="listener discovered")
    status, headers, body = put(gw, host, "must-not-arrive")
    assert status == 403 and problem(status, headers, body) is None
    assert json.loads(body)["error_code"] == "forbidden"
    time.sleep(QUIET)
    assert heard(node) == []
    client = RosWorkerClient.for_runtime_dir(gw.runtime_dir)
    try:
        assert client.call("stats", timeout=5)["details"]["publishers"] == 0  # none was even created
    finally:
        client.close()
    record("security: publish disabled", requests=1, statuses={str(status): 1}, note="PUT refused, nothing heard")


def test_api_token_is_required_and_refused_writes_publish_nothing(gateways, nodes):
    node = listener(nodes)
    # (no failure limit: this test makes more failed attempts from one address than the default allows)
    gw = gateways("--allow-publish", "--api-token", TOKEN, "--log-level", "warning", "--auth-failure-limit", "")
    host = gw.get("/components").json()["items"][0]["id"]
    poll_until(lambda: CMD in {t["id"] for t in gw.get("/apps/sec_listener/data").json()["items"]}, 30,
               message="listener discovered")
    attempts = {
        "no header": ({}, 401),
        "empty bearer": ({"Authorization": "Bearer "}, 401),
        "basic auth": ({"Authorization": "Basic " + base64.b64encode(f"x:{TOKEN}".encode()).decode()}, 401),
        "token without scheme": ({"Authorization": TOKEN}, 401),
        "wrong token": ({"Authorization": "Bearer wrong-token-0123456789abcdef"}, 401),
        "token prefix": ({"Authorization": "Bearer " + TOKEN[:-1]}, 401),
        "token plus a byte": ({"Authorization": "Bearer " + TOKEN + "x"}, 401),
        "token twice": ({"Authorization": f"Bearer {TOKEN} {TOKEN}"}, 401),
        "upper-cased token": ({"Authorization": "Bearer " + TOKEN.upper()}, 401),
        "token in another header": ({"X-Api-Token": TOKEN}, 401),
        "huge token": ({"Authorization": "Bearer " + "a" * 6000}, 401),
    }
    statuses = {}
    for i, (name, (headers, expected)) in enumerate(attempts.items()):
        status, answer_headers, body = put(gw, host, f"refused-{i}", headers)
        statuses[name] = status
        assert status == expected, (name, status, body[:200])
        assert problem(status, answer_headers, body) is None, (name, body[:200])
        if status == 401:
            assert answer_headers.get("www-authenticate", "").startswith("Bearer")
    # Token in the query string and a non-ASCII (latin-1) header value: refused, never a 500.
    status, _, _ = Client(gw.port).request(
        "PUT", f"/api/v1/components/{host}/data{CMD}?access_token={TOKEN}",
        json.dumps({"type": "std_msgs/msg/String", "data": {"data": "refused-query"}}).encode(),
        {"Content-Type": "application/json"})
    statuses["token in the query"] = status
    assert status == 401
    raw = (f"PUT /api/v1/components/{host}/data{CMD} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n"
           "Content-Type: application/json\r\nAuthorization: Bearer \xe9\xe8\xff\r\n").encode("latin-1")
    body = json.dumps({"type": "std_msgs/msg/String", "data": {"data": "refused-latin1"}}).encode()
    status, _ = raw_exchange(gw.port, raw + f"Content-Length: {len(body)}\r\n\r\n".encode() + body)
    statuses["latin-1 token"] = status
    assert status == 401, status   # a bad token is medkit's 401 invalid_token
    time.sleep(QUIET)
    assert heard(node) == [], f"refused writes were published: {heard(node)}"
    # The positive control: the right token publishes, and the listener hears exactly that.
    status, _, body = put(gw, host, "authorized", {"Authorization": f"Bearer {TOKEN}"})
    assert status == 200, body
    poll_until(lambda: heard(node) == ["authorized"], 15, message="the authorized message heard")
    time.sleep(0.5)
    assert heard(node) == ["authorized"]
    record("security: API token", requests=len(statuses) + 1,
           statuses={str(s): list(statuses.values()).count(s) for s in set(statuses.values())} | {"200": 1},
           note="refused PUTs published nothing; the right token did")


def test_body_limit_is_enforced_and_oversized_messages_are_not_published(gateways, nodes):
    node = listener(nodes)
    limit = 2048
    gw = gateways("--allow-publish", "--max-body-bytes", str(limit), "--log-level", "warning")
    host = gw.get("/components").json()["items"][0]["id"]
    poll_until(lambda: CMD in {t["id"] for t in gw.get("/apps/sec_listener/data").json()["items"]}, 30,
               message="listener discovered")
    path = f"/api/v1/components/{host}/data{CMD}"

    def body_of(size: int, text: str) -> bytes:
        skeleton = json.dumps({"type": "std_msgs/msg/String", "data": {"data": text}}).encode()
        pad = size - len(skeleton)
        return json.dumps({"type": "std_msgs/msg/String", "data": {"data": text + " " * pad}}).encode()

    results = {}
    over = body_of(limit + 1, "over")
    results["one byte over"] = Client(gw.port).request("PUT", path, over, {"Content-Type": "application/json"})
    head = f"PUT {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\nContent-Type: application/json\r\n"
    chunked_body = body_of(4 * limit, "chunked")
    chunks = b"".join(b"%x\r\n%s\r\n" % (len(chunked_body[i:i + 500]), chunked_body[i:i + 500])
                      for i in range(0, len(chunked_body), 500)) + b"0\r\n\r\n"
    status, _ = raw_exchange(gw.port, (head + "Transfer-Encoding: chunked\r\n\r\n").encode() + chunks)
    results["chunked over"] = (status,)
    started = time.monotonic()
    status, _ = raw_exchange(gw.port, (head + "Content-Length: 1000000000\r\n\r\n").encode() + b"{}", timeout=10)
    results["claims 1 GB"] = (status, time.monotonic() - started)
    for name, result in results.items():
        assert result[0] == 413, (name, result)
    assert results["claims 1 GB"][1] < 5, "the gateway waited for a body it was going to refuse"
    r = results["one byte over"]
    assert json.loads(r[2])["error_code"] == "payload-too-large" and problem(r[0], r[1], r[2]) is None
    time.sleep(QUIET)
    assert heard(node) == []
    exact = body_of(limit, "exact")
    assert len(exact) == limit
    status, _, body = Client(gw.port).request("PUT", path, exact, {"Content-Type": "application/json"})
    assert status == 200, body
    poll_until(lambda: [t.strip() for t in heard(node)] == ["exact"], 15, message="message at the limit heard")
    record("security: body limit", requests=len(results) + 1,
           statuses={"413": len(results), "200": 1}, note=f"--max-body-bytes {limit}")
