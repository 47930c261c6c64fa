"""The one checker of what a command's ``args`` hold (ROS thread).

The HTTP side has checked what a client sent; these guard the wire (a probe, a
client of another version, a hostile process with the socket): nothing a
command receives may raise anything but :class:`IpcError`, and every refusal is
``bad-request`` with a text that names the field and what it takes.

    name = args.string(task.args, "entity_id", limit=256)
    node = args.node(task.args)                    # "/namespace/name"
    seconds = args.number(task.args, "seconds", 1.0, 0, 600)
"""

from __future__ import annotations

from typing import Any

from ipc.errors import IpcError
from ipc.protocol import BYTES_MODES
from ipc.topics import InvalidTopic, normalize_topic

MAX_NODE = 1024  # characters of a fully qualified node name


def _bad(text: str) -> IpcError:
    return IpcError("bad-request", text)


def string(args: dict, name: str, choices: tuple[str, ...] | None = None, limit: int = 4096) -> str:
    """A string of 1 to ``limit`` characters (one of ``choices``, when given)."""
    value = args.get(name)
    if not isinstance(value, str) or not value or len(value) > limit or (choices and value not in choices):
        raise _bad(f"{name}: expected " + (f"one of {', '.join(choices)}" if choices
                                           else f"a string of 1 to {limit} characters"))
    return value


def optional(args: dict, name: str, check, *a: Any, **kw: Any) -> Any:
    """``check(args, name, ...)`` when ``name`` is there and not None, else None."""
    return None if args.get(name) is None else check(args, name, *a, **kw)


def number(args: dict, name: str, default: float, low: float, high: float) -> float:
    """A number from ``low`` to ``high`` (``default`` when absent)."""
    value = args.get(name, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (low <= value <= high):
        raise _bad(f"{name}: expected a number from {low:g} to {high:g}")
    return float(value)


def integer(args: dict, name: str, low: int, high: int, text: str | None = None) -> int:
    """An integer from ``low`` to ``high`` (``text``: what the refusal says it expects)."""
    value = args.get(name)
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise _bad(f"{name}: expected " + (text or f"an integer from {low} to {high}"))
    return value


def flag(args: dict, name: str, default: bool = False) -> bool:
    value = args.get(name, default)
    if not isinstance(value, bool):
        raise _bad(f"{name}: expected a boolean")
    return value


def strings(args: dict, name: str, limit: int, text: str, item_limit: int | None = None) -> list[str]:
    """A list of at most ``limit`` strings (each 1 to ``item_limit`` characters when given)."""
    value = args.get(name)
    if not isinstance(value, list) or len(value) > limit or not all(
            isinstance(s, str) and (item_limit is None or 0 < len(s) <= item_limit) for s in value):
        raise _bad(f"{name}: expected {text}")
    return value


def bytes_mode(args: dict, name: str = "bytes", default: str | None = None) -> str:
    """``array`` or ``base64``: how byte arrays are written."""
    value = args.get(name, default)
    if value not in BYTES_MODES:
        raise _bad(f"{name}: expected 'array' or 'base64'")
    return value


def topic(args: dict, name: str = "topic") -> str:
    """A topic name by rmw's rules, normalized (``invalid-topic`` otherwise)."""
    try:
        return normalize_topic(args.get(name))
    except InvalidTopic as exc:
        raise IpcError("invalid-topic", str(exc), {"topic": str(args.get(name))[:300]}) from None


def is_node(value: Any) -> bool:
    return isinstance(value, str) and value.startswith("/") and not value.endswith("/") and len(value) <= MAX_NODE


def node(args: dict, name: str = "node") -> str:
    """A fully qualified node name (``/namespace/name``)."""
    value = args.get(name)
    if not is_node(value):
        raise _bad(f"{name}: expected a fully qualified node name (/namespace/name)")
    return value
