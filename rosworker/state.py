"""What a restarted ROS worker needs from its predecessor, kept in the runtime dir.

``<runtime_dir>/pool.json``: the pooled topics (subscribed again as their
publishers are discovered), the nodes of the graph (the new worker does
not answer anyone until discovery has found them again, or a deadline
passes) and the cyclic subscriptions (their streams go on after the restart).  Written atomically, at most once per ``STATE_SAVE_EVERY``, only when
it changed; a worker killed outright leaves the last copy behind.
"""

from __future__ import annotations

import json
import logging
import os

log = logging.getLogger("sovd.rosworker.state")

FILE_NAME = "pool.json"
MAX_ITEMS = 8192


class RestartState:
    def __init__(self, runtime_dir: str):
        self.path = os.path.join(runtime_dir, FILE_NAME)
        self._saved: tuple | None = None

    def save(self, topics: list[str], nodes: list[str], subscriptions: list[dict] | None = None) -> None:
        subscriptions = subscriptions or []
        current = (tuple(topics), tuple(nodes), json.dumps(subscriptions, sort_keys=True))
        if current == self._saved:
            return
        tmp = self.path + ".tmp"
        try:
            # Private like everything in the runtime dir, whatever the umask (the topic and
            # node names of the robot are nobody else's business).
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            os.fchmod(fd, 0o600)  # an older copy may have been made with other bits
            with os.fdopen(fd, "w") as fh:
                json.dump({"topics": topics, "nodes": nodes, "subscriptions": subscriptions}, fh)
            os.replace(tmp, self.path)
            self._saved = current
        except OSError as exc:
            log.warning("could not save the restart state to %s: %s", self.path, exc)

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
