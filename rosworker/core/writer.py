"""One thread that writes the latest state of something, off the ROS thread.

The ROS thread hands its state over with :meth:`LatestWriter.submit` and never
waits on a disk: the item goes into a dict keyed by what it is (a fault code, a
trigger id, the whole restart state), so a key submitted again before it was
written is written once, with its newest value, and what waits is bounded by
the number of keys.  The writer thread takes everything pending as one batch
and hands it to ``write(batch)`` (a dict: key -> value).

``then`` (a command's reply, a goal's 202) runs on the ROS thread (through
``post``) once what was submitted with it, and everything submitted before, is
written: a change a client was told about is on disk, and survives a ROS worker
killed right after.  :meth:`LatestWriter.after` is the same for a caller that
changed nothing itself.

A write that raises is counted (``errors``, ``last_error``) and handed to
``on_error``.  With ``retry_after`` its items go back (a newer value of a key
wins), and so do their ``then``; the writer tries again after that many seconds
(``keep`` may bound what waits meanwhile).  Without it they are dropped and their
``then`` runs.

Before :meth:`start` and after :meth:`close`, ``submit`` writes on the caller's
thread at once (and ``then`` runs there).  Its users: the restart state
(``core/state.py``), the store's faults, fault events and triggers
(``core/store.py``) and the operations' running goals (``operations/goals.py``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

log = logging.getLogger("sovd.rosworker.writer")


class LatestWriter:
    def __init__(self, name: str, write: Callable[[dict[Any, Any]], None], *,
                 post: Callable[[Callable[[], None]], None] | None = None, retry_after: float | None = None,
                 on_error: Callable[[Exception], None] | None = None,
                 keep: Callable[[dict[Any, Any]], None] | None = None):
        self.name = name
        self._write = write
        self._post = post or (lambda fn: fn())
        self.retry_after = retry_after
        self._on_error = on_error or (lambda exc: log.warning("%s: a write failed: %s", name, exc))
        self._keep = keep or (lambda pending: None)
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._pending: dict[Any, Any] = {}
        self._seq = 0          # bumped by each submit
        self._written = 0      # every submit up to this one is written (or was dropped)
        self._waiting: list[tuple[int, Callable[[], None]]] = []
        self._thread: threading.Thread | None = None
        self._closing = False
        self._busy = False
        self._io = threading.Lock()  # one write at a time (close() may give up on a slow one)
        self.writes = 0        # batches written
        self.errors = 0        # batches that failed
        self.last_error = ""

    # ---- the ROS thread ----------------------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()

    @property
    def threaded(self) -> bool:
        return self._thread is not None and not self._closing

    @property
    def pending(self) -> int:
        """Items waiting to be written, and the batch being written (read by /health)."""
        return len(self._pending) + (1 if self._busy else 0)

    def submit(self, key: Any, value: Any, then: Callable[[], None] | None = None) -> None:
        """Write ``value`` as ``key`` soon (the latest value wins); ``then`` once it is written."""
        with self._lock:
            self._seq += 1
            self._pending[key] = value
            self._keep(self._pending)
            threaded = self.threaded
            if then is not None and threaded:
                self._waiting.append((self._seq, then))
                then = None
            self._wake.notify()
        if not threaded:
            self._write_pending()
        if then is not None:
            then()

    def after(self, then: Callable[[], None]) -> None:
        """``then`` once everything submitted so far is written (at once when it is)."""
        with self._lock:
            if self._written < self._seq and self.threaded:
                self._waiting.append((self._seq, then))
                return
        then()

    def close(self, timeout: float) -> bool:
        """Write what is pending and stop the thread, within ``timeout`` s (False: it did not finish);
        later submits write on the caller's thread."""
        with self._lock:
            self._closing = True
            self._wake.notify()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                log.warning("%s: the last writes did not finish within %g s", self.name, timeout)
                return False
        self._write_pending()  # never started, or the thread gave up on a failure: written here
        return True

    # ---- the writer thread ---------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._lock:
                while not self._pending and not self._closing:
                    self._wake.wait()
                if not self._pending:
                    return
            if not self._write_pending(posted=True) and self.retry_after is not None:
                if self._closing:
                    return
                time.sleep(self.retry_after)

    def _write_pending(self, posted: bool = False) -> bool:
        """Write what is pending (on this thread); True unless the write failed."""
        with self._lock:
            batch, self._pending = self._pending, {}
            seq = self._seq
            self._busy = bool(batch)
        ok = True
        if batch:
            try:
                with self._io:
                    self._write(batch)
                self.writes += 1
            except Exception as exc:  # noqa: BLE001 - a disk, a database: counted and handed on
                ok = False
                self.errors += 1
                self.last_error = f"{type(exc).__name__}: {exc}"[:300]
                self._on_error(exc)
        with self._lock:
            self._busy = False
            if ok or self.retry_after is None:
                self._written = max(self._written, seq)
            else:
                for key, value in batch.items():
                    self._pending.setdefault(key, value)  # a newer value of a key wins
                self._keep(self._pending)
            ready = [fn for s, fn in self._waiting if s <= self._written]
            self._waiting = [(s, fn) for s, fn in self._waiting if s > self._written]
        for fn in ready:
            self._post(fn) if posted else fn()
        return ok


def once_written(executor: Any, then: Callable[[], None], wait: float, late: str = "") -> Callable[[], None]:
    """``then`` (a command's reply) to run once: when the returned function is called (the change it
    answers is written: ``submit``'s ``then``), or after ``wait`` s (a slow disk: the change holds in
    memory; ``late`` is logged then).  ROS thread."""
    done = False

    def once() -> None:
        nonlocal done
        if not done:
            done = True
            timer.cancel()
            then()

    def too_late() -> None:
        if late:
            log.warning("%s was not written within %g s; answering anyway", late, wait)
        once()

    timer = executor.call_later(wait, too_late)
    return once
