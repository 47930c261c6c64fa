"""Direct sends of stream frames (issue 23), through a real gateway and a real publisher.

Under gunicorn the hub writes each frame on the client's connection itself,
framed as the server would frame it: HTTP/1.1 chunks (the connection stays
usable for the next request once the stream ends) and, for an HTTP/1.0
client, the bare event stream.  Slow readers, buffers and metrics are in
tests/system/subscriptions/test_app_streams.py.
"""

from __future__ import annotations

import json
import socket
import time

import pytest
import requests

from common.harness.procs import poll_until
from tests.support.rospub import RosNode

APP = "sender"
TOPIC = "/sender/count"
RATE = 20  # Hz
GATEWAY = ("--workers", "1", "--log-level", "warning")


# The two fixtures read the module that uses them (tests/reliability/test_stream_phase.py imports them):
# its APP publishes a counter on TOPIC (std_msgs/msg/Float64) at RATE, and its gateway (GATEWAY's flags)
# is ready once it serves that topic as data.
@pytest.fixture(scope="module")
def robot(request):
    mod = request.module
    node = RosNode({"node": mod.APP, "publish": [
        {"topic": mod.TOPIC, "type": "std_msgs/msg/Float64", "rate": mod.RATE, "counter": "data"}]}, timeout=60)
    yield node
    node.stop()


@pytest.fixture(scope="module")
def gw(request, robot, gateway):
    mod = request.module
    gw = gateway(*mod.GATEWAY)
    poll_until(lambda: gw.get(f"/apps/{mod.APP}/data{mod.TOPIC}").json()["x-medkit"]["status"] == "data", 30,
               message="the robot's data")
    return gw


def subscribe(gw, duration: int = 60) -> dict:
    r = requests.post(f"{gw.api}/apps/{APP}/cyclic-subscriptions", timeout=10, json={
        "resource": f"/api/v1/apps/{APP}/data{TOPIC}", "interval": "fast", "duration": duration})
    assert r.status_code == 201, r.text
    return r.json()


def read_until(sock: socket.socket, buf: bytes, done, timeout: float = 15.0) -> bytes:
    deadline = time.monotonic() + timeout
    while not done(buf):
        sock.settimeout(max(0.01, deadline - time.monotonic()))
        data = sock.recv(65536)
        if not data:
            break
        buf += data
        assert time.monotonic() < deadline, buf[-300:]
    return buf


def dechunk(body: bytes) -> tuple[bytes, bytes]:
    """The de-chunked body up to its last chunk, and what follows it on the connection."""
    out = b""
    while True:
        size_line, _, rest = body.partition(b"\r\n")
        size = int(size_line, 16)
        assert rest[size:size + 2] == b"\r\n", rest[:size + 10]
        out += rest[:size]
        body = rest[size + 2:]
        if size == 0:
            return out, body


def events_of(text: bytes) -> list[dict]:
    return [json.loads(block[6:]) for block in text.split(b"\n\n") if block.startswith(b"data: ")]


def test_an_http11_stream_is_well_framed_chunks_and_its_connection_serves_the_next_request(gw):
    sub = subscribe(gw, duration=2)
    with socket.create_connection(("127.0.0.1", gw.port), timeout=10) as sock:
        sock.sendall(f"GET {sub['event_source']} HTTP/1.1\r\nHost: x\r\n\r\n".encode())
        raw = read_until(sock, b"", lambda b: b"\r\n0\r\n\r\n" in b)      # the stream expires after 2 s
        head, _, body = raw.partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 200") and b"transfer-encoding: chunked" in head.lower(), head
        text, after = dechunk(body)
        events = events_of(text)
        assert len(events) >= 10, len(events)                          # ~40 at fast; a hang catcher
        values = [e["payload"]["data"]["data"] for e in events]
        assert values == sorted(values) and values[-1] > values[0]
        assert after == b""
        # The same connection, kept alive, answers the next request: the framing was exact.
        sock.sendall(b"GET /api/v1/version-info HTTP/1.1\r\nHost: x\r\n\r\n")
        raw = read_until(sock, b"", lambda b: b"\r\n\r\n" in b and b"}" in b)
        assert raw.startswith(b"HTTP/1.1 200"), raw[:200]


def test_an_http10_client_gets_the_bare_event_stream(gw):
    sub = subscribe(gw, duration=2)
    with socket.create_connection(("127.0.0.1", gw.port), timeout=10) as sock:
        sock.sendall(f"GET {sub['event_source']} HTTP/1.0\r\nHost: x\r\n\r\n".encode())
        raw = read_until(sock, b"", lambda b: False)                    # until the server closes it
    head, _, body = raw.partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.0 200") and b"transfer-encoding" not in head.lower(), head
    assert body.startswith(b"data: {"), body[:100]
    events = events_of(body)
    assert len(events) >= 10 and all("payload" in e for e in events), len(events)
