"""Blocking work (SQLite) off an HTTP worker's event loop.

An HTTP worker serves every connection on one gevent loop: a call that blocks the thread (a
SQLite commit waits for the disk) would stall them all.  :func:`run` hands such a call to gevent's
thread pool and lets the calling greenlet wait for it; :func:`every` runs a function in the
background at an interval (a greenlet that hands each call to the pool).  Outside gevent (the
Flask test client, a tool) the call runs inline and the background loop is a daemon thread.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any, TypeVar

from ipc.client import green

T = TypeVar("T")
log = logging.getLogger("sovd.http.blocking")


def run(fn: Callable[..., T], *args: Any) -> T:
    """``fn(*args)`` on a thread of its own; only the calling greenlet waits for it."""
    if green():
        import gevent

        return gevent.get_hub().threadpool.apply(fn, args)
    return fn(*args)


def every(seconds: float, fn: Callable[[], Any], name: str) -> Callable[[], None]:
    """Call ``fn`` every ``seconds`` (its errors logged, never raised) until the function returned is
    called (or for the life of the process)."""
    stopped = False

    def once() -> None:
        try:
            run(fn)
        except Exception:
            log.exception("%s failed", name)

    if green():
        import gevent

        def loop() -> None:
            while not stopped:
                gevent.sleep(seconds)
                if not stopped:
                    once()

        gevent.spawn(loop)

        def stop_green() -> None:
            nonlocal stopped
            stopped = True

        return stop_green
    event = threading.Event()

    def thread_loop() -> None:
        while not event.wait(seconds):
            once()

    threading.Thread(target=thread_loop, name=name, daemon=True).start()
    return event.set
