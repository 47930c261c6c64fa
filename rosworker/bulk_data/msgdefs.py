"""The complete message definition of a ROS 2 type, as rosbag2 stores it in an MCAP schema.

An MCAP reader that knows no ROS types (Foxglove, ``mcap-ros2-support``) decodes a
channel's CDR with nothing but its schema, so the schema must carry the type's own
``.msg`` text and, recursively, that of every type it uses.  rosbag2's
``LocalMessageDefinitionSource`` does this with the ``.msg`` files a ROS install keeps
under ``share/<package>/msg/``, and so does :func:`definition`, in its ``ros2msg``
encoding (``docs/message_definition_encoding.md`` of rosbag2):

- the root type's text first, without a delimiter;
- then each type it depends on, depth first, each once, after a line of 80 ``=`` and
  a line ``MSG: <type as the field names it>`` (``std_msgs/Header``, or
  ``<package>/<Name>`` for a field of the same package written without one).

A type without a ``.msg`` file (defined in IDL only) gets the ``ros2idl`` encoding:
every ``.idl`` text, each after the delimiter ``IDL: <package>/msg/<Name>``.

Where the files are: each prefix of ``AMENT_PREFIX_PATH`` (a robot's ROS install and its
workspaces), then this interpreter's own prefix, which is where the ``ros-jazzy-*``
wheels put ``share/``.  Plain file reads: the ROS worker's writer thread calls this
(``writer.py``), never the ROS thread.  Definitions are cached per type.
"""

from __future__ import annotations

import functools
import os
import re
import sys

DELIMITER = "=" * 80
MAX_DEPTH = 50          # nesting levels followed (rosbag2's cap is the same order)
MAX_TYPES = 500         # types in one definition, at most
PRIMITIVES = frozenset({"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
                        "int32", "uint32", "int64", "uint64", "string", "wstring"})
# The type at the start of a field line: "pkg/Type[] name", "Type[<=3] name", "float64 x"; comments and
# constants of primitive types fall out below.  A bounded string ("string<=10 name") is primitive either way.
_FIELD_TYPE = re.compile(r"^\s*([A-Za-z][A-Za-z0-9_/]*)(?:\[[^\]]*\])?\s+", re.M)
_IDL_INCLUDE = re.compile(r'^#include\s+["<]([A-Za-z0-9_/]+)\.idl[">]', re.M)
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


class DefinitionNotFound(LookupError):
    """No ``.msg`` (or ``.idl``) file for a type under any known prefix."""


def prefixes() -> list[str]:
    """Where ``share/<package>`` is looked for, in order."""
    out = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    for prefix in (sys.prefix, sys.base_prefix):
        if prefix not in out:
            out.append(prefix)
    return out


def _split(type_name: str) -> tuple[str, str, str]:
    """``pkg/Name`` or ``pkg/msg/Name`` -> (pkg, "msg", Name); ValueError for anything else."""
    parts = type_name.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(_NAME.match(p) for p in parts):
        raise ValueError(f"not a message type name: {type_name!r}")
    return parts[0], parts[1], parts[2]


def _read(type_name: str, extension: str) -> str:
    package, folder, name = _split(type_name)
    for prefix in prefixes():
        path = os.path.join(prefix, "share", package, folder, name + extension)
        try:
            with open(path, encoding="utf-8") as fh:
                return fh.read()
        except FileNotFoundError:
            continue
    raise DefinitionNotFound(f"{type_name}: no {extension} file under share/{package}/{folder} of "
                             + ", ".join(prefixes()))


def _msg_dependencies(text: str, package: str) -> list[str]:
    out: list[str] = []
    for match in _FIELD_TYPE.finditer(text):
        name = match.group(1)
        if name in PRIMITIVES:
            continue
        dep = name if "/" in name else f"{package}/{name}"
        if dep not in out:
            out.append(dep)
    return out


def _expand(root: str, extension: str, dependencies) -> str:
    """The root's text and every dependency's after its delimiter (each type once, depth first)."""
    seen = {root}
    label = "MSG" if extension == ".msg" else "IDL"

    def walk(type_name: str, depth: int) -> str:
        if depth > MAX_DEPTH:
            raise ValueError(f"{root}: definitions nested deeper than {MAX_DEPTH} levels")
        text = _read(type_name, extension)
        result = text
        for dep in dependencies(text, _split(type_name)[0]):
            if dep in seen:
                continue
            seen.add(dep)
            if len(seen) > MAX_TYPES:
                raise ValueError(f"{root}: more than {MAX_TYPES} types in its definition")
            result += f"\n{DELIMITER}\n{label}: {dep}\n" + walk(dep, depth + 1)
        return result

    return walk(root, 1)


@functools.lru_cache(maxsize=512)
def definition(type_name: str) -> tuple[str, str]:
    """``(encoding, text)`` of ``pkg/msg/Name``: ``("ros2msg", ...)``, or ``("ros2idl", ...)`` when the
    type has no ``.msg`` file.  Raises :class:`DefinitionNotFound` when neither is installed, ValueError
    for a name that is not a message type's."""
    try:
        return "ros2msg", _expand(type_name, ".msg", _msg_dependencies)
    except DefinitionNotFound:
        pass
    package, folder, name = _split(type_name)
    root = f"{package}/{folder}/{name}"
    text = _expand(root, ".idl", lambda text, _pkg: list(dict.fromkeys(_IDL_INCLUDE.findall(text))))
    return "ros2idl", f"{DELIMITER}\nIDL: {root}\n" + text
