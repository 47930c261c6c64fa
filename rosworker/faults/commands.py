"""The faults' commands: ``fault_list``, ``fault_get``, ``fault_clear``, ``fault_events`` (``ipc/PROTOCOL.md``).

The HTTP side has checked what a client sent (medkit's rules); these guard the
wire (``core/args.py``).
"""

from __future__ import annotations

from collections.abc import Callable

from ipc.errors import IpcError

from ..core import args
from .manager import FaultManager
from .model import CODE_MAX, STATUSES


def _codes(a: dict) -> list[str]:
    return args.strings(a, "codes", 100_000, f"a list of fault codes of 1 to {CODE_MAX} characters", CODE_MAX)


def handlers(manager: FaultManager) -> dict[str, Callable]:
    """``fault_list``, ``fault_get``, ``fault_clear`` and ``fault_events``: name -> handler(task)."""
    def fault_list(task) -> None:
        statuses = task.args.get("statuses")
        if not isinstance(statuses, list) or not all(s in STATUSES for s in statuses):
            raise IpcError("bad-request", "statuses: expected a list of " + ", ".join(STATUSES))
        task.reply({"items": manager.listing(statuses)})

    def fault_get(task) -> None:
        task.reply(manager.get(_codes({"codes": [task.args.get("code")]})[0]))

    def fault_clear(task) -> None:
        task.reply({"cleared": manager.clear(_codes(task.args))})

    def fault_events(task) -> None:
        after = args.integer(task.args, "after", 0, 2**63, "an event id (a non-negative integer)") \
            if "after" in task.args else 0
        task.reply({"events": manager.events_after(after), "next_id": manager.next_event_id})

    return {"fault_list": fault_list, "fault_get": fault_get, "fault_clear": fault_clear,
            "fault_events": fault_events}
