"""Message -> JSON: what a sample's ``data`` is (the pool and the stream ticks, on the ROS thread).

Representation on the JSON side:

* nested messages are objects keyed by the ROS field names (``builtin_interfaces/msg/Time`` is
  simply ``{"sec": ..., "nanosec": ...}``);
* ``bool`` -> boolean, integers -> integer, ``float32``/``float64`` -> number (always a float:
  ``1.0`` stays ``1.0``), ``string``/``wstring`` -> string (``"123"`` stays a string);
* arrays and sequences -> arrays (empty -> ``[]``); ``byte``/``octet``/``char`` values -> integers;
* with ``bytes_mode="base64"`` every ``uint8[]``/``byte[]`` (``octet``) array or sequence becomes a
  single standard, padded base64 string instead of an array of integers;
* JSON has no NaN or +-inf.  As in the proto3 JSON mapping, a non-finite float is the string
  ``"NaN"``, ``"Infinity"`` or ``"-Infinity"`` (REP 117 gives them different meanings: invalid, no
  return, too close), in samples and in PUT bodies alike, so a GET -> PUT round trip is exact
  (``decode.py`` reads them back).

The fields come from ``msgtypes._plan``; how rclpy stores them is described in ``msgtypes.py``.
"""

from __future__ import annotations

import array
import base64
import math
from typing import Any

import numpy
import orjson

from .msgtypes import ConversionError, _check_mode, _is_message_class, _plan, _Spec

__all__ = ["to_plain", "to_json"]

_SMALL_FLOATS = 48  # float arrays up to this size are encoded as lists (see _numeric)


def _require_message(msg: Any) -> None:
    if not _is_message_class(type(msg)):
        raise ConversionError("invalid-type", f"expected a ROS message, got {type(msg).__name__}")


def _raw_bytes(value: Any) -> Any:
    """The bytes of a byte-ish array field as a C-contiguous buffer, without copying if possible."""
    if isinstance(value, (bytes, bytearray, memoryview)):
        return value
    if isinstance(value, array.array) and value.itemsize == 1:
        return value
    if isinstance(value, numpy.ndarray):
        return numpy.ascontiguousarray(value, dtype=numpy.uint8)
    try:  # list of 1-byte ``bytes`` (byte[]) or, from hand-made messages, of ints
        return b"".join(value)
    except TypeError:
        return bytes(value)


def _non_finite(value: float) -> str:
    """The JSON text of a float that is not finite: "NaN", "Infinity" or "-Infinity"."""
    return "NaN" if value != value else "Infinity" if value > 0 else "-Infinity"


def _float(value: Any) -> float | str:
    value = float(value)
    return value if value - value == 0.0 else _non_finite(value)  # x - x is NaN for NaN and +-inf


def _numeric(value: Any, fast: bool) -> Any:
    """array.array / ndarray of numbers -> list, or (fast) a numpy array orjson writes natively.

    A float array holding NaN or +-inf (rare) becomes a list with those values as strings.
    """
    if not fast:
        out = value.tolist()
        floats = value.typecode in "fd" if isinstance(value, array.array) else value.dtype.kind == "f"
        return out if not floats or all(map(math.isfinite, out)) else [_float(x) for x in out]
    if isinstance(value, array.array):
        out = numpy.frombuffer(value, dtype=value.typecode)
    else:
        out = numpy.ascontiguousarray(value)
    if out.dtype.kind == "f":
        # The guard of the fast path: is every value finite?  Small arrays (a covariance) as a
        # list: its sum is finite if every value is (NaN and inf propagate; only a sum beyond
        # 1.8e308 needs the exact check), cheaper than any numpy call.  Large ones: vectorised.
        if out.size <= _SMALL_FLOATS:
            values = out.tolist()
            if not math.isfinite(sum(values)) and not all(map(math.isfinite, values)):
                return [_float(x) for x in values]
            return values
        if out.dtype != numpy.float64:
            # orjson prints float32 with the shortest float32 digits ("0.1"), which parses back to
            # a different double than float(x) (0.10000000149011612); widening keeps the exact value.
            out = out.astype(numpy.float64)
        if numpy.count_nonzero(numpy.isfinite(out)) != out.size:
            return [_float(x) for x in out.tolist()]
    elif out.dtype.kind not in "iub" or out.dtype.byteorder not in "=|":
        return out.tolist()
    return out


def _encode(spec: _Spec, value: Any, mode: str, fast: bool) -> Any:
    kind = spec.kind
    if kind == "message":
        return _encode_msg(value, mode, fast)
    if kind == "float":  # inlined _float(): this is the hot path of float-heavy messages
        value = float(value)
        return value if value - value == 0.0 else _non_finite(value)
    if kind == "int":
        return value if type(value) is int else int(value)
    if kind == "bool":
        return bool(value)
    if kind == "array":
        if spec.bytelike:
            raw = _raw_bytes(value)
            if mode == "base64":
                return base64.b64encode(raw).decode("ascii")
            raw = numpy.frombuffer(raw, dtype=numpy.uint8)
            return raw if fast else raw.tolist()
        if spec.item.typecode and isinstance(value, (array.array, numpy.ndarray)):
            return _numeric(value, fast)
        return [_encode(spec.item, x, mode, fast) for x in value]
    if kind == "octet":
        return value[0] if isinstance(value, (bytes, bytearray)) else int(value)
    if kind == "char":
        return ord(value) if isinstance(value, str) else int(value)
    return value  # string, wstring, wchar: str


def _encode_msg(msg: Any, mode: str, fast: bool) -> dict[str, Any]:
    return {name: _encode(spec, getattr(msg, name), mode, fast) for name, spec in _plan(type(msg))}


def to_plain(msg: Any, bytes_mode: str = "array") -> dict[str, Any]:
    """Message -> dict of plain Python values (dict, list, str, int, float, bool) ready for JSON."""
    _check_mode(bytes_mode)
    _require_message(msg)
    return _encode_msg(msg, bytes_mode, False)


def to_json(obj: Any, bytes_mode: str = "array") -> bytes:
    """Encode a message, or a plain dict/list (which may contain messages), as JSON bytes.

    Numeric arrays go to orjson as numpy views (several times faster than lists of ints).
    NaN and +-inf in a message's float fields are written as "NaN", "Infinity" and "-Infinity";
    a plain ``float`` outside a message is orjson's business (it writes ``null``).
    """
    _check_mode(bytes_mode)

    def default(value: Any) -> Any:
        if _is_message_class(type(value)):
            return _encode_msg(value, bytes_mode, True)
        if isinstance(value, array.array):
            return _numeric(value, True)
        if isinstance(value, numpy.ndarray):  # dtypes orjson cannot write natively
            return value.tolist()
        if isinstance(value, numpy.generic):
            return value.item()
        raise TypeError(f"{type(value).__name__} is not JSON serializable")

    data = _encode_msg(obj, bytes_mode, True) if _is_message_class(type(obj)) else obj
    try:
        return orjson.dumps(data, default=default, option=orjson.OPT_SERIALIZE_NUMPY)
    except orjson.JSONEncodeError as exc:
        raise ConversionError("invalid-data", f"cannot encode as JSON: {exc}") from None
