"""The HTTP worker process: gunicorn's gevent worker, with a deadline on every read from a client.

gunicorn's master forks each HTTP worker and calls ``init_process`` in the
child.  That is where, and the only place where, gevent patches the process
(:meth:`GeventWorker.patch`, first thing after the fork, before the Flask
app is loaded).  The master itself, the supervisor and the ROS worker are
never patched: they load this module (gunicorn resolves ``worker_class`` in
the master) but only import gevent.

One worker serves every connection on one event loop: each connection is a
greenlet from a pool of ``worker_connections`` (a stalled or idle client
costs a few KiB, not a thread), and a request waiting on the ROS worker
waits for its socket on the event loop (``ipc/client.py``,
``ipc/greenwaits.py``).  Every read from a client has a deadline:

- the **request head** (request line and headers, whatever their size):
  ``header_timeout`` seconds from the accept, or, on a kept-alive
  connection, from the first byte of the next request.  Past it the
  connection is closed without an answer (a client that has not sent a
  whole head cannot be answered meaningfully; nginx does the same);
- the **request body**: ``body_timeout`` seconds from the end of the head for
  the whole body, however it trickles.  Past it the application's read
  raises :class:`BodyTimeout` (Werkzeug's ``RequestTimeout``): the client gets
  the contract's JSON ``408`` and the connection is closed.  A body the
  application did not read is drained under the same deadline before the
  connection is reused, or the connection is closed;
- **between requests** a kept-alive connection may stay idle ``keepalive``
  seconds (``gunicorn_conf.py``: longer than nginx's upstream keep-alive).

Stopping.  When gunicorn begins a graceful stop of this worker (SIGTERM from
the master or the operator, ``max_requests`` reached, SIGQUIT/SIGINT),
``alive`` turns false.  Then, on the event loop: :func:`stopping` is set (a
long-lived response such as an event stream waits on it, sends a last frame
and ends instead of holding the graceful timeout); connections that are idle
or still sending a head are closed at once; the listeners stop accepting;
requests in progress get gunicorn's ``graceful_timeout`` (``shutdown_grace``)
to finish, and are killed after it.
"""

from __future__ import annotations

import resource
import threading
import time
from functools import partial

import gevent
from gevent.pool import Pool
from gevent.server import StreamServer
from gevent.socket import wait_read
from gunicorn.sock import ssl_context
from gunicorn.workers.ggevent import GeventWorker
from werkzeug.exceptions import RequestTimeout

from common import settings
from common.process import PerProcess

HEARTBEAT_S = 1.0        # how often the worker tells the master it is alive (gunicorn's own rate)
DRAIN_CHUNK = 64 * 1024  # reads of a body the application left unread
FD_MARGIN = 256          # descriptors beside the client connections (ZeroMQ, logs, files)

# threading.Event looked up when made: gevent's once the worker is patched.
_stop_event: PerProcess[threading.Event] = PerProcess(lambda: threading.Event())


def stopping() -> threading.Event:
    """The event set when this HTTP worker begins to stop; wait on it to end a long response.

    One per process, made on first use in the process that uses it.  In a
    gevent worker it is gevent's event (``threading`` is patched there), so
    ``stopping().wait(timeout)`` suspends only the calling greenlet; in a
    process without gevent (a Flask test client) it is a plain
    ``threading.Event`` that nothing sets.
    """
    return _stop_event.get()


class BodyTimeout(RequestTimeout):
    """The request body did not arrive within ``body_timeout``: a JSON 408 (``app/core/errors.py``)."""


class HttpWorker(GeventWorker):
    _alive = True
    _loop = None  # the event loop, once this worker runs

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # Constructed in the master before the fork: nothing here touches gevent or the process.
        cfg = settings.load(None)  # the supervisor hands every setting over as SOVD_* variables
        self.head_timeout = cfg.header_timeout
        self.body_timeout = cfg.body_timeout
        self._waiting: dict = {}  # greenlet -> the gevent.Timeout of its wait for the client
        self._stop_begun = False

    # ---- lifecycle ------------------------------------------------------------------------
    @property
    def alive(self) -> bool:
        return self._alive

    @alive.setter
    def alive(self, value: bool) -> None:
        # gunicorn turns this false from signal handlers, request greenlets and its run loop;
        # the stop itself runs as a callback on the event loop.
        self._alive = value
        if not value and self._loop is not None:
            self._loop.run_callback_threadsafe(self._begin_stop)

    def init_process(self):
        _raise_fd_limit(self.worker_connections + FD_MARGIN, self.log)
        super().init_process()  # patches, reinitialises the hub, loads the app, calls run()

    def run(self):
        self._loop = gevent.get_hub().loop
        # bulk-data downloads: zero-copy, never blocking the loop (app/core/sendfile.py)
        from .core import sendfile

        sendfile.install()
        stop = stopping()
        servers = []
        # TLS (tls_cert, tls_key): gunicorn's context (app/gunicorn_conf.py's ssl_context), as its own
        # gevent worker passes it; each connection's handshake runs on that connection's greenlet.
        tls = {"ssl_context": ssl_context(self.cfg)} if self.cfg.is_ssl else {}
        for sock in self.sockets:
            sock.setblocking(1)
            server = StreamServer(sock, handle=partial(self.handle, sock),
                                  spawn=Pool(self.worker_connections), **tls)
            if self.cfg.workers > 1:
                server.max_accept = 1  # as gunicorn's gevent worker: spread accepts over the workers
            server.start()
            servers.append(server)

        while self.alive:
            self.notify()
            stop.wait(HEARTBEAT_S)
        self._begin_stop()

        for server in servers:
            server.close()  # stop accepting
        deadline = time.monotonic() + self.cfg.graceful_timeout
        for server in servers:
            while server.pool.free_count() != server.pool.size:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    self.log.warning("Worker graceful timeout (pid:%s)", self.pid)
                    server.stop(timeout=1)
                    break
                self.notify()
                server.pool.join(timeout=min(HEARTBEAT_S, remaining))

    def _begin_stop(self) -> None:
        """On the event loop: tell long responses, close connections that wait for a request."""
        if self._stop_begun:
            return
        self._stop_begun = True
        stopping().set()
        for glet, timeout in list(self._waiting.items()):
            self._loop.run_callback(self._expire, glet, timeout)

    def _expire(self, glet, timeout) -> None:
        # A hub callback: every greenlet still listed is suspended in its wait for the client.
        if self._waiting.get(glet) is timeout:
            glet.throw(timeout)

    # ---- waits for the client -------------------------------------------------------------
    def timeout_ctx(self):
        """Around each request head (gunicorn's keep-alive loop): ``header_timeout``."""
        if not self.alive:
            raise StopIteration("worker stopping")  # gunicorn closes the connection quietly
        return _ClientWait(self, self.head_timeout)

    def handle_request(self, listener_name, req, sock, addr):
        if _has_body(req):
            req.body.reader = _DeadlineReader(req.body.reader, self.body_timeout, req)
        handled = super().handle_request(listener_name, req, sock, addr)
        # Kept alive: the rest of the body, then the next request's first byte.
        if not (self._drain_body(req) and self._next_request_arrives(sock, req)):
            raise StopIteration("closing")
        return handled

    def _drain_body(self, req) -> bool:
        try:
            while req.body.read(DRAIN_CHUNK):
                pass
        except Exception as exc:  # the deadline, or a body that breaks its own framing
            self.log.debug("Closing connection: request body not drained (%s)", type(exc).__name__)
            return False
        return True

    def _next_request_arrives(self, sock, req) -> bool:
        if not self.alive:
            return False
        if _buffered(req.unreader):
            return True  # pipelined: part of the next request is already here
        arrived = False
        with _ClientWait(self, self.cfg.keepalive):
            wait_read(sock.fileno())
            arrived = True
        return arrived


class _ClientWait:
    """A wait for bytes from a client that ends quietly at its deadline, or when the worker stops.

    A ``gevent.Timeout(seconds, False)``: when it fires, the ``with`` block is
    left without an exception.  While the block runs the greenlet is listed in
    ``worker._waiting``, so that a stopping worker can fire it early.
    """

    __slots__ = ("worker", "timeout", "glet")

    def __init__(self, worker: HttpWorker, seconds: float):
        self.worker = worker
        self.timeout = gevent.Timeout(seconds, False)
        self.glet = None

    def __enter__(self):
        self.glet = gevent.getcurrent()
        self.worker._waiting[self.glet] = self.timeout
        self.timeout.start()
        return self

    def __exit__(self, typ, value, tb):
        self.worker._waiting.pop(self.glet, None)
        return self.timeout.__exit__(typ, value, tb)


class _DeadlineReader:
    """gunicorn's body reader (length or chunked) with one deadline for the whole body."""

    __slots__ = ("reader", "deadline", "seconds", "req")

    def __init__(self, reader, seconds: float, req):
        self.reader = reader
        self.seconds = seconds
        self.deadline = time.monotonic() + seconds
        self.req = req

    def read(self, size):
        remaining = self.deadline - time.monotonic()
        if remaining <= 0:
            raise self._expired()
        timer = gevent.Timeout(remaining)
        timer.start()
        try:
            return self.reader.read(size)
        except gevent.Timeout as exc:
            if exc is not timer:
                raise
            raise self._expired() from None
        finally:
            timer.close()

    def _expired(self) -> BodyTimeout:
        self.req.must_close = True  # where the next request would start is unknown
        return BodyTimeout(f"The request body did not arrive within {self.seconds:g} s "
                           "(body_timeout); send it in one go, or raise the gateway's body_timeout")


def _has_body(req) -> bool:
    length = getattr(req.body.reader, "length", None)
    return length is None or length > 0  # chunked, or a Content-Length above 0


def _buffered(unreader) -> bool:
    buf = unreader.buf
    buf.seek(0, 2)
    return buf.tell() > 0


def _raise_fd_limit(wanted: int, log) -> None:
    """Let this worker hold ``worker_connections`` connections: raise the soft descriptor limit."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY or soft >= wanted:
        return
    target = wanted if hard == resource.RLIM_INFINITY else min(wanted, hard)
    if target > soft:
        resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
    if target < wanted:
        log.warning("open-file limit %d is below worker_connections + %d = %d: raise LimitNOFILE",
                    target, FD_MARGIN, wanted)
