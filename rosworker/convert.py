"""Conversion between ROS 2 messages and JSON-ready data (``rosidl_runtime_py`` is not available).

Everything is driven by the generated classes' own introspection: ``get_fields_and_field_types()``
gives the field names and ``SLOT_TYPES`` (``rosidl_parser.definition`` objects) their types.

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
  return, too close), in samples and in PUT bodies alike, so a GET -> PUT round trip is exact.
  ``from_plain`` also reads ``null`` in a float field as NaN: medkit's clients write NaN that way.

rclpy storage (what ``to_plain`` reads, and what ``from_plain`` produces): a ``byte`` is a
1-length ``bytes`` and ``byte[]`` a list of them; a ``uint8``/``char`` is an ``int``; numeric
sequences are ``array.array``; fixed-size numeric arrays are ``numpy.ndarray``.  Jazzy disables the
generated setters' checks unless ``ROS_PYTHON_CHECK_FIELDS=1``, and the C serializer silently
truncates out-of-range integers, short fixed arrays and strings at a NUL, so ``from_plain``
validates everything itself.
"""

from __future__ import annotations

import array
import base64
import binascii
import copy
import functools
import importlib
import importlib.util
import math
import os
from typing import Any

import numpy
import orjson
from rosidl_parser import definition as _d

from ipc.topics import MESSAGE_TYPE, valid_message_type

__all__ = [
    "ConversionError", "check_type_name", "load_type", "type_name",
    "to_plain", "to_json", "from_plain", "schema", "default_value",
]


class ConversionError(ValueError):
    """A conversion failed; ``code`` is "invalid-type", "type-not-installed" or "invalid-data"."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


# ---------------------------------------------------------------------------- type names



def _short(text: str, limit: int = 80) -> str:
    """repr() of a client-supplied string, cut so that error messages stay small."""
    return repr(text if len(text) <= limit else text[:limit] + "...")


def check_type_name(name: Any) -> None:
    """Raise ConversionError("invalid-type") unless ``name`` is exactly ``pkg/msg/Name``."""
    if not isinstance(name, str):
        raise ConversionError("invalid-type", f"Message type must be a string, got {type(name).__name__}")
    if not valid_message_type(name):
        raise ConversionError(
            "invalid-type",
            f"Invalid message type {_short(name)}: expected 'package/msg/Name', e.g. 'std_msgs/msg/String'",
        )


def _is_message_class(obj: Any) -> bool:
    return (isinstance(obj, type) and hasattr(type(obj), "__import_type_support__")
            and hasattr(type(obj), "_TYPE_SUPPORT") and hasattr(obj, "get_fields_and_field_types")
            and hasattr(obj, "SLOT_TYPES"))


def _is_ros_interface_package(pkg: str) -> bool:
    """True if top-level ``pkg`` looks like a rosidl-generated package, WITHOUT importing it.

    Importing ``pkg.msg`` would execute ``pkg/__init__.py`` first, so arbitrary installed modules
    (``this``, ``antigravity``, ...) must be ruled out from the file system alone.
    """
    try:
        spec = importlib.util.find_spec(pkg)
    except Exception:  # noqa: BLE001 - anything odd means "not a ROS package"
        return False
    for loc in (spec.submodule_search_locations or []) if spec else []:
        if os.path.isfile(os.path.join(loc, "msg", "__init__.py")) and any(
            f.startswith(f"{pkg}_s__rosidl_typesupport_c") for f in os.listdir(loc)
        ):
            return True
    return False


@functools.lru_cache(maxsize=1024)  # exceptions are not cached: a later install is picked up
def _load_checked(name: str) -> type:
    pkg, cls_name = MESSAGE_TYPE.fullmatch(name).groups()
    missing = ConversionError("type-not-installed", f"Message type '{name}' is not installed on the gateway")
    if not _is_ros_interface_package(pkg):
        raise missing
    try:
        cls = getattr(importlib.import_module(f"{pkg}.msg"), cls_name, None)
    except Exception:  # noqa: BLE001 - a broken package is as good as a missing one
        raise missing from None
    if not _is_message_class(cls) or not cls.__module__.startswith(f"{pkg}.msg."):
        raise missing
    if type(cls)._TYPE_SUPPORT is None:
        type(cls).__import_type_support__()
        if type(cls)._TYPE_SUPPORT is None:
            raise ConversionError(
                "type-not-installed",
                f"Message type '{name}' is installed but its type support library could not be loaded",
            )
    return cls


def load_type(name: Any) -> type:
    """Return the message class for ``pkg/msg/Name``; only ever raises ConversionError."""
    check_type_name(name)
    return _load_checked(name)


def type_name(cls: Any) -> str:
    """``std_msgs.msg.String`` (class or instance) -> ``"std_msgs/msg/String"``."""
    cls = cls if isinstance(cls, type) else type(cls)
    parts = cls.__module__.split(".")
    if parts[-1].startswith("_"):
        parts.pop()
    return "/".join(parts + [cls.__name__])


# ------------------------------------------------------------------------- field specs

_INT_ALIASES = {"short": "int16", "unsigned short": "uint16", "long": "int32",
                "unsigned long": "uint32", "long long": "int64", "unsigned long long": "uint64"}
_TYPECODES = {"int8": "b", "uint8": "B", "int16": "h", "uint16": "H", "int32": "i",
              "uint32": "I", "int64": "q", "uint64": "Q", "float": "f", "double": "d"}
_LABELS = {"float": "float32", "double": "float64", "long double": "float128",
           "boolean": "bool", "octet": "byte"}
_F32_LIMIT = 2.0**128 * (1 - 2.0**-25)  # the smallest double that rounds to float32 inf
# Non-finite floats on the JSON side (the proto3 JSON mapping); null is read as NaN too.
NON_FINITE = ("NaN", "Infinity", "-Infinity")
_FROM_JSON = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf, None: math.nan}
_SMALL_FLOATS = 48  # float arrays up to this size are encoded as lists (see _numeric)
_ONE_BYTE = [bytes((i,)) for i in range(256)]
_EXPECT = {"bool": "a boolean", "int": "an integer",
           "float": 'a number, "NaN", "Infinity" or "-Infinity"', "octet": "an integer",
           "char": "an integer or a 1-character string", "wchar": "a 1-character string",
           "string": "a string", "message": "an object", "array": "an array"}


class _Spec:
    """How one ROS type (a field, or the items of an array field) is represented."""

    __slots__ = ("kind", "label", "lo", "hi", "max_len", "typecode", "ns", "_cls",
                 "item", "fixed", "bound", "bytelike")

    def __init__(self, t: Any) -> None:
        self.max_len = self.typecode = self.item = self.fixed = self.bound = self._cls = None
        self.lo = self.hi = 0
        self.bytelike = False
        if isinstance(t, _d.AbstractNestedType):
            self.kind, self.item = "array", _Spec(t.value_type)
            self.bytelike = getattr(t.value_type, "typename", None) in ("uint8", "octet")
            if isinstance(t, _d.Array):
                self.fixed, suffix = t.size, str(t.size)
            else:
                self.bound = getattr(t, "maximum_size", None)
                suffix = f"<={self.bound}" if self.bound is not None else ""
            self.label = f"{self.item.label}[{suffix}]"
        elif isinstance(t, _d.NamespacedType):
            self.kind, self.ns, self.label = "message", t, "/".join([*t.namespaces, t.name])
        elif isinstance(t, _d.AbstractGenericString):
            self.kind = "string"
            self.max_len = getattr(t, "maximum_size", None)
            base = "wstring" if isinstance(t, _d.AbstractWString) else "string"
            self.label = base if self.max_len is None else f"{base}<={self.max_len}"
        else:  # BasicType
            name = _INT_ALIASES.get(t.typename, t.typename)
            self.label, self.typecode = _LABELS.get(name, name), _TYPECODES.get(name)
            if name in ("boolean", "octet", "char", "wchar"):
                self.kind = {"boolean": "bool"}.get(name, name)
            elif name in ("float", "double", "long double"):
                self.kind = "float"
            else:
                bits = int(name.removeprefix("u").removeprefix("int"))
                self.kind = "int"
                self.lo, self.hi = ((0, 2**bits - 1) if name[0] == "u"
                                    else (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1))

    @property
    def cls(self) -> type:
        """Message class of a ``message`` spec, imported from trusted SLOT_TYPES on first use."""
        if self._cls is None:
            mod = importlib.import_module(".".join(self.ns.namespaces))
            self._cls = getattr(mod, self.ns.name)
        return self._cls


@functools.cache
def _plan(cls: type) -> tuple[tuple[str, _Spec], ...]:
    if not _is_message_class(cls):
        raise ConversionError("invalid-type", f"{cls!r} is not a ROS message class")
    return tuple(zip(cls.get_fields_and_field_types(), map(_Spec, cls.SLOT_TYPES), strict=True))


@functools.cache
def _fields(cls: type) -> dict[str, _Spec]:
    return dict(_plan(cls))


def _check_mode(bytes_mode: str) -> None:
    if bytes_mode not in ("array", "base64"):
        raise ConversionError("invalid-data", f"bytes_mode must be 'array' or 'base64', got {bytes_mode!r}")


def _require_message(msg: Any) -> None:
    if not _is_message_class(type(msg)):
        raise ConversionError("invalid-type", f"expected a ROS message, got {type(msg).__name__}")


# ------------------------------------------------------------------- message -> JSON data

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


def default_value(cls: type) -> dict[str, Any]:
    """The JSON data of a default-constructed ``cls``."""
    if not _is_message_class(cls):
        raise ConversionError("invalid-type", f"{cls!r} is not a ROS message class")
    return to_plain(cls())


# ------------------------------------------------------------------- JSON data -> message

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


# ---------------------------------------------------------------------------------- schema

def _spec_schema(spec: _Spec, mode: str) -> dict[str, Any]:
    kind = spec.kind
    if kind == "message":
        return _schema(spec.cls, mode)
    if kind == "array":
        if spec.bytelike and mode == "base64":
            return {"type": "string", "contentEncoding": "base64", "x-ros-type": spec.label}
        out = {"type": "array", "items": _spec_schema(spec.item, mode), "x-ros-type": spec.label}
        if spec.fixed is not None:
            out["minItems"] = out["maxItems"] = spec.fixed
        elif spec.bound is not None:
            out["maxItems"] = spec.bound
        return out
    if kind in ("int", "octet", "char"):
        lo, hi = (spec.lo, spec.hi) if kind == "int" else (0, 255 if kind == "octet" else 127)
        return {"type": "integer", "minimum": lo, "maximum": hi, "x-ros-type": spec.label}
    if kind == "float":  # NaN and +-inf are strings (see the module docstring)
        return {"anyOf": [{"type": "number"}, {"type": "string", "enum": list(NON_FINITE)}],
                "x-ros-type": spec.label}
    if kind == "bool":
        return {"type": "boolean", "x-ros-type": spec.label}
    out = {"type": "string", "x-ros-type": spec.label}
    if kind == "wchar":
        out["minLength"] = out["maxLength"] = 1
    elif spec.max_len is not None:
        out["maxLength"] = spec.max_len
    return out


@functools.cache
def _schema(cls: type, mode: str) -> dict[str, Any]:
    return {"title": type_name(cls), "type": "object",
            "properties": {name: _spec_schema(spec, mode) for name, spec in _plan(cls)},
            "additionalProperties": False}


def schema(cls: type, bytes_mode: str = "array") -> dict[str, Any]:
    """JSON schema of ``cls``'s data (cached per class; a fresh copy is returned)."""
    _check_mode(bytes_mode)
    return copy.deepcopy(_schema(cls, bytes_mode))
