"""A small Server-Sent Events client for tests: one raw socket, chunked decoding, deadlines.

    with EventStream(port, "/api/v1/apps/x/cyclic-subscriptions/sub_.../events") as s:
        assert s.status == 200
        event = s.next(timeout=2)      # {"timestamp", "payload"} or {"timestamp", "error"}; None at the end
        s.comments                     # ":" lines seen (keep-alives)
        s.fields[i]                    # the other lines of event i: {"id": ..., "event": ...}
        s.blocks[i]                    # event i's bytes as they came (without the blank line)

Frames are parsed as they arrive, so a test can tell a stream that is sent
event by event from one buffered until it ends.  ``recv_buffer`` shrinks the
socket's receive buffer for slow-reader tests.
"""

from __future__ import annotations

import json
import socket
import sys
import time
from collections.abc import Iterator
from typing import Any


class StreamEnded(Exception):
    pass


class EventStream:
    def __init__(self, port: int, path: str, host: str = "127.0.0.1", timeout: float = 10.0,
                 recv_buffer: int | None = None, headers: dict[str, str] | None = None):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        if recv_buffer:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, recv_buffer)
        self.sock.settimeout(timeout)
        self.sock.connect((host, port))
        extra = "".join(f"{k}: {v}\r\n" for k, v in (headers or {}).items())
        self.sock.sendall(f"GET {path} HTTP/1.1\r\nHost: {host}\r\nAccept: text/event-stream\r\n{extra}\r\n"
                          .encode())
        self._raw = b""        # bytes off the socket not yet de-chunked
        self._text = b""       # de-chunked body not yet split into events
        self._chunked = False
        self._done = False     # the body ended (last chunk, or the connection closed)
        self.comments: list[bytes] = []
        self.events: list[dict[str, Any]] = []   # every event parsed so far, in order
        self.fields: list[dict[str, str]] = []   # each event's "id:" and "event:" lines
        self.blocks: list[bytes] = []            # each event's lines as they came (without the blank line)
        self.arrivals: list[float] = []          # monotonic time each event was parsed
        self.status, self.headers, self.body = self._head(timeout)

    @property
    def local_port(self) -> int:
        return self.sock.getsockname()[1]

    def _fill(self, deadline: float) -> bool:
        """Read once more; False when the deadline passed, raises StreamEnded at EOF."""
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        self.sock.settimeout(left)
        try:
            data = self.sock.recv(65536)
        except TimeoutError:
            return False
        except OSError:
            data = b""
        if not data:
            raise StreamEnded()
        self._raw += data
        return True

    def _head(self, timeout: float):
        deadline = time.monotonic() + timeout
        while b"\r\n\r\n" not in self._raw:
            if not self._fill(deadline):
                raise AssertionError(f"no response head within {timeout} s: {self._raw[:200]!r}")
        head, _, self._raw = self._raw.partition(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        status = int(lines[0].split()[1])
        headers = {}
        for line in lines[1:]:
            k, _, v = line.partition(":")
            headers[k.strip().lower()] = v.strip()
        self._chunked = headers.get("transfer-encoding", "").lower() == "chunked"
        body = b""
        if "content-length" in headers:
            length = int(headers["content-length"])
            while len(self._raw) < length:
                if not self._fill(deadline):
                    break
            body, self._raw = self._raw[:length], self._raw[length:]
            self._done = True
        return status, headers, body

    def _dechunk(self) -> None:
        if not self._chunked:
            self._text += self._raw
            self._raw = b""
            return
        while True:
            size_line, sep, rest = self._raw.partition(b"\r\n")
            if not sep:
                return
            size = int(size_line.split(b";")[0], 16)
            if size == 0:
                self._done = True
                self._raw = b""
                return
            if len(rest) < size + 2:
                return
            self._text += rest[:size]
            self._raw = rest[size + 2:]

    def _parse(self) -> None:
        while b"\n\n" in self._text:
            block, _, self._text = self._text.partition(b"\n\n")
            data = []
            fields = {}
            for line in block.split(b"\n"):
                if line.startswith(b":"):
                    self.comments.append(line)
                elif line.startswith(b"data:"):
                    data.append(line[5:].lstrip(b" "))
                elif line.startswith((b"id:", b"event:")):
                    key, _, value = line.decode().partition(":")
                    fields[key] = value.strip()
            if data:
                self.events.append(json.loads(b"\n".join(data)))
                self.blocks.append(block)
                self.fields.append(fields)
                self.arrivals.append(time.monotonic())

    def next(self, timeout: float = 5.0, start: int | None = None) -> dict[str, Any] | None:
        """The next event not returned yet; None when the stream ended; AssertionError past ``timeout``."""
        index = self._returned if start is None else start
        deadline = time.monotonic() + timeout
        while len(self.events) <= index:
            self._dechunk()
            self._parse()
            if len(self.events) > index:
                break
            if self._done:
                return None
            try:
                if not self._fill(deadline):
                    raise AssertionError(f"no event within {timeout} s (have {len(self.events)})")
            except StreamEnded:
                self._done = True
                self._dechunk()
                self._parse()
                if len(self.events) <= index:
                    return None
        self._returned = index + 1
        return self.events[index]

    _returned = 0

    def take(self, count: int, timeout: float) -> list[dict[str, Any]]:
        """Up to ``count`` events, waiting at most ``timeout`` in all: fewer when they did not come (so an
        assertion on the list shows which ones are missing)."""
        until = time.monotonic() + timeout
        out = []
        while len(out) < count and (left := until - time.monotonic()) > 0:
            try:
                event = self.next(timeout=left)
            except AssertionError:
                break
            if event is None:
                break
            out.append(event)
        return out

    def collect(self, seconds: float) -> list[dict[str, Any]]:
        """Every event that arrives within ``seconds`` (the stream may end earlier)."""
        return self.take(sys.maxsize, seconds)

    def ended(self, timeout: float) -> bool:
        """Read until the stream ends (True) or ``timeout`` passes (False)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                if self.next(timeout=max(0.01, deadline - time.monotonic())) is None:
                    return True
            except AssertionError:
                return False
        return False

    def close(self) -> None:
        try:
            self.sock.close()
        except OSError:
            pass

    def __enter__(self) -> EventStream:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def sse_events(response) -> Iterator[dict[str, Any] | None]:
    """The events of a ``requests`` response streamed with ``stream=True`` (``/faults/stream``):
    ``{"id": int, "event", "data"}`` each as it comes, and None for a comment (a keep-alive: the reader
    can look at its clock)."""
    current: dict[str, Any] = {}
    for line in response.iter_lines():
        line = line.decode() if isinstance(line, bytes) else line
        if not line:
            yield current if "data" in current else None
            current = {}
        elif not line.startswith(":"):
            key, _, value = line.partition(":")
            value = value.strip()
            current[key] = json.loads(value) if key == "data" else int(value) if key == "id" else value

