"""What a restarted ROS worker needs from its predecessor, kept in the runtime dir.

``<runtime_dir>/restart-state.json`` holds one list per *part*: the core's
``nodes`` (the graph's nodes: the new worker answers nobody until discovery has
found them again, or a deadline passes), and what the families add with
:meth:`RestartState.part` (the data family's pooled ``topics``, subscribed again
as their publishers are discovered; the cyclic ``subscriptions``, whose streams
go on after the restart).  Written atomically, only when it changed; a worker
killed outright leaves the last copy behind.  Only a restarted worker reads it:
the first boot of a gateway removes it (:meth:`RestartState.discard`), so a new
gateway starts empty.

Threads: the ROS thread calls :meth:`RestartState.save` (every ``STATE_SAVE_EVERY``,
``core/family.py``, and after each change of a part that its owner wants on disk
before it answers); that compares each part's version (or value) with the last
one handed over and, when one changed, hands the lists to the writer thread
(``core/writer.py``: the latest wins), which serialises and writes them.  A part
of records (``records=True``) is a list of JSON texts its owner made once per
change of each item, so the ROS thread's cost of a change does not grow with the
part.  ``save``'s ``then`` (a command's reply) runs on the ROS thread once a
state at least as new is written.  Before :meth:`start` and after
:meth:`close`, ``save`` writes on the caller's thread.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from typing import Any

from common.process import remove, write_atomic

from .writer import LatestWriter

log = logging.getLogger("sovd.rosworker.state")

FILE_NAME = "restart-state.json"
MAX_ITEMS = 8192


class _Part:
    __slots__ = ("name", "value", "records", "version")

    def __init__(self, name: str, value: Callable[[], list], records: bool, version: Callable[[], Any] | None):
        self.name, self.value, self.records, self.version = name, value, records, version

    def seen(self) -> Any:
        return self.version() if self.version is not None else tuple(self.value())


class RestartState:
    def __init__(self, runtime_dir: str, post: Callable[[Callable[[], None]], None] | None = None):
        self.path = os.path.join(runtime_dir, FILE_NAME)
        self._parts: list[_Part] = []
        self._submitted: tuple | None = None   # what the last save saw of each part
        self._written_text: bytes | None = None
        self._loaded: dict[str, list] = {}
        self._writer = LatestWriter("restart-state-writer", self._write_batch, post=post)

    def part(self, name: str, value: Callable[[], list], *, records: bool = False,
             version: Callable[[], Any] | None = None) -> None:
        """One more list in the file: ``value()`` gives it (strings; with ``records``, JSON texts of objects,
        asked for only when ``version()`` changed).  Before the loop runs (a family's start)."""
        self._parts.append(_Part(name, value, records, version))

    # ---- the ROS thread -----------------------------------------------------------------------------
    def start(self) -> None:
        self._writer.start()

    def save(self, then: Callable[[], None] | None = None) -> None:
        """Hand the parts to the writer if one changed; ``then`` once a state at least as new is written."""
        seen = tuple(p.seen() for p in self._parts)
        if seen == self._submitted:
            if then is not None:
                self._writer.after(then)
            return
        self._submitted = seen
        self._writer.submit("state", [(p.name, p.records, p.value()) for p in self._parts], then)

    def close(self, timeout: float) -> None:
        """Write what is pending and stop the writer, within ``timeout`` s; later saves write at once."""
        self._writer.close(timeout)

    # ---- the writer thread ------------------------------------------------------------------------------
    def _write_batch(self, batch: dict[str, list]) -> None:
        parts = batch["state"]
        text = b"{" + b",".join(
            json.dumps(name).encode() + b":" + (b"[" + b",".join(value) + b"]" if records
                                                 else json.dumps(value).encode())
            for name, records, value in parts) + b"}"
        if text == self._written_text:
            return
        try:
            # Private like everything in the runtime dir (the topic and node names of the
            # robot are nobody else's business).
            write_atomic(self.path, text)
            self._written_text = text
        except OSError as exc:
            log.warning("could not save the restart state to %s: %s", self.path, exc)

    # ---- boot ----------------------------------------------------------------------------------------
    def discard(self) -> None:
        """Remove the previous run's state (the first boot of a gateway: nothing died)."""
        for path in (self.path, self.path + ".tmp"):
            remove(path, log, "could not remove the previous run's state")

    def load(self) -> None:
        """Read what the previous worker saved (nothing when there is none, or it is damaged)."""
        self._loaded = {}
        try:
            with open(self.path) as fh:
                data = json.load(fh)
        except (OSError, ValueError):
            return
        if isinstance(data, dict):
            self._loaded = data

    def loaded(self, name: str, records: bool = False) -> list:
        """The part ``name`` as the previous worker saved it: strings (objects with ``records``), the newest
        ``MAX_ITEMS``; empty when there is none."""
        items = self._loaded.get(name)
        kind = dict if records else str
        return [x for x in items if isinstance(x, kind)][-MAX_ITEMS:] if isinstance(items, list) else []
