"""gunicorn's gthread worker, with request heads read on the event loop instead of a thread.

The stock gthread worker hands every new connection to a pool thread at
once; the thread waits up to 5 s for a first byte and then reads the request
head with a blocking socket and no timeout.  So ``workers × threads``
connections that send nothing (a port scan, browser preconnects) or half a
head and then nothing (slowloris) hold every thread, and every other client
waits.  nginx in front prevents that, but the gateway must not depend on it.

:class:`HeadBufferingWorker` changes only where the head is read: a new
connection, and a kept-alive one that becomes readable, stay on the worker's
selector (no thread) while bytes come in; each readable event does one
non-blocking ``recv``.  Only once the head is complete (``\\r\\n\\r\\n``), or
larger than ``HEAD_HANDOFF_BYTES`` (the parser then answers the limit errors),
does the connection go to a pool thread, with the bytes already read pushed
back into gunicorn's parser.  A head that is not complete within the
``header_timeout`` setting (seconds from accept, or from a kept-alive
connection's next byte) is dropped.  Everything else (parsing, the WSGI
call, keep-alive, graceful shutdown) is gunicorn's.

With TLS or HTTP/2 cleartext configured (the gateway uses neither) the stock
behaviour is kept.  The worker uses gthread internals (``TConn``, the
selector, ``enqueue_req``, ``pending_conns``), so ``pyproject.toml`` pins
gunicorn's major version; ``tests/test_gunicorn_worker.py`` and
``tests/reliability/test_hostile_http.py`` check the behaviour through a real
gunicorn.
"""

from __future__ import annotations

import errno
import selectors
import time
from collections import deque
from functools import partial

from gunicorn.workers import gthread

from app import config as settings

HEAD_HANDOFF_BYTES = 64 * 1024  # hand a head this large to the parser, which enforces the limits
RECV_CHUNK = 16 * 1024
HEAD_END = b"\r\n\r\n"


class HeadBufferingWorker(gthread.ThreadWorker):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.reading_heads: deque[gthread.TConn] = deque()  # ordered by deadline
        # The supervisor hands every setting to gunicorn's processes as SOVD_* variables.
        self.head_timeout = settings.load(None).header_timeout
        self._buffering = not (self.cfg.is_ssl or getattr(self.cfg, "http2_cleartext", None)
                               in ("prior-knowledge", "upgrade", "both"))

    # ---- on the event loop (main thread) -------------------------------------------------
    def accept(self, listener):
        if not self._buffering:
            return super().accept(listener)
        try:
            client_sock, client_addr = listener.accept()
        except OSError as exc:
            if exc.errno not in (errno.EAGAIN, errno.ECONNABORTED, errno.EWOULDBLOCK):
                raise
            return
        self.nr_conns += 1
        conn = gthread.TConn(self.cfg, client_sock, client_addr, listener.getsockname())  # non-blocking
        self._read_head(conn)

    def on_client_socket_readable(self, conn, client):
        if not self._buffering:
            return super().on_client_socket_readable(conn, client)
        self._resume(conn, client, self.keepalived_conns)

    def on_pending_socket_readable(self, conn, client):
        # Parked by handle() below: the rest of a pipelined head is still to come.
        if not self._buffering:
            return super().on_pending_socket_readable(conn, client)
        self._resume(conn, client, self.pending_conns)

    def _resume(self, conn, client, waiting: deque) -> None:
        self.poller.unregister(client)
        waiting.remove(conn)
        self._read_head(conn)

    def _read_head(self, conn) -> None:
        # Bytes gunicorn's parser already holds (the start of a pipelined request) come first.
        held = conn.parser.unreader.take_buffered() if conn.parser is not None else b""
        conn.head = bytearray(held)
        conn.head_deadline = time.monotonic() + self.head_timeout
        conn.sock.setblocking(False)
        if _head_complete(conn.head):
            self._hand_over(conn)
            return
        self.reading_heads.append(conn)
        self.poller.register(conn.sock, selectors.EVENT_READ, partial(self._on_head_bytes, conn))

    def _on_head_bytes(self, conn, client) -> None:
        try:
            data = conn.sock.recv(RECV_CHUNK)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:  # the client went away before sending a whole head
            self._drop_head(conn)
            return
        conn.head += data
        if not _head_complete(conn.head):
            return
        self.poller.unregister(conn.sock)
        self.reading_heads.remove(conn)
        self._hand_over(conn)

    def _hand_over(self, conn) -> None:
        conn.prebuffered = bytes(conn.head)
        conn.head = None
        conn.data_ready = True
        self.enqueue_req(conn)

    def _drop_head(self, conn) -> None:
        """Close a connection whose head is still being read (it is registered and listed)."""
        self.poller.unregister(conn.sock)
        self.reading_heads.remove(conn)
        self.nr_conns -= 1
        conn.close()

    def murder_pending(self):
        super().murder_pending()
        now = time.monotonic()
        while self.reading_heads and self.reading_heads[0].head_deadline <= now:
            self._drop_head(self.reading_heads[0])

    def murder_keepalived(self, force=False):
        super().murder_keepalived(force)
        if force:  # the worker is stopping: heads still being read will not be served
            while self.reading_heads:
                self._drop_head(self.reading_heads[0])

    # ---- in a pool thread ----------------------------------------------------------------
    def handle(self, conn):
        prebuffered = getattr(conn, "prebuffered", None)
        if prebuffered is not None:
            conn.prebuffered = None
            try:
                conn.sock.setblocking(True)
                conn.init()
            except Exception as exc:  # as in gunicorn's handle(): log it, close the connection
                self.handle_error(None, conn.sock, conn.client, exc)
                return False
            conn.parser.unreader.unread(prebuffered)
        elif self._buffering and conn.initialized:
            # A kept-alive connection whose next (pipelined) request is only partly here:
            # back to the event loop rather than a blocking read on this thread.
            if not _head_complete(conn.parser.unreader.buf.getvalue()):
                return gthread._DEFER if self.alive else False
        return super().handle(conn)


def _head_complete(data) -> bool:
    """A whole request head is here, or so much that the parser must judge it (limits)."""
    return HEAD_END in data or len(data) >= HEAD_HANDOFF_BYTES
