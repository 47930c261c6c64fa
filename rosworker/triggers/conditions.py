"""Trigger conditions (medkit's), evaluated on JSON values.

``OnChange`` fires on the first value and on every change; ``OnChangeTo`` when
the value becomes ``target_value`` (the first value only checks the target);
``EnterRange``/``LeaveRange`` on the crossing of the inclusive
``[lower_bound, upper_bound]`` (a previous value is needed).  Values are
compared as IEEE numbers: NaN is in no range, and two NaN are no change.
"""

from __future__ import annotations

import json
import math
from typing import Any

from ipc import jsonpointer
from ipc.errors import IpcError

CONDITIONS = ("OnChange", "OnChangeTo", "EnterRange", "LeaveRange")
TARGET_VALUE_MAX = 4096  # bytes of the JSON of an OnChangeTo target_value
_NON_FINITE = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}


def _number(value: Any) -> float | None:
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str):
        return _NON_FINITE.get(value)
    return None


def same(a: Any, b: Any) -> bool:
    """JSON equality with IEEE numbers: 1 == 1.0, NaN == NaN (no change), a boolean is no number."""
    if isinstance(a, bool) or isinstance(b, bool):
        return isinstance(a, bool) and isinstance(b, bool) and a == b
    na, nb = _number(a), _number(b)
    if na is not None and nb is not None and not (isinstance(a, str) and isinstance(b, str)):
        return na == nb or (na != na and nb != nb)
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same(v, b[k]) for k, v in a.items())
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


def in_range(value: Any, low: float, high: float) -> bool:
    number = _number(value)
    return number is not None and low <= number <= high  # NaN compares false: in no range


def fires(condition: dict[str, Any], previous: Any, current: Any) -> bool:
    """Whether ``condition`` fires on ``current`` after ``previous`` (MISSING: there was none)."""
    kind = condition["condition_type"]
    first = previous is jsonpointer.MISSING
    if kind == "OnChange":
        return first or not same(previous, current)
    if kind == "OnChangeTo":
        return same(current, condition["target_value"]) and (first or not same(previous, current))
    if first:
        return False
    low, high = condition["lower_bound"], condition["upper_bound"]
    was, now = in_range(previous, low, high), in_range(current, low, high)
    return (not was and now) if kind == "EnterRange" else (was and not now)


def check_condition(value: Any) -> dict[str, Any]:
    """The condition a client sent, as kept (only its own fields); IpcError("bad-request")."""
    if not isinstance(value, dict) or value.get("condition_type") not in CONDITIONS:
        raise IpcError("bad-request", "condition: expected an object whose condition_type is one of "
                       + ", ".join(CONDITIONS))
    kind = value["condition_type"]
    out: dict[str, Any] = {"condition_type": kind}
    if kind == "OnChangeTo":
        if "target_value" not in value:
            raise IpcError("bad-request", "condition: OnChangeTo needs target_value")
        try:
            size = len(json.dumps(value["target_value"], separators=(",", ":")).encode())
        except (TypeError, ValueError, RecursionError):
            raise IpcError("bad-request", "condition: target_value is not a JSON value") from None
        if size > TARGET_VALUE_MAX:
            raise IpcError("bad-request", f"condition: target_value too large ({size} bytes of JSON; "
                           f"at most {TARGET_VALUE_MAX})", {"max_bytes": TARGET_VALUE_MAX})
        out["target_value"] = value["target_value"]
    elif kind in ("EnterRange", "LeaveRange"):
        low, high = value.get("lower_bound"), value.get("upper_bound")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                   for v in (low, high)) or low > high:
            raise IpcError("bad-request", "condition: lower_bound and upper_bound must be finite numbers, "
                                          "lower_bound <= upper_bound")
        out["lower_bound"], out["upper_bound"] = low, high
    return out
