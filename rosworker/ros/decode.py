"""JSON -> message: the data of a ``PUT .../data/...`` (the publishers, on the ROS thread).

The JSON side is the one ``encode.py`` writes; :func:`from_plain` also reads ``null`` in a float
field as NaN: medkit's clients write NaN that way.  Jazzy disables the generated setters' checks
unless ``ROS_PYTHON_CHECK_FIELDS=1``, and the C serializer silently truncates out-of-range
integers, short fixed arrays and strings at a NUL, so ``from_plain`` validates everything itself
and produces rclpy's storage representation (``msgtypes.py``).
"""

from __future__ import annotations

import array
import base64
import binascii
import math
from typing import Any

import numpy

from .msgtypes import ConversionError, _fields, _is_message_class, _short, _Spec, type_name

__all__ = ["from_plain"]

_F32_LIMIT = 2.0**128 * (1 - 2.0**-25)  # the smallest double that rounds to float32 inf
# Non-finite floats on the JSON side (msgtypes.NON_FINITE); null is read as NaN too.
_FROM_JSON = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf, None: math.nan}
_ONE_BYTE = [bytes((i,)) for i in range(256)]
_EXPECT = {"bool": "a boolean", "int": "an integer",
           "float": 'a number, "NaN", "Infinity" or "-Infinity"', "octet": "an integer",
           "char": "an integer or a 1-character string", "wchar": "a 1-character string",
           "string": "a string", "message": "an object", "array": "an array"}


def _kind(value: Any) -> str:
    """JSON name of a value's kind, for error messages."""
    if value is None:
        return "null"
    for types, name in ((bool, "boolean"), ((int, float), "number"), (str, "string"),
                        ((list, tuple), "array"), (dict, "object")):
        if isinstance(value, types):
            return name
    return type(value).__name__


def _invalid(path: str, problem: str) -> ConversionError:
    return ConversionError("invalid-data", f"{path}: {problem}")


def _expected(spec: _Spec, value: Any, path: str) -> ConversionError:
    what = "an array or a base64 string" if spec.bytelike else _EXPECT[spec.kind]
    got = f"string {_short(value, 40)}" if spec.kind == "float" and isinstance(value, str) else _kind(value)
    return _invalid(path, f"expected {what} ({spec.label}), got {got}")


def _int_text(value: int) -> str:
    return str(value) if value.bit_length() <= 128 else "a very large integer"


def _decode(spec: _Spec, value: Any, path: str) -> Any:
    """Validate one JSON value against ``spec``; return it in rclpy's storage representation."""
    kind = spec.kind
    is_int = isinstance(value, int) and not isinstance(value, bool)
    if kind == "float":
        if not (is_int or isinstance(value, float)):
            if value is None or isinstance(value, str) and value in _FROM_JSON:
                return _FROM_JSON[value]
            raise _expected(spec, value, path)
        try:
            value = float(value)
        except OverflowError:
            raise _invalid(path, f"{_int_text(value)} is too large for {spec.label}") from None
        if spec.typecode == "f":  # round now, so that the message holds what goes on the wire
            if _F32_LIMIT <= abs(value) < float("inf"):
                raise _invalid(path, f"{value!r} is out of range for float32")
            value = array.array("f", (value,))[0]
        return value
    if kind in ("int", "octet", "char") and is_int:
        lo, hi = (spec.lo, spec.hi) if kind == "int" else (0, 255 if kind == "octet" else 127)
        if not lo <= value <= hi:
            raise _invalid(path, f"{_int_text(value)} is out of range for {spec.label} ({lo}..{hi})")
        return int(value) if kind == "int" else _ONE_BYTE[value] if kind == "octet" else chr(value)
    if kind == "bool" and isinstance(value, bool):
        return value
    if kind in ("string", "char", "wchar") and isinstance(value, str):
        if kind != "string" and (len(value) != 1 or (kind == "char" and ord(value) > 127)):
            raise _invalid(path, f"expected a single character for {spec.label}")
        if spec.max_len is not None and len(value) > spec.max_len:
            raise _invalid(path, f"at most {spec.max_len} characters allowed for {spec.label}, "
                                 f"got {len(value)}")
        if "\x00" in value:
            raise _invalid(path, "strings may not contain NUL characters")
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            raise _invalid(path, "string is not valid Unicode (lone surrogate)") from None
        return str(value)
    if kind == "message" and isinstance(value, dict):
        return _decode_msg(spec.cls, value, path)
    if kind == "array":
        return _decode_array(spec, value, path)
    raise _expected(spec, value, path)


def _decode_numbers(item: _Spec, values: list, path: str) -> array.array:
    """list of JSON numbers -> array.array; C-speed when valid, precise message when not."""
    types = set(map(type, values))
    if item.kind == "float" and not types <= {int, float}:  # "NaN", "Infinity", "-Infinity", null
        values = [_FROM_JSON.get(x, x) if x is None or type(x) is str else x for x in values]
        types = set(map(type, values))
    if types <= ({int} if item.kind == "int" else {int, float}):
        try:
            if item.typecode == "B":  # bytes() range-checks ints several times faster
                return array.array("B", bytes(values))
            if item.typecode != "f":
                return array.array(item.typecode, values)
            wide = numpy.array(values, dtype=numpy.float64)
            if not (numpy.abs(wide[numpy.isfinite(wide)]) >= _F32_LIMIT).any():
                return array.array("f", wide.astype(numpy.float32).tobytes())
        except (OverflowError, ValueError):
            pass  # fall through: find the offending element
    out = [_decode(item, x, f"{path}[{i}]") for i, x in enumerate(values)]
    return array.array(item.typecode, out)


def _decode_array(spec: _Spec, value: Any, path: str) -> Any:
    item, raw = spec.item, None
    if spec.bytelike and isinstance(value, str):
        try:
            raw = base64.b64decode(value, validate=True)
        except (binascii.Error, ValueError):
            raise _invalid(path, f"invalid base64 string for {spec.label}") from None
    elif not isinstance(value, (list, tuple)):
        raise _expected(spec, value, path)
    count = len(raw if raw is not None else value)
    if spec.fixed is not None and count != spec.fixed:
        raise _invalid(path, f"exactly {spec.fixed} items required for {spec.label}, got {count}")
    if spec.bound is not None and count > spec.bound:
        raise _invalid(path, f"at most {spec.bound} items allowed for {spec.label}, got {count}")
    if item.typecode:  # numeric, including uint8: array.array, or numpy for fixed-size arrays
        out = array.array("B", raw) if raw is not None else _decode_numbers(item, value, path)
        return numpy.frombuffer(out, dtype=out.typecode).copy() if spec.fixed is not None else out
    if item.kind == "octet":
        if raw is None and set(map(type, value)) <= {int}:
            try:
                raw = bytes(value)
            except ValueError:
                pass
        if raw is not None:
            return list(map(_ONE_BYTE.__getitem__, raw))
    return [_decode(item, x, f"{path}[{i}]") for i, x in enumerate(value)]


def _field_text(key: Any) -> str:
    return key if isinstance(key, str) and key.isidentifier() and len(key) <= 64 else (
        _short(key, 64) if isinstance(key, str) else repr(type(key).__name__))


def _decode_msg(cls: type, data: dict, path: str) -> Any:
    fields, msg = _fields(cls), cls()
    for key, value in data.items():
        spec = fields.get(key) if isinstance(key, str) else None
        if spec is None:
            raise _invalid(f"{path}.{_field_text(key)}", f"no such field in {type_name(cls)}")
        sub = f"{path}.{key}"
        converted = _decode(spec, value, sub)
        try:
            setattr(msg, key, converted)
        except (AssertionError, TypeError, ValueError, OverflowError) as exc:
            raise _invalid(sub, str(exc)[:200]) from None
    return msg


def from_plain(cls: type, data: Any, *, path: str = "data") -> Any:
    """Build a ``cls`` message from JSON data; missing fields keep their defaults.

    Only ever raises ConversionError; messages name the field path (``data.header.stamp.sec``).
    """
    if not _is_message_class(cls):
        raise ConversionError("invalid-type", f"{cls!r} is not a ROS message class")
    if not isinstance(data, dict):
        raise _invalid(path, f"expected an object for {type_name(cls)}, got {_kind(data)}")
    try:
        return _decode_msg(cls, data, path)
    except ConversionError:
        raise
    except Exception as exc:  # noqa: BLE001 - e.g. MemoryError; the contract is ConversionError only
        raise _invalid(path, f"cannot build {type_name(cls)}: {type(exc).__name__}") from None
