"""Freeze frames: what a fault's confirmation keeps of the robot's state (medkit's snapshots).

At confirmation a fault keeps the failing status's key/value pairs, and the
newest message of each topic that ``fault_snapshot_topics`` names for its code
(``CODE_PATTERN=/topic,/topic2;OTHER*=/t3``), read through the core's samplers
(``core/samplers.py``: the data family's topics, never waiting).  The topics are
pooled (``warm``) when the fault turns PREFAILED, so that they have a message by
then.  ``SNAPSHOTS_MAX`` frames of at most ``SNAPSHOT_BYTES`` each per fault.
"""

from __future__ import annotations

import fnmatch
import json
import logging
from typing import Any

from ipc.errors import IpcError

from .model import SNAPSHOTS_MAX, TOPIC, parse_snapshot_topics

log = logging.getLogger("sovd.rosworker.faults")

SNAPSHOT_BYTES = 64 * 1024


class FreezeFrames:
    def __init__(self, samplers: Any, snapshot_topics: str):
        self.samplers = samplers
        self.snapshot_topics = parse_snapshot_topics(snapshot_topics)

    def topics_for(self, code: str) -> list[str]:
        out: list[str] = []
        for pattern, topics in self.snapshot_topics:
            if fnmatch.fnmatchcase(code, pattern):
                out.extend(t for t in topics if t not in out)
        return out[:SNAPSHOTS_MAX - 1]

    def warm(self, code: str) -> None:
        """Pool the code's snapshot topics now, so that they have a message at confirmation."""
        for topic in self.topics_for(code):
            try:
                self.samplers.warm("data", topic)
            except IpcError as exc:
                log.debug("snapshot topic %s: %s", topic, exc.message)

    def take(self, record: dict[str, Any], values: dict[str, Any] | None, wall: int,
             stale: bool) -> list[dict[str, Any]]:
        """The freeze frames of ``record`` at its confirmation: the failing status's ``values`` (not for a
        stale one: it has none of its own), then the newest message of each of its code's topics."""
        code = record["code"]
        frames = []
        if values is not None and not stale:
            frames.append(_frame(record["name"], TOPIC, "diagnostic_msgs/msg/DiagnosticStatus",
                                      json.dumps(values, separators=(",", ":")), wall))
        for topic in self.topics_for(code):
            try:
                result = self.samplers.read("data", topic, "array")
            except IpcError as exc:
                frames.append({**_frame(topic, topic, "", "{}", wall), "error": exc.message[:300]})
                continue
            if result is None or result.get("status") != "data":
                continue
            text = bytes(result["data_json"])
            frames.append(_frame(topic, topic, result.get("type") or "", text.decode("utf-8", "replace"),
                                      wall))
        return frames[:SNAPSHOTS_MAX]



def _frame(name: str, topic: str, message_type: str, data: str, wall: int) -> dict[str, Any]:
    frame: dict[str, Any] = {"type": "freeze_frame", "name": name, "topic": topic,
                             "message_type": message_type, "captured_at_ns": wall}
    if len(data) > SNAPSHOT_BYTES:
        frame.update(data="{}", truncated=len(data))
    else:
        frame["data"] = data
    return frame
