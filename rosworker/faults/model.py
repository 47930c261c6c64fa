"""A fault as the faults family keeps and shows it: statuses, codes, medkit's ``fault_to_json``.

Plain functions and constants (no rclpy): the manager (``manager.py``), the
freeze frames (``snapshots.py``) and the commands (``commands.py``) share them.
"""

from __future__ import annotations

import re
from typing import Any

TOPIC = "/diagnostics"
TYPE = "diagnostic_msgs/msg/DiagnosticArray"
CODE_MAX = 256
SNAPSHOTS_MAX = 8          # freeze frames per fault
PREFAILED, CONFIRMED, PREPASSED, HEALED, CLEARED = "PREFAILED", "CONFIRMED", "PREPASSED", "HEALED", "CLEARED"
STATUSES = (PREFAILED, CONFIRMED, PREPASSED, HEALED, CLEARED)
ACTIVE = (PREFAILED, CONFIRMED, PREPASSED)
LABELS = {0: "INFO", 1: "WARN", 2: "ERROR", 3: "CRITICAL"}
_NOT_ALNUM = re.compile(r"[^A-Za-z0-9]+")


def fault_code(name: str) -> str:
    """medkit's generated code: upper case, each run of non-alphanumerics one ``_``, none at the ends."""
    return _NOT_ALNUM.sub("_", name).strip("_").upper()[:CODE_MAX]


def parse_codes(text: str) -> dict[str, str]:
    """``fault_codes``: ``status name=CODE;other name=CODE2`` -> {name: code}."""
    out = {}
    for item in (text or "").split(";"):
        name, sep, code = item.rpartition("=")
        if sep and name.strip() and fault_code(code):
            out[name.strip()] = fault_code(code)
    return out


def parse_snapshot_topics(text: str) -> list[tuple[str, list[str]]]:
    """``fault_snapshot_topics``: ``CODE_PATTERN=/topic,/topic2;OTHER*=/t3`` -> [(pattern, topics)]."""
    out = []
    for item in (text or "").split(";"):
        pattern, sep, topics = item.partition("=")
        names = [t.strip() for t in topics.split(",") if t.strip()]
        if sep and pattern.strip() and names:
            out.append((pattern.strip(), names[:SNAPSHOTS_MAX]))
    return out


def public(record: dict[str, Any]) -> dict[str, Any]:
    """A fault as medkit lists it (``fault_to_json``): times in seconds, ``last_passed`` once passed."""
    out: dict[str, Any] = {
        "fault_code": record["code"], "severity": record["severity"], "description": record["description"],
        "first_occurred": record["first_ns"] / 1e9, "last_occurred": record["last_ns"] / 1e9,
    }
    if record.get("passed_ns"):
        out["last_passed"] = record["passed_ns"] / 1e9
    out.update(occurrence_count=record["count"], status=record["status"],
               reporting_sources=list(record["sources"]), severity_label=LABELS.get(record["severity"], "UNKNOWN"))
    return out


def level(value: Any) -> int:
    if isinstance(value, (bytes, bytearray)):
        return value[0] if value else 0
    return int(value)
