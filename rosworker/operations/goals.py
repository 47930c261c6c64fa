"""The running goals' restart record: ``operations.json`` in the runtime dir.

The running goals (id, action, type, entity) are written by the latest-state
writer (``core/writer.py``: never on the ROS thread) whenever a goal starts or
finishes; a goal's 202 is answered once its record is on disk, so a ROS worker
killed right after still knows it.  A restarted worker reads it
(:func:`load_restart`): those goals are kept as failed, ``ros2_status:
"unknown"``, with a message (rclpy cannot re-attach to a goal it did not send,
so they cannot be cancelled).
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable

from common.process import write_atomic

from ..core.writer import LatestWriter
from .actions import Goal

log = logging.getLogger("sovd.rosworker.operations")

STATE_FILE = "operations.json"
MAX_GOALS = 4096
RESTART_MESSAGE = ("The ROS worker restarted while this goal was running; the gateway cannot follow it "
                   "any more (rclpy cannot re-attach to a goal it did not send). The goal may still be "
                   "running on the action server, which was not asked to cancel it.")


class GoalRecord:
    """Writes the running goals (and those already lost) to ``operations.json``, the latest wins."""

    def __init__(self, runtime_dir: str, post: Callable[[Callable[[], None]], None]):
        self.path = os.path.join(runtime_dir, STATE_FILE)
        self._writer = LatestWriter("operations-state", self._write, post=post)
        self._writer.start()

    def save(self, goals: list[Goal], then: Callable[[], None] | None = None) -> None:
        # Running goals, and those already known as lost (a previous restart): both read
        # "unknown" after the next one.
        records = [{"id": g.id, "action": g.path, "type": g.type_name, "entity_id": g.entity_id,
                    "created": g.created, "message": g.message if g.done else None}
                   for g in goals if not g.done or g.ros2_status == "unknown"]
        self._writer.submit("goals", json.dumps(records), then)

    def _write(self, batch: dict[str, str]) -> None:
        try:
            write_atomic(self.path, batch["goals"].encode())  # 0600, as every file of the runtime dir
        except OSError as exc:
            log.warning("could not write %s: %s", self.path, exc)

    def close(self, wait: float) -> None:
        self._writer.close(wait)


def load_restart(runtime_dir: str) -> list[Goal]:
    """The goals a previous ROS worker had running, as failed ``unknown`` goals."""
    path = os.path.join(runtime_dir, STATE_FILE)
    try:
        with open(path) as fh:
            records = json.load(fh)
    except FileNotFoundError:
        return []
    except (OSError, ValueError) as exc:
        log.warning("ignoring %s: %s", path, exc)
        return []
    goals = []
    for record in records if isinstance(records, list) else []:
        try:
            goal = Goal(bytes.fromhex(record["id"]), str(record["action"]), str(record["type"]),
                        str(record.get("entity_id", "")))
            goal.created = float(record.get("created", time.time()))
        except (KeyError, TypeError, ValueError):
            continue
        message = record.get("message")
        goal.finish("unknown", message if isinstance(message, str) and message else RESTART_MESSAGE)
        goals.append(goal)
    return goals[:MAX_GOALS]
