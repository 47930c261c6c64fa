"""app/gunicorn_worker.py through a real gateway: request heads are read without a thread.

One HTTP worker with two threads, so that two stalled clients would be
enough to starve it if a head were read on a pool thread.
"""

from __future__ import annotations

import socket
import time

import pytest

from tests.support.gateway import Gateway

HEADER_TIMEOUT = 2.0
HEALTH = b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\n"


@pytest.fixture(scope="module")
def gw():
    gateway = Gateway("--workers", "1", "--threads", "2", "--header-timeout", str(HEADER_TIMEOUT),
                      "--log-level", "warning")
    yield gateway
    gateway.stop()


def connect(gw) -> socket.socket:
    return socket.create_connection(("127.0.0.1", gw.port), timeout=10)


def read_response(sock: socket.socket) -> tuple[int, bytes]:
    """One HTTP/1.1 response with a Content-Length: (status, body)."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(65536)
        assert chunk, f"connection closed before a response head: {data!r}"
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    length = next(int(v) for k, _, v in (line.partition(":") for line in lines[1:])
                  if k.strip().lower() == "content-length")
    while len(body) < length:
        chunk = sock.recv(65536)
        assert chunk, "connection closed inside a response body"
        body += chunk
    return int(lines[0].split()[1]), body[:length]


def health_is_served(gw) -> None:
    with connect(gw) as s:
        s.settimeout(5)  # a hang catcher: a starved worker would not answer at all
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
    stalled = [connect(gw) for _ in range(6)]  # three times the worker's threads
    try:
        for s in stalled:
            s.sendall(HEALTH)  # the blank line never comes
        health_is_served(gw)
        for s in stalled:
            assert closed_by_server(s, HEADER_TIMEOUT + 5), "a stalled head was kept past the header timeout"
    finally:
        for s in stalled:
            s.close()
    health_is_served(gw)


def test_idle_connections_hold_no_thread_and_are_dropped_after_the_header_timeout(gw):
    idle = [connect(gw) for _ in range(20)]
    try:
        health_is_served(gw)
        assert all(closed_by_server(s, HEADER_TIMEOUT + 5) for s in idle)
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
        conns[0].settimeout(5)
        assert read_response(conns[0])[0] == 200
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
