"""ROS 2 parameter values <-> JSON, and what a node's refusal means (the configurations' values).

A value goes out as JSON with its real type (NaN and ±inf as proto3's strings
"NaN", "Infinity", "-Infinity"); a value a client sends is made a
``ParameterValue`` of the parameter's current type when it fits, else of the
type the JSON reads as (the node then decides, with its own reason).
"""

from __future__ import annotations

import math
from typing import Any

from rcl_interfaces.msg import ParameterType, ParameterValue

from ipc.errors import IpcError

T = ParameterType
TYPE_NAMES = {
    T.PARAMETER_BOOL: "bool", T.PARAMETER_INTEGER: "int", T.PARAMETER_DOUBLE: "double",
    T.PARAMETER_STRING: "string", T.PARAMETER_BYTE_ARRAY: "byte_array", T.PARAMETER_BOOL_ARRAY: "bool_array",
    T.PARAMETER_INTEGER_ARRAY: "int_array", T.PARAMETER_DOUBLE_ARRAY: "double_array",
    T.PARAMETER_STRING_ARRAY: "string_array", T.PARAMETER_NOT_SET: "not_set",
}
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1
_NON_FINITE = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}


def _double_out(x: float) -> float | str:
    """A double as JSON: NaN and ±inf as proto3's strings."""
    if math.isnan(x):
        return "NaN"
    if math.isinf(x):
        return "Infinity" if x > 0 else "-Infinity"
    return x


def value_json(v: ParameterValue) -> Any:
    t = v.type
    if t == T.PARAMETER_BOOL:
        return bool(v.bool_value)
    if t == T.PARAMETER_INTEGER:
        return int(v.integer_value)
    if t == T.PARAMETER_DOUBLE:
        return _double_out(float(v.double_value))
    if t == T.PARAMETER_STRING:
        return str(v.string_value)
    if t == T.PARAMETER_BYTE_ARRAY:
        return [b if isinstance(b, int) else b[0] for b in v.byte_array_value]
    if t == T.PARAMETER_BOOL_ARRAY:
        return [bool(b) for b in v.bool_array_value]
    if t == T.PARAMETER_INTEGER_ARRAY:
        return [int(i) for i in v.integer_array_value]
    if t == T.PARAMETER_DOUBLE_ARRAY:
        return [_double_out(float(d)) for d in v.double_array_value]
    if t == T.PARAMETER_STRING_ARRAY:
        return [str(s) for s in v.string_array_value]
    return None


def type_name(v: ParameterValue) -> str:
    return TYPE_NAMES.get(v.type, "not_set")


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and INT64_MIN <= x <= INT64_MAX


def _double_in(x: Any) -> float | None:
    if isinstance(x, bool):
        return None
    if isinstance(x, str):
        return _NON_FINITE.get(x)
    if isinstance(x, (int, float)):
        try:
            return float(x)
        except OverflowError:
            return None
    return None


def _convert(data: Any, t: int) -> ParameterValue | None:
    """``data`` as a value of type ``t``, or None when it is not one."""
    if t == T.PARAMETER_BOOL:
        return ParameterValue(type=t, bool_value=data) if isinstance(data, bool) else None
    if t == T.PARAMETER_INTEGER:
        return ParameterValue(type=t, integer_value=data) if _is_int(data) else None
    if t == T.PARAMETER_DOUBLE:
        d = _double_in(data)
        return None if d is None else ParameterValue(type=t, double_value=d)
    if t == T.PARAMETER_STRING:
        return ParameterValue(type=t, string_value=data) if isinstance(data, str) else None
    if not isinstance(data, list):
        return None
    if t == T.PARAMETER_BYTE_ARRAY:
        if all(_is_int(b) and 0 <= b <= 255 for b in data):
            return ParameterValue(type=t, byte_array_value=[bytes([b]) for b in data])
    elif t == T.PARAMETER_BOOL_ARRAY:
        if all(isinstance(b, bool) for b in data):
            return ParameterValue(type=t, bool_array_value=data)
    elif t == T.PARAMETER_INTEGER_ARRAY:
        if all(_is_int(i) for i in data):
            return ParameterValue(type=t, integer_array_value=data)
    elif t == T.PARAMETER_DOUBLE_ARRAY:
        doubles = [_double_in(d) for d in data]
        if all(d is not None for d in doubles):
            return ParameterValue(type=t, double_array_value=doubles)
    elif t == T.PARAMETER_STRING_ARRAY:
        if all(isinstance(s, str) for s in data):
            return ParameterValue(type=t, string_array_value=data)
    return None


def _inferred(data: Any) -> int | None:
    """The parameter type a JSON value reads as by itself (None: none)."""
    if isinstance(data, bool):
        return T.PARAMETER_BOOL
    if _is_int(data):
        return T.PARAMETER_INTEGER
    if isinstance(data, float):
        return T.PARAMETER_DOUBLE
    if isinstance(data, str):
        return T.PARAMETER_STRING
    if isinstance(data, list) and data:
        for t in (T.PARAMETER_BOOL_ARRAY, T.PARAMETER_INTEGER_ARRAY, T.PARAMETER_DOUBLE_ARRAY,
                  T.PARAMETER_STRING_ARRAY):
            if _convert(data, t) is not None:
                return t
    return None


def to_value(data: Any, current: int) -> ParameterValue:
    """The value to send for ``data``: of the parameter's type when it fits, else of the type the
    JSON reads as (the node then decides, with its own reason); IpcError when it reads as none."""
    value = _convert(data, current)
    if value is None:
        inferred = _inferred(data)
        value = None if inferred is None else _convert(data, inferred)
    if value is None:
        expected = TYPE_NAMES.get(current, "a parameter value")
        raise IpcError("invalid-parameter-value",
                       f"The value is not a ROS 2 parameter value of type {expected}: expected a boolean, an "
                       "integer (64-bit), a number (NaN and infinities as \"NaN\", \"Infinity\", \"-Infinity\"), "
                       "a string, or a non-empty array of one of those (bytes: integers 0-255)",
                       {"expected_type": expected})
    return value


def same_value(a: ParameterValue, b: ParameterValue) -> bool:
    return a.type == b.type and value_json(a) == value_json(b)


def descriptor_json(d: Any) -> dict[str, Any]:
    """The describe_parameters answer: description, read-only and, when declared, ranges and constraints."""
    out: dict[str, Any] = {"description": str(d.description), "read_only": bool(d.read_only)}
    if d.additional_constraints:
        out["additional_constraints"] = str(d.additional_constraints)
    if d.dynamic_typing:
        out["dynamic_typing"] = True
    if d.integer_range:
        r = d.integer_range[0]
        out["integer_range"] = {"from_value": int(r.from_value), "to_value": int(r.to_value), "step": int(r.step)}
    if d.floating_point_range:
        r = d.floating_point_range[0]
        out["floating_point_range"] = {"from_value": _double_out(r.from_value), "to_value": _double_out(r.to_value),
                                       "step": _double_out(r.step)}
    return out


def refused(reason: str, name: str) -> IpcError:
    """A set the node refused: read-only (403) or any other reason (400), with the node's reason."""
    text = reason or "the node refused the value without a reason"
    low = text.lower()
    if "read-only" in low or "read only" in low or "read_only" in low:
        return IpcError("parameter-read-only", text, {"name": name})
    return IpcError("invalid-parameter-value", text, {"name": name})
