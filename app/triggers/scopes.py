"""What a trigger on ``…/faults``, ``…/faults/{code}`` or ``…/logs`` observes: the entity's scope.

The routes of ``app/triggers/routes.py`` ask :func:`resolve` for a resource of
these collections (after the entity checks every resource gets).  The scope is
the one the faults and logs routes use: the node FQNs of the entity's apps
(``app/logs/routes.py`` ``source_fqns``: an app's own node, a component's or a
function's hosted apps' nodes), resolved when the trigger is made and sent to
the ROS worker as the trigger's ``target`` (JSON, ``rosworker/triggers/sources.py``).

A condition that cannot apply is refused here (400 ``invalid-parameter``): a
fault event's and a log line's payload is an object, never a number, so
``EnterRange``/``LeaveRange`` need a ``path`` to a number in it
(``/severity``, ``/occurrence_count``, ``/context/line``).  ``…/logs`` has no
items (``…/logs/x`` is refused), and ``…/faults/{code}`` takes one fault code.
"""

from __future__ import annotations

import json
import re
from typing import Any
from urllib.parse import unquote, urlsplit

from ..core import rosclient
from ..core.entities import Entity
from ..core.errors import ApiError
from ..logs.routes import source_fqns

COLLECTIONS = ("faults", "logs")
CODE_MAX = 256
_REST = re.compile(r"^/api/v1/[^/?#]+/[^/?#]+/(faults|logs)(/.*)?$")
RANGES = ("EnterRange", "LeaveRange")


def _bad(message: str, parameter: str, value: Any = None) -> ApiError:
    params: dict[str, Any] = {"parameter": parameter}
    if value is not None:
        params["value"] = str(value)[:300]
    return ApiError(400, "invalid-parameter", message, params)


def resolve(resource: str, entity: Entity, condition: dict[str, Any], path: str) -> tuple[str, str, str]:
    """``(source kind, target, bytes mode)`` of a faults or logs resource of ``entity``."""
    match = _REST.match(urlsplit(resource).path)
    if match is None:  # pragma: no cover - the caller matched the collection already
        raise _bad("Unknown collection", "resource", resource)
    kind, rest = match.group(1), unquote(match.group(2) or "")
    target: dict[str, Any] = {"nodes": source_fqns(rosclient.get().entities(), entity)}
    if kind == "logs":
        if rest.strip("/"):
            raise _bad("The logs collection has no items: observe /api/v1/{entity}/{id}/logs", "resource", resource)
    else:
        code = rest[1:] if rest.startswith("/") else rest
        if code and (len(code) > CODE_MAX or "/" in code):
            raise _bad(f"Invalid fault code: 1 to {CODE_MAX} characters, no '/'", "resource", resource)
        target["code"] = code or None
    if condition["condition_type"] in RANGES and not path:
        raise _bad(f"{condition['condition_type']} on {kind} needs a 'path' to a number in the payload "
                   f"(a {'fault event' if kind == 'faults' else 'log entry'} is an object), e.g. "
                   f"{'/severity' if kind == 'faults' else '/context/line'}", "path")
    return kind, json.dumps(target, separators=(",", ":")), "array"
