"""``type_info``: the JSON schema of a message type's data, and its default value.

The schema describes what ``encode.py`` writes and ``decode.py`` accepts, per byte-array mode;
it is built once per class and mode, and each caller gets a fresh copy.  Runs on the ROS thread
(``rosworker/data/commands.py``).
"""

from __future__ import annotations

import copy
import functools
from typing import Any

from .encode import to_plain
from .msgtypes import (
    NON_FINITE,
    ConversionError,
    _check_mode,
    _is_message_class,
    _plan,
    _Spec,
    type_name,
)

__all__ = ["schema", "default_value"]


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
    if kind == "float":
        # A number, as medkit's own schema says: "type" is what medkit's web UI (and other form
        # builders) read to draw a number field; a list of types there breaks its form builder.
        # NaN and +-inf are the strings of the anyOf (see encode.py's docstring and the README).
        return {"type": "number", "anyOf": [{"type": "number"}, {"type": "string", "enum": list(NON_FINITE)}],
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


def default_value(cls: type) -> dict[str, Any]:
    """The JSON data of a default-constructed ``cls``."""
    if not _is_message_class(cls):
        raise ConversionError("invalid-type", f"{cls!r} is not a ROS message class")
    return to_plain(cls())
