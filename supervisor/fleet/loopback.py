"""The robot's link reaches its own gateway over the loopback, as any HTTP client does.

So everything the gateway checks applies to a request that came through the fleet: its identity
(the caller's ``Authorization`` header goes along, and :data:`~supervisor.fleet.wire.MARK` makes the
gateway ask for it even on a read, ``app/fleet/robotside.py``), its switches, its limits, its access
log.  One keep-alive connection per thread of the link's pool; a request gets the caller's
remaining budget as its timeout, and an answer larger than :data:`~supervisor.fleet.wire.MAX_BODY`
is refused rather than carried.
"""

from __future__ import annotations

import http.client
import socket
import threading

from ipc import fleet as wire

ANSWER_HEADERS = tuple(h.lower() for h in wire.REPLY_HEADERS)


class TooLarge(Exception):
    pass


def _host_port(bind: str) -> tuple[str, int]:
    host, _, port = bind.rpartition(":")
    host = host.strip("[]")
    if host in ("", "0.0.0.0"):
        host = "127.0.0.1"
    elif host == "::":
        host = "::1"
    return host, int(port)


class Loopback:
    def __init__(self, bind: str):
        self.host, self.port = _host_port(bind)
        self._local = threading.local()

    def _connection(self, timeout: float) -> http.client.HTTPConnection:
        conn = getattr(self._local, "conn", None)
        if conn is None:
            conn = self._local.conn = http.client.HTTPConnection(self.host, self.port, timeout=timeout)
        conn.timeout = timeout
        if conn.sock is not None:
            conn.sock.settimeout(timeout)
        return conn

    def _drop(self) -> None:
        conn = getattr(self._local, "conn", None)
        if conn is not None:
            conn.close()
        self._local.conn = None

    def request(self, method: str, path: str, query: str, headers: dict[str, str], body: bytes,
                timeout: float) -> tuple[int, dict[str, str], bytes]:
        """One request to the gateway; raises OSError (no answer, timeout) or :class:`TooLarge`."""
        target = path + ("?" + query if query else "")
        sent = {**headers, wire.MARK: "1", "Connection": "keep-alive"}
        for attempt in (0, 1):
            conn = self._connection(max(0.05, timeout))
            try:
                conn.request(method, target, body=body or None, headers=sent)
                response = conn.getresponse()
                length = response.getheader("Content-Length")
                if length is not None and length.isdigit() and int(length) > wire.MAX_BODY:
                    self._drop()
                    raise TooLarge(int(length))
                data = response.read(wire.MAX_BODY + 1)
                if len(data) > wire.MAX_BODY:
                    self._drop()
                    raise TooLarge(len(data))
                if response.will_close:
                    self._drop()
                answer = {k: v for k, v in response.getheaders() if k.lower() in ANSWER_HEADERS}
                return response.status, {_canonical(k): v for k, v in answer.items()}, data
            except (http.client.RemoteDisconnected, ConnectionResetError, BrokenPipeError):
                # A kept-alive connection the gateway closed meanwhile: once more on a new one,
                # for a read only (a write may have been done).
                self._drop()
                if attempt or wire.is_write(method):
                    raise
            except (OSError, http.client.HTTPException) as exc:
                self._drop()
                if isinstance(exc, OSError):
                    raise
                raise OSError(str(exc)) from None
        raise OSError("unreachable")  # pragma: no cover - the loop returns or raises


def _canonical(name: str) -> str:
    for known in wire.REPLY_HEADERS:
        if known.lower() == name.lower():
            return known
    return name


def port_open(bind: str, timeout: float = 0.5) -> bool:
    host, port = _host_port(bind)
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False
