"""app/http_worker.py through a real gateway: every read from a client has a deadline and holds no thread.

One HTTP worker.  With gevent a connection costs one greenlet of the
worker's ``worker_connections`` pool (64 here), not a thread: the tests stall
more clients at once than the whole gateway had threads before (2 × 8), and
check that ``/health`` is served meanwhile (a generous hang-catching bound)
and that the server closes each stalled connection after its timeout.
"""

from __future__ import annotations

import json
import signal
import socket
import sys
import threading
import time

import psutil
import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import Proc, free_port, poll_until

HEADER_TIMEOUT = 2.0
BODY_TIMEOUT = 2.0
HANG = 5.0  # seconds past a timeout by which the server must have acted: a hang catcher, not a benchmark
HEALTH = b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\n"
STALLED = 24  # more than the 16 threads of the old default (2 workers x 8)
BIG_HEADERS = b"".join(b"X-Big-%d: %s\r\n" % (i, b"a" * 8000) for i in range(9))  # 72 KB: legal (8190 a field)


@pytest.fixture(scope="module")
def gw(gateway):
    return gateway("--workers", "1", "--worker-connections", "64",
                   "--header-timeout", str(HEADER_TIMEOUT), "--body-timeout", str(BODY_TIMEOUT),
                   "--allow-publish", "--log-level", "warning")


@pytest.fixture(scope="module")
def sink(gw) -> str:
    host = gw.get("/components").json()["items"][0]["id"]
    return f"/api/v1/components/{host}/data/http_worker_test/sink"


def connect(gw) -> socket.socket:
    return socket.create_connection(("127.0.0.1", gw.port), timeout=10)


def read_response(sock: socket.socket) -> tuple[int, bytes]:
    """One HTTP/1.1 response with a Content-Length: (status, body)."""
    status, _, body = Responses(sock).next()
    return status, body


def read_response_with_head(sock: socket.socket) -> tuple[int, dict[str, str], bytes]:
    return Responses(sock).next()


class Responses:
    """HTTP/1.1 responses with a Content-Length read one after the other from a socket.

    Keeps what it read past a response: pipelined answers may arrive in one segment.
    """

    def __init__(self, sock: socket.socket):
        self.sock = sock
        self.data = b""

    def _more(self, what: str) -> None:
        chunk = self.sock.recv(65536)
        assert chunk, f"connection closed {what}: {self.data!r}"
        self.data += chunk

    def next(self) -> tuple[int, dict[str, str], bytes]:
        while b"\r\n\r\n" not in self.data:
            self._more("before a response head")
        head, _, rest = self.data.partition(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        headers = {k.strip().lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:])}
        length = int(headers["content-length"])
        self.data = rest
        while len(self.data) < length:
            self._more("inside a response body")
        body, self.data = self.data[:length], self.data[length:]
        return int(lines[0].split()[1]), headers, body


def health_is_served(gw) -> None:
    with connect(gw) as s:
        s.settimeout(HANG)  # a hang catcher: a starved worker would not answer at all
        s.sendall(HEALTH + b"Connection: close\r\n\r\n")
        status, body = read_response(s)
    assert status == 200, body
    assert b'"worker_alive":true' in body.replace(b" ", b"")


def closed_by_server(sock: socket.socket, within: float) -> bool:
    sock.settimeout(within)
    try:
        return sock.recv(1) == b""
    except ConnectionResetError:
        return True
    except TimeoutError:
        return False


def test_a_head_sent_in_pieces_is_answered(gw):
    request = HEALTH + b"Connection: close\r\n\r\n"
    with connect(gw) as s:
        for i in range(0, len(request), 7):
            s.sendall(request[i:i + 7])
            time.sleep(0.02)
        status, body = read_response(s)
    assert status == 200 and b"x-medkit-subscription-executor" in body


def test_stalled_heads_hold_no_thread_and_are_dropped_after_the_header_timeout(gw):
    stalled = [connect(gw) for _ in range(STALLED)]
    try:
        for s in stalled:
            s.sendall(HEALTH)  # the blank line never comes
        health_is_served(gw)
        for s in stalled:
            assert closed_by_server(s, HEADER_TIMEOUT + HANG), "a stalled head was kept past the header timeout"
    finally:
        for s in stalled:
            s.close()
    health_is_served(gw)


def test_idle_connections_hold_no_thread_and_are_dropped_after_the_header_timeout(gw):
    idle = [connect(gw) for _ in range(20)]
    try:
        health_is_served(gw)
        assert all(closed_by_server(s, HEADER_TIMEOUT + HANG) for s in idle)
    finally:
        for s in idle:
            s.close()


def test_a_kept_alive_connection_that_stalls_inside_its_next_head_holds_no_thread(gw):
    conns = [connect(gw) for _ in range(4)]
    try:
        for s in conns:
            s.sendall(HEALTH + b"\r\n")
            assert read_response(s)[0] == 200
            s.sendall(HEALTH)  # the next request on the same connection, half of it
        health_is_served(gw)
        # A client that finishes its head late (within the timeout) is still answered.
        conns[0].sendall(b"\r\n")
        conns[0].settimeout(HANG)
        assert read_response(conns[0])[0] == 200
        # The others never finish theirs: dropped once the header timeout has passed.
        assert all(closed_by_server(s, HEADER_TIMEOUT + HANG) for s in conns[1:])
    finally:
        for s in conns:
            s.close()


def test_pipelined_requests_with_a_partial_last_head(gw):
    with connect(gw) as s:
        s.sendall(HEALTH + b"\r\n" + b"GET /api/v1/version-info HTTP/1.1\r\n")
        status, _ = read_response(s)
        assert status == 200
        health_is_served(gw)  # the partial second head is not read on a thread
        s.sendall(b"Host: x\r\nConnection: close\r\n\r\n")
        status, body = read_response(s)
    assert status == 200 and b"base_uri" in body


def test_an_oversized_head_is_refused_by_the_parser(gw):
    with connect(gw) as s:
        s.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\nX-Big: " + b"a" * 70000 + b"\r\n\r\n")
        s.settimeout(10)
        data = s.recv(65536)
    assert data.split(b" ", 2)[1] in (b"400", b"431"), data[:200]
    health_is_served(gw)


# --------------------------------------------------------------------------------- heads of 64 KiB and more
def test_a_head_of_72_kb_sent_at_once_is_legal_and_answered(gw):
    """The control for the next test: such a head is refused for its slowness, not its size."""
    with connect(gw) as s:
        s.settimeout(HANG)
        s.sendall(HEALTH + BIG_HEADERS + b"Connection: close\r\n\r\n")
        assert read_response(s)[0] == 200


def send_slowly(socks: list[socket.socket], data: bytes, piece: int, pause: float,
                sent: dict[int, int] | None = None) -> dict[int, int]:
    """Send ``data`` on every socket ``piece`` bytes at a time, ``pause`` s apart (run it on a thread).

    ``sent`` (updated as it goes) counts, per socket index, the bytes sent before the
    server closed that socket.
    """
    sent = sent if sent is not None else {}
    sent.update(dict.fromkeys(range(len(socks)), 0))
    gone: set[int] = set()
    for offset in range(0, len(data), piece):
        for i, s in enumerate(socks):
            if i in gone:
                continue
            try:
                s.sendall(data[offset:offset + piece])
                sent[i] += len(data[offset:offset + piece])
            except OSError:  # reset or broken pipe: the server closed the connection
                gone.add(i)
        if len(gone) == len(socks):
            break
        time.sleep(pause)
    return sent


def test_slow_heads_of_64_kib_and_more_hold_nothing_and_are_dropped_after_the_header_timeout(gw):
    head = HEALTH + BIG_HEADERS + b"\r\n"
    socks = [connect(gw) for _ in range(STALLED)]
    sent: dict[int, int] = {}
    # 4 KiB every 0.3 s: the whole head would take ~5.5 s, well past the 2 s header timeout.
    sender = threading.Thread(target=send_slowly, args=(socks, head, 4096, 0.3, sent))
    started = time.monotonic()
    sender.start()
    try:
        poll_until(lambda: len(sent) == STALLED and min(sent.values()) >= 8192, HANG,
                   message="every slow head under way")
        health_is_served(gw)  # while every slow head is being sent
        for s in socks:
            assert closed_by_server(s, HEADER_TIMEOUT + HANG), "a slow 64 KiB+ head was kept past the timeout"
        sender.join(30)
        assert not sender.is_alive()
        # None got its whole head in: each was cut off by the server, not answered.
        assert all(n < len(head) for n in sent.values()), sent
        assert time.monotonic() - started < HEADER_TIMEOUT + HANG
    finally:
        for s in socks:
            s.close()
    health_is_served(gw)


# --------------------------------------------------------------------------------- bodies
def put_head(path: str, length: int) -> bytes:
    return (f"PUT {path} HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            f"Content-Length: {length}\r\n\r\n").encode()


def test_a_body_sent_in_pieces_within_the_timeout_is_published(gw, sink):
    body = json.dumps({"type": "std_msgs/msg/String", "data": {"data": "slow but in time"}}).encode()
    with connect(gw) as s:
        s.sendall(put_head(sink, len(body)))
        for i in range(0, len(body), 20):
            s.sendall(body[i:i + 20])
            time.sleep(0.05)
        s.settimeout(HANG)
        status, answer = read_response(s)
    assert status == 200, answer
    assert json.loads(answer)["x-medkit"]["status"] == "published"


def test_put_bodies_that_never_arrive_or_trickle_get_408_and_are_closed(gw, sink):
    """20+ PUTs whose body never comes (or trickles in slower than the timeout allows)."""
    body = json.dumps({"type": "std_msgs/msg/String", "data": {"data": "x" * 400}}).encode()
    silent = [connect(gw) for _ in range(STALLED)]
    trickling = [connect(gw) for _ in range(4)]
    started = time.monotonic()
    try:
        for s in silent:
            s.sendall(put_head(sink, len(body)) + body[:10])  # the rest never comes
        for s in trickling:
            s.sendall(put_head(sink, len(body)))
        # 20 bytes every 0.2 s: ~4 s for the body, past the 2 s body timeout, never idle for long.
        trickler = threading.Thread(target=send_slowly, args=(trickling, body, 20, 0.2), daemon=True)
        trickler.start()
        health_is_served(gw)  # while every body is awaited
        for s in silent + trickling:
            s.settimeout(BODY_TIMEOUT + HANG)
            status, headers, answer = read_response_with_head(s)
            assert status == 408, answer
            doc = json.loads(answer)
            assert doc["error_code"] == "invalid-request"
            assert "body_timeout" in doc["parameters"]["details"]
            assert headers.get("connection", "").lower() == "close"
            assert closed_by_server(s, HANG), "the connection was kept after a 408"
        assert time.monotonic() - started < BODY_TIMEOUT + HANG
        trickler.join(HANG)
    finally:
        for s in silent + trickling:
            s.close()
    health_is_served(gw)


def test_a_body_the_app_does_not_read_is_drained_or_the_connection_dropped(gw):
    """A PUT refused before its body is read: answered at once, then dropped if the body never comes."""
    with connect(gw) as s:
        s.sendall(put_head("/api/v1/health", 1000))  # 405: the app never reads the body
        s.settimeout(HANG)
        assert read_response(s)[0] == 405
        assert closed_by_server(s, BODY_TIMEOUT + HANG), "a connection waited for an unread body forever"
    with connect(gw) as s:  # the body does come: the connection is reused
        s.sendall(put_head("/api/v1/health", 1000) + b" " * 1000 + HEALTH + b"\r\n")
        s.settimeout(HANG)
        answers = Responses(s)
        assert answers.next()[0] == 405
        assert answers.next()[0] == 200


def test_a_kept_alive_connection_may_idle_for_keepalive_not_header_timeout(tmp_path):
    """Between requests the bound is gunicorn's keepalive (nginx reuses such connections), then it is dropped.

    gunicorn alone with the gateway's config and a short keepalive (3 s) next to a 1 s header timeout.
    """
    port = free_port()
    env = {"SOVD_BIND": f"127.0.0.1:{port}", "SOVD_RUNTIME_DIR": str(tmp_path), "SOVD_WORKERS": "1",
           "SOVD_HEADER_TIMEOUT": "1", "SOVD_LOG_LEVEL": "warning"}
    gunicorn = Proc([sys.executable, "-m", "gunicorn", "-c", "python:app.gunicorn_conf", "--keep-alive", "3",
                     "app.wsgi:create_app()"], env=env, name="gunicorn")
    version = b"GET /api/v1/version-info HTTP/1.1\r\nHost: x\r\n\r\n"
    try:
        poll_until(lambda: requests.get(f"http://127.0.0.1:{port}/api/v1/version-info", timeout=2).ok, 30,
                   message="gunicorn up")
        with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
            s.settimeout(HANG)
            s.sendall(version)
            assert read_response(s)[0] == 200
            # Idle past the header timeout: not dropped (a server closing early would show here) ...
            assert not closed_by_server(s, 1.5)
            s.sendall(version)
            s.settimeout(HANG)
            assert read_response(s)[0] == 200
            # ... but dropped once the keepalive has passed.
            assert closed_by_server(s, 3 + HANG)
    finally:
        gunicorn.stop()


# --------------------------------------------------------------------------------- stopping
def stream_until_closed(url: str, frames: list[str], timeout: float) -> None:
    with requests.get(url, stream=True, timeout=timeout) as r:
        assert r.status_code == 200
        for line in r.iter_lines():
            if line.startswith(b"event: "):
                frames.append(line[7:].decode())


def test_a_stream_ends_with_a_last_frame_when_its_worker_is_told_to_stop():
    """SIGTERM to one HTTP worker: its stream says so and ends; the master starts a new worker."""
    gw = Gateway("--workers", "1", "--debug-commands", "--shutdown-grace", "60", "--log-level", "warning")
    try:
        frames: list[str] = []
        reader = threading.Thread(target=stream_until_closed,
                                  args=(gw.api + "/x-sovd-debug/stream?interval=0.05", frames, 30))
        reader.start()
        poll_until(lambda: frames.count("tick") >= 3, 10, message="the stream is flowing")
        [worker] = gw.http_workers()
        worker.send_signal(signal.SIGTERM)
        reader.join(15)  # far below the 60 s grace that a stream ignoring the stop would hold
        assert not reader.is_alive(), "the stream did not end when its worker began to stop"
        assert frames[-1] == "stopping" and frames.count("stopping") == 1, frames[-5:]
        poll_until(lambda: [p.pid for p in gw.http_workers()] not in ([], [worker.pid]), 30,
                   message="a new HTTP worker")
        poll_until(lambda: gw.get("/health").status_code == 200, 30, message="health after the restart")
    finally:
        gw.stop()


def test_max_requests_ends_streams_as_a_stop_does(tmp_path):
    """gunicorn's max_requests (reached by other requests) is a graceful stop: the stream ends too.

    gunicorn alone with the gateway's config (no ROS worker is needed for these routes).
    """
    port = free_port()
    env = {"SOVD_BIND": f"127.0.0.1:{port}", "SOVD_RUNTIME_DIR": str(tmp_path), "SOVD_WORKERS": "1",
           "SOVD_DEBUG_COMMANDS": "1", "SOVD_SHUTDOWN_GRACE": "60", "SOVD_LOG_LEVEL": "info"}
    gunicorn = Proc([sys.executable, "-m", "gunicorn", "-c", "python:app.gunicorn_conf", "--max-requests", "5",
                     "app.wsgi:create_app()"], env=env, name="gunicorn")
    base = f"http://127.0.0.1:{port}/api/v1"
    try:
        poll_until(lambda: requests.get(base + "/x-sovd-debug/worker", timeout=2).ok, 30, message="gunicorn up")
        first = requests.get(base + "/x-sovd-debug/worker", timeout=5).json()["pid"]  # requests 1 and 2
        frames: list[str] = []
        reader = threading.Thread(target=stream_until_closed,
                                  args=(base + "/x-sovd-debug/stream?interval=0.05", frames, 30))
        reader.start()  # request 3
        poll_until(lambda: frames.count("tick") >= 2, 30, message="the stream is flowing")
        for _ in range(2):  # requests 4 and 5: the worker is done after this one
            assert requests.get(base + "/version-info", timeout=5).ok
        reader.join(15)  # far below the 60 s grace
        assert not reader.is_alive(), "the stream did not end when max_requests was reached"
        assert frames[-1] == "stopping", frames[-5:]
        poll_until(lambda: requests.get(base + "/x-sovd-debug/worker", timeout=2).json()["pid"] != first, 30,
                   message="a new worker after max_requests")
    finally:
        gunicorn.stop()


def test_sigterm_to_the_gateway_ends_streams_and_idle_connections_without_waiting_for_the_grace():
    gw = Gateway("--workers", "2", "--debug-commands", "--shutdown-grace", "60", "--log-level", "warning")
    idle: list[socket.socket] = []
    try:
        streams = [[] for _ in range(4)]
        readers = [threading.Thread(target=stream_until_closed,
                                    args=(gw.api + "/x-sovd-debug/stream?interval=0.05", f, 30))
                   for f in streams]
        for t in readers:
            t.start()
        poll_until(lambda: all(f.count("tick") >= 2 for f in streams), 30, message="every stream flowing")
        idle = [connect(gw) for _ in range(20)]             # connected, nothing sent
        for s in idle[:5]:                                  # kept alive after one request
            s.sendall(HEALTH + b"\r\n")
            assert read_response(s)[0] == 200
        for s in idle[5:10]:                                # half a head
            s.sendall(HEALTH)
        gw.signal(signal.SIGTERM)
        # Everything ends at once: a hang catcher far below the 60 s that a stream or a
        # connection still waiting for a request would hold.
        assert gw.proc.wait(timeout=20) == 0, "\n".join(gw.output[-30:])
        for t in readers:
            t.join(5)
        assert not any(t.is_alive() for t in readers)
        assert all(f[-1] == "stopping" for f in streams), [f[-3:] for f in streams]
    finally:
        for s in idle:
            s.close()
        gw.stop()


def test_http_workers_are_green_and_nothing_else_loads_gevent():
    """gevent patches the HTTP workers only: the supervisor and the ROS worker never even load it."""
    gw = Gateway("--workers", "2", "--debug-commands", "--log-level", "warning")
    try:
        seen: dict[int, bool] = {}

        def both_answered() -> bool:
            answer = gw.get("/x-sovd-debug/worker").json()  # a new connection each time
            seen[answer["pid"]] = answer["green"]
            return len(seen) == 2

        poll_until(both_answered, 20, interval=0.01, message="both HTTP workers answered")
        assert all(seen.values()), seen
        for proc in (psutil.Process(gw.pid), gw.rosworker()):
            with open(f"/proc/{proc.pid}/maps") as fh:  # every shared object the process has loaded
                maps = fh.read()
            assert "/site-packages/gevent/" not in maps and "/site-packages/greenlet/" not in maps, \
                proc.cmdline()
    finally:
        gw.stop()
