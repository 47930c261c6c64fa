"""What a restarted ROS worker needs from its predecessor, kept in the runtime dir.

``<runtime_dir>/restart-state.json``: the pooled topics (subscribed again as their
publishers are discovered), the nodes of the graph (the new worker does
not answer anyone until discovery has found them again, or a deadline
passes) and the cyclic subscriptions (their streams go on after the restart).
Written atomically, only when it changed; a worker killed outright leaves the
last copy behind.  Only a restarted worker reads it: the first boot of a
gateway removes it (``rosworker/main.py``), so a new gateway starts empty.

Threads: the ROS thread calls :meth:`RestartState.submit` (after each change
of the subscriptions, and every ``STATE_SAVE_EVERY`` for the pool); that only
puts the state in one slot (the latest wins: states submitted while a write
runs are coalesced into the next one) and wakes the writer thread, which
serialises and writes it.  The subscriptions arrive as their JSON records,
made once per change of each (``rosworker/subscriptions/registry.py``), so the ROS thread's
cost of a change does not grow with the registry.  ``submit``'s ``then``
(a command's reply) is handed back to the ROS thread through ``post`` once a
state at least as new is written.  Before :meth:`start` and after
:meth:`close`, ``submit`` writes on the caller's thread.
"""

from __future__ import annotations

import json
import logging
import os
import threading
from collections.abc import Callable

from common.process import write_atomic

log = logging.getLogger("sovd.rosworker.state")

FILE_NAME = "restart-state.json"
MAX_ITEMS = 8192


class RestartState:
    def __init__(self, runtime_dir: str, post: Callable[[Callable[[], None]], None] | None = None):
        self.path = os.path.join(runtime_dir, FILE_NAME)
        self._post = post or (lambda fn: fn())
        self._written_text: bytes | None = None
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._submitted: tuple | None = None     # what the last submit saw (topics, nodes, version)
        self._seq = 0                           # bumped by each submit that changed something
        self._written = 0                       # the newest seq written (or failed to be)
        self._pending: tuple | None = None      # (seq, topics, nodes, records): the one slot
        self._waiting: list[tuple[int, Callable[[], None]]] = []
        self._thread: threading.Thread | None = None
        self._closing = False
        self._io = threading.Lock()             # one write at a time (close() may time out on one)

    # ---- ROS thread -----------------------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="restart-state-writer", daemon=True)
        self._thread.start()

    def submit(self, topics: list[str], nodes: list[str], version: int, records: Callable[[], list[bytes]],
               then: Callable[[], None] | None = None) -> None:
        """Hand the state over (``records`` is called only when ``version`` changed); ``then`` once written."""
        seen = (tuple(topics), tuple(nodes), version)
        with self._lock:
            if seen != self._submitted:
                self._submitted = seen
                self._seq += 1
                self._pending = (self._seq, topics, nodes, records())
                self._wake.notify()
            threaded = self._thread is not None and not self._closing
            if then is not None and threaded and self._written < self._seq:
                self._waiting.append((self._seq, then))
                then = None
        if not threaded:
            self._write_pending()
        if then is not None:
            then()

    def close(self, timeout: float) -> None:
        """Write what is pending and stop the writer, within ``timeout`` s; later submits write at once."""
        with self._lock:
            self._closing = True
            self._wake.notify()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                log.warning("the restart state's writer did not finish within %g s", timeout)

    # ---- the writer thread -----------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._lock:
                while self._pending is None and not self._closing:
                    self._wake.wait()
                if self._pending is None:
                    return
            self._write_pending()

    def _write_pending(self) -> None:
        with self._lock:
            job, self._pending = self._pending, None
        if job is not None:
            seq, topics, nodes, records = job
            with self._io:
                self._write(topics, nodes, records)
            with self._lock:
                self._written = max(self._written, seq)
                ready = [fn for s, fn in self._waiting if s <= self._written]
                self._waiting = [(s, fn) for s, fn in self._waiting if s > self._written]
            for fn in ready:
                self._post(fn)

    def _write(self, topics: list[str], nodes: list[str], records: list[bytes]) -> None:
        text = b"".join((b'{"topics":', json.dumps(topics).encode(), b',"nodes":', json.dumps(nodes).encode(),
                         b',"subscriptions":[', b",".join(records), b"]}"))
        if text == self._written_text:
            return
        try:
            # Private like everything in the runtime dir (the topic and node names of the
            # robot are nobody else's business).
            write_atomic(self.path, text)
            self._written_text = text
        except OSError as exc:
            log.warning("could not save the restart state to %s: %s", self.path, exc)

    # ---- boot ----------------------------------------------------------------------------------
    def discard(self) -> None:
        """Remove the previous run's state (the first boot of a gateway: nothing died)."""
        for path in (self.path, self.path + ".tmp"):
            try:
                os.unlink(path)
            except FileNotFoundError:
                pass
            except OSError as exc:
                log.warning("could not remove the previous run's state %s: %s", path, exc)

    def load(self) -> tuple[list[str], list[str], list[dict]]:
        """``(topics, nodes, subscriptions)`` saved by the previous worker; empty when there is none."""
        try:
            with open(self.path) as fh:
                data = json.load(fh)
        except (OSError, ValueError):
            return [], [], []
        if not isinstance(data, dict):
            return [], [], []

        def strings(key: str) -> list[str]:
            items = data.get(key)
            return [x for x in items if isinstance(x, str)][-MAX_ITEMS:] if isinstance(items, list) else []

        subs = data.get("subscriptions")
        subs = [s for s in subs if isinstance(s, dict)][-MAX_ITEMS:] if isinstance(subs, list) else []
        return strings("topics"), strings("nodes"), subs
