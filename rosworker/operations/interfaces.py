"""Which services and actions a node offers, and their interface types (``op_list``'s part).

Discovery: a node's services as the graph lists them.  Parameter services,
``get_type_description`` and the hidden ``/_action/`` services are not
operations; an action is found through its ``<action>/_action/send_goal``
service (type ``pkg/action/Name_SendGoal``).  Each carries ``type_info``: the
JSON schemas (and default values) of the request and response, or of the goal,
result and feedback, built by ``ros/schema.py`` as the data items' are.

Types: ``pkg/srv/Name`` and ``pkg/action/Name`` only, imported only from a
rosidl-generated package (the file system is looked at first, as
``msgtypes.load_type`` does for messages).
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import json
import os
import re
from typing import Any

from ipc.errors import IpcError

from ..ros.msgtypes import ConversionError, _is_message_class
from ..ros.schema import default_value, schema

INTERFACE = re.compile(r"^([A-Za-z][A-Za-z0-9_]{0,100})/(srv|action)/([A-Z][A-Za-z0-9]{0,100})$")
PARAMETER_SERVICES = frozenset({"describe_parameters", "get_parameter_types", "get_parameters",
                                "list_parameters", "set_parameters", "set_parameters_atomically"})
SEND_GOAL = "/_action/send_goal"


def _package_has(pkg: str, kind: str) -> bool:
    """True if ``pkg`` is a rosidl-generated package with ``kind`` interfaces, WITHOUT importing it."""
    try:
        spec = importlib.util.find_spec(pkg)
    except Exception:  # noqa: BLE001 - anything odd means "not a ROS package"
        return False
    for loc in (spec.submodule_search_locations or []) if spec else []:
        if os.path.isfile(os.path.join(loc, kind, "__init__.py")) and any(
                f.startswith(f"{pkg}_s__rosidl_typesupport_c") for f in os.listdir(loc)):
            return True
    return False


@functools.lru_cache(maxsize=512)
def _load(name: str, kind: str) -> type:
    match = INTERFACE.fullmatch(name)
    if match is None or match.group(2) != kind:
        example = "std_srvs/srv/Trigger" if kind == "srv" else "test_msgs/action/Fibonacci"
        raise ConversionError("invalid-type", f"Invalid {'service' if kind == 'srv' else 'action'} type "
                                              f"{name[:80]!r}: expected 'package/{kind}/Name', e.g. '{example}'")
    pkg, _, cls_name = match.groups()
    missing = ConversionError("type-not-installed", f"Type '{name}' is not installed on the gateway")
    if not _package_has(pkg, kind):
        raise missing
    try:
        cls = getattr(importlib.import_module(f"{pkg}.{kind}"), cls_name, None)
    except Exception:  # noqa: BLE001 - a broken package is as good as a missing one
        raise missing from None
    parts = ("Request", "Response") if kind == "srv" else ("Goal", "Result", "Feedback")
    if cls is None or not all(_is_message_class(getattr(cls, p, None)) for p in parts):
        raise missing
    return cls


def load_interface(name: Any, kind: str) -> type:
    """The service (``kind`` "srv") or action class of ``name``; raises IpcError (400) on trouble."""
    if not isinstance(name, str):
        raise IpcError("type-introspection-failed", "type: expected a string")
    try:
        return _load(name, kind)
    except ConversionError as exc:
        raise IpcError("type-introspection-failed", exc.message, {"type": name[:300]}) from None


@functools.lru_cache(maxsize=512)
def _type_info(name: str, kind: str) -> str:
    cls = load_interface(name, kind)
    parts = ("request", "response") if kind == "srv" else ("goal", "result", "feedback")
    info: dict[str, Any] = {p: schema(getattr(cls, p.capitalize())) for p in parts}
    info["default_value"] = {p: default_value(getattr(cls, p.capitalize())) for p in parts}
    return json.dumps(info)


def type_info(name: str, kind: str) -> dict[str, Any] | None:
    """The schemas and default values of a service or action type, or None when it cannot be loaded."""
    try:
        return json.loads(_type_info(name, kind))
    except IpcError:
        return None


def node_operations(services: list[tuple[str, list[str]]]) -> list[dict[str, Any]]:
    """A node's operations from its ``(service name, types)`` list, services first, then actions."""
    out_services, out_actions = [], []
    for path, types in sorted(services):
        if not types:
            continue
        type_name = types[0]
        short = path.rsplit("/", 1)[-1]
        if path.endswith(SEND_GOAL) and type_name.endswith("_SendGoal") and "/action/" in type_name:
            action_path = path[:-len(SEND_GOAL)]
            if action_path:
                out_actions.append({"kind": "action", "path": action_path,
                                    "name": action_path.rsplit("/", 1)[-1],
                                    "type": type_name[:-len("_SendGoal")]})
            continue
        if "/_action/" in path or short == "get_type_description" or \
                (short in PARAMETER_SERVICES and type_name.startswith("rcl_interfaces/srv/")):
            continue
        out_services.append({"kind": "service", "path": path, "name": short, "type": type_name})
    return out_services + out_actions
