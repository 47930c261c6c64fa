"""One open ``text/event-stream`` response, whatever it streams: a cyclic subscription, a trigger, the faults.

A stream is fed by its hub's reader greenlet (``hub.py``: one per HTTP worker
process and kind) and written to its client; all on gevent, no thread.

- **One buffer policy.**  At most ``max_frames`` frames and ``max_bytes`` bytes
  wait for a slow client (``STREAM_BUFFER_BYTES`` unless said); past either the
  oldest go first (the newest frame is always kept), each counted in
  ``frames_dropped``.  A frame pushed with a sequence number (``seq``: a trigger's
  events, the faults' event ids) not above the last one's is dropped: an event
  both replayed and received live is sent once.  While a stream opens
  (:meth:`Stream.hold`: its replay is being fetched), what is pushed is held, and
  pushed after the replay, in order (:meth:`Stream.release`).
- **One way to write.**  On gunicorn's gevent worker a stream writes its
  connection itself (``sock``; the response head goes through the server, as the
  body's first piece): a pushed frame is sent at once by whoever pushes it (one
  non-blocking send; a frame shared by every stream of a key, already framed as an
  HTTP chunk when the response is chunked), and what the kernel does not take is
  written by the stream's own greenlet.  Without ``sock`` (the Flask test client)
  frames are yielded to the server.  The connection's send buffer is
  ``STREAM_SNDBUF``.
- **One stall cut.**  A write that lasts ``send_timeout`` is cut by the hub's
  ticker (``sending_since``: a deadline stamp per write in progress, no timer per
  frame): the connection is shut down and the body ends in :class:`SendStalled`.
- **One way to notice a client that left.**  A failed write; and while a stream
  gets no frame, the hub's ticker looks at its connection (:func:`gone`) every
  ``GONE_CHECK`` seconds.
- A ``:`` keep-alive comment after ``KEEPALIVE`` seconds of silence; the stream
  ends at ``end()`` (once what is buffered is written), at its expiry, when its
  client leaves, and when the HTTP worker stops (the hub ends every stream).
- Its frames are counted in the hub's ``frames_sent`` and ``frames_dropped``,
  and open streams in ``open_streams`` (``/health``'s ``x-medkit-streams``,
  ``/metrics``), whatever the kind.
"""

from __future__ import annotations

import collections
import errno
import socket
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from typing import Any

import gevent.event

# ... and bytes: past this, older frames go too (the newest is always kept).  An image stream's
# frame is a megabyte or more; a slow client holds one of them here, not four.
STREAM_BUFFER_BYTES = 1 << 20
# SO_SNDBUF of a stream's connection (Linux doubles it for its bookkeeping).  Left to itself the
# kernel grows a send buffer to megabytes for a client that does not read: without this, one
# stalled reader of an image stream held 3 MB in the kernel, beside what the buffer holds.
# 128 KiB in flight still carries 100 MB/s at a LAN's 1 ms round trip.
STREAM_SNDBUF = 128 * 1024
KEEPALIVE = 15.0           # seconds of silence before a ":" comment line
GONE_CHECK = 1.0           # seconds of silence after which the ticker looks whether the client left


def rfc3339(ns: int) -> bytes:
    """``2026-02-14T10:30:00.250Z``: UTC, milliseconds."""
    return (datetime.fromtimestamp(ns / 1e9, UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z").encode()


def frame(stamp_ns: int, *, payload: bytes | None = None, error: bytes | None = None) -> bytes:
    """One SSE event of SOVD's: ``data: {"timestamp", "payload" | "error"}`` and a blank line."""
    field = b'"payload":' + payload if payload is not None else b'"error":' + error
    return b'data: {"timestamp":"' + rfc3339(stamp_ns) + b'",' + field + b"}\n\n"


def chunked(data: bytes) -> bytes:
    """``data`` as one HTTP/1.1 chunk (what the server would frame a yielded piece as)."""
    return b"%X\r\n" % len(data) + data + b"\r\n"


KEEPALIVE_FRAME = b": keep-alive\n\n"
KEEPALIVE_CHUNK = chunked(KEEPALIVE_FRAME)


class SendStalled(OSError):
    """A frame could not be written within the send timeout: the client is not reading."""

    def __init__(self, seconds: float):
        super().__init__(errno.EPIPE, f"the client took no frame for {seconds:g} s (stream_send_timeout)")


def gone(sock: Any) -> bool:
    """True when the client closed its connection (a peek at the real socket, never waiting)."""
    real = getattr(sock, "_sock", sock)
    if real is None:
        return False
    try:
        return real.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
    except (BlockingIOError, InterruptedError):
        return False
    except OSError:
        return True


class Stream:
    """One open event-stream response of a hub (``hub.py``).  A hub adds what it needs of the stream
    (the subscription or trigger it serves) as attributes."""

    def __init__(self, hub: Any, max_frames: int, sock: Any = None, framed: bool = False,
                 max_bytes: int = STREAM_BUFFER_BYTES, expires: float | None = None):
        self.hub = hub
        self.max_frames = max_frames
        self.max_bytes = max_bytes
        self.expires = expires     # monotonic; None: until it ends
        self.frames: collections.deque[bytes] = collections.deque()
        self.buffered = 0          # bytes in ``frames``
        self.wake = gevent.event.Event()
        self.ended = False
        self.opened = False        # the response head went out: frames may be sent on ``sock``
        self.last_frame = time.monotonic()
        self.last_seq = 0          # the sequence number of the newest frame pushed with one
        self.held: list[tuple[bytes, int | None]] | None = None  # pushed while opening (hold)
        self.ending = False        # end() came while holding: it ends once what was held is pushed
        self.sock = sock           # written directly (None: frames are yielded to the server)
        self.framed = framed       # direct and chunked: ``frames`` hold HTTP chunks
        self.partial = b""         # direct: the rest of a write the kernel did not take at once
        self.sending_since = 0.0   # direct: monotonic start of the write in progress (0: none)
        self.cut = False           # the ticker cut this stream's connection (a stalled reader)

    # ---- the hub's side (its reader greenlet, its ticker) ----------------------------------------
    def push(self, chunk: bytes, framed: bytes | None = None, now: float | None = None,
             seq: int | None = None) -> None:
        """Queue one frame (``framed``: the same frame as an HTTP chunk, if the caller has it;
        ``seq``: its sequence number, a frame not above the last one's is dropped)."""
        if self.ended:
            return
        if self.held is not None:
            self.held.append((chunk, seq))
            return
        if seq is not None:
            if seq <= self.last_seq:
                return
            self.last_seq = seq
        if self.framed:
            chunk = framed if framed is not None else chunked(chunk)
        self.frames.append(chunk)
        self.buffered += len(chunk)
        while len(self.frames) > self.max_frames or (self.buffered > self.max_bytes and len(self.frames) > 1):
            self.buffered -= len(self.frames.popleft())
            self.hub.counters["frames_dropped"] += 1
        self.last_frame = time.monotonic() if now is None else now
        if self.sock is not None and self.opened and not self.sending_since and not self.partial:
            self._send_now()
        else:
            self.wake.set()

    def hold(self) -> None:
        """From now on what is pushed waits (while the stream's replay is fetched)."""
        self.held = []

    def release(self) -> None:
        """Push what was held, in order (after the replay), and end the stream if it was told to."""
        held, self.held = self.held or [], None
        for chunk, seq in held:
            self.push(chunk, seq=seq)
        if self.ending:
            self.end()

    def end(self, last: bytes | None = None) -> None:
        """End the stream once what is buffered (and ``last``) is written."""
        if last is not None:
            self.push(last)
        if self.held is not None:
            self.ending = True
            return
        self.ended = True
        self.wake.set()

    # ---- writing --------------------------------------------------------------------------------
    def _take(self) -> bytes:
        """Everything queued, as one write (counted as sent here: metrics are flushed per tick)."""
        count = len(self.frames)
        data = self.frames.popleft() if count == 1 else b"".join(self.frames)
        self.frames.clear()
        self.buffered = 0
        self.hub.counters["frames_sent"] += count
        return data

    def _send_now(self) -> None:
        """One non-blocking send of what is queued (the reader's greenlet); the rest is the stream's."""
        data = self._take()
        try:
            sent = self.sock.send(data, 0, 0.0)
        except BlockingIOError:
            sent = 0
        except OSError:  # the client went away: the body ends, the server closes the connection
            self.ended = True
            self.wake.set()
            return
        if sent < len(data):
            self.partial = data[sent:]
            self.wake.set()

    def _write(self, data: bytes) -> None:
        """A blocking write on this stream's greenlet; the ticker cuts it after the send timeout."""
        hub = self.hub
        self.sending_since = time.monotonic()
        hub.sending.add(self)
        try:
            self.sock.sendall(data)
        except OSError:
            if self.cut:
                raise SendStalled(hub.send_timeout) from None
            raise
        finally:
            self.sending_since = 0.0
            hub.sending.discard(self)

    def body(self, opening: Callable[[Stream], None] | None = None, first: bytes = b"") -> Iterator[bytes]:
        """The response body: it opens the stream in its hub when it is first iterated, and its
        ``finally`` gives it back (client gone, expiry, end).

        ``opening(stream)`` runs once the stream is registered, before the response head goes
        (a trigger's or the faults' replay); ``first`` is the body's first piece, sent with the
        head.  A response whose body is never iterated (a HEAD) registers nothing, so no stream can
        be open without this ``finally`` to give it back.
        """
        hub = self.hub
        direct = self.sock is not None
        try:
            hub.register(self)
            if opening is not None:
                opening(self)
            yield first   # the server writes the response head now; the frames follow
            self.opened = True
            quiet_since = time.monotonic()
            while True:
                if self.partial or self.frames:
                    if direct:
                        data, self.partial = self.partial or self._take(), b""
                        self._write(data)
                    else:
                        yield self._take()
                    quiet_since = time.monotonic()
                    continue
                if self.ended:
                    return
                now = time.monotonic()
                if self.expires is not None and now >= self.expires:
                    return
                if now - quiet_since >= KEEPALIVE:
                    if direct:
                        self._write(KEEPALIVE_CHUNK if self.framed else KEEPALIVE_FRAME)
                    else:
                        yield KEEPALIVE_FRAME
                    quiet_since = now
                    continue
                self.wake.clear()
                if not self.frames and not self.partial and not self.ended:
                    left = KEEPALIVE - (now - quiet_since)
                    self.wake.wait(left if self.expires is None else min(self.expires - now, left))
        finally:
            hub.close(self)
