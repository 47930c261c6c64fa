"""Zero-copy file responses on the HTTP workers' event loop: ``sendfile(2)`` that never blocks it.

gunicorn sends a response made of ``wsgi.file_wrapper`` (a bulk-data download,
``download.py``) with ``socket.sendfile``.  gevent's socket implements that by reading the
file into Python 8 KiB at a time and sending each piece (``os.sendfile`` would block a
blocking socket and so the whole worker).  :func:`cooperative_sendfile` replaces it in
the HTTP workers (``install``, called by ``app/http_worker.py`` once gevent has patched
the process): the kernel copies from the page cache straight to the non-blocking socket;
when the socket's buffer is full the greenlet waits for it to drain on the event loop,
and it yields after every ``SLICE`` bytes sent, so a 500 MB download neither passes
through Python nor holds up the other connections of its worker.

Anything ``os.sendfile`` refuses (a file that is not a regular file, a socket type it
does not take) falls back to gevent's own way.  Standard library and gevent only.
"""

from __future__ import annotations

import errno
import os

SLICE = 4 << 20  # bytes sent before the greenlet lets the others run


def cooperative_sendfile(self, file, offset: int = 0, count: int | None = None) -> int:
    """``socket.sendfile`` for a gevent socket: ``os.sendfile`` in non-blocking slices."""
    from gevent import sleep
    from gevent.socket import wait_write

    try:
        in_fd = file.fileno()
        size = os.fstat(in_fd).st_size
    except (AttributeError, OSError, ValueError):
        return self._sendfile_use_send(file, offset, count)
    end = size if not count else min(size, offset + count)
    out_fd = self.fileno()
    timeout = self.gettimeout()
    position, since_yield = offset, 0
    try:
        while position < end:
            try:
                sent = os.sendfile(out_fd, in_fd, position, min(end - position, SLICE))
            except BlockingIOError:
                wait_write(out_fd, timeout=timeout)
                continue
            except OSError as exc:
                if exc.errno in (errno.EINVAL, errno.ENOSYS) and position == offset:
                    return self._sendfile_use_send(file, offset, count)  # not a file sendfile takes
                raise
            if sent == 0:
                break  # the file got shorter under us
            position += sent
            since_yield += sent
            if since_yield >= SLICE:
                since_yield = 0
                sleep(0)
        return position - offset
    finally:
        if position > offset:
            file.seek(position)


def install() -> None:
    """Use :func:`cooperative_sendfile` for gevent's sockets (an HTTP worker, after gevent's patch)."""
    from gevent import socket as gsocket

    gsocket.socket.sendfile = cooperative_sendfile
