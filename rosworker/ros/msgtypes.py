"""ROS 2 message types: names, loading, and what a type is made of (``rosidl_runtime_py`` is not available).

Everything is driven by the generated classes' own introspection: ``get_fields_and_field_types()``
gives the field names and ``SLOT_TYPES`` (``rosidl_parser.definition`` objects) their types.
:func:`_plan` turns them, once per class, into the field specs (``_Spec``) that the conversions
of this package share: ``encode.py`` (message -> JSON), ``decode.py`` (JSON -> message) and
``schema.py`` (``type_info``: schema and default value).  The underscore names here are shared
by those modules only.

Type names: only ``pkg/msg/Name`` is accepted, and a package is imported only when the file
system shows that it is a rosidl-generated one (:func:`load_type`).

rclpy storage (what ``encode.py`` reads, and what ``decode.py`` produces): a ``byte`` is a
1-length ``bytes`` and ``byte[]`` a list of them; a ``uint8``/``char`` is an ``int``; numeric
sequences are ``array.array``; fixed-size numeric arrays are ``numpy.ndarray``.

Runs on the ROS thread (the ROS worker), and in tests and benchmarks.
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import os
from typing import Any

from rosidl_parser import definition as _d

from ipc.topics import MESSAGE_TYPE, valid_message_type

__all__ = ["NON_FINITE", "ConversionError", "check_type_name", "load_type", "type_name"]


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
# Non-finite floats on the JSON side (the proto3 JSON mapping: encode.py, decode.py, schema.py).
NON_FINITE = ("NaN", "Infinity", "-Infinity")


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

