"""The faults as triggers observe them (``core/resources.py``): ``…/faults`` and ``…/faults/{code}``.

A trigger on an entity's faults observes every fault event in the entity's scope
(its nodes: the rule of ``routes.py``), or only those of one fault code; the ROS
worker evaluates it on each event (``rosworker/faults/observable.py``), whose
payload is the fault as ``GET /faults`` lists it plus ``event_type``.
"""

from __future__ import annotations

from typing import Any
from urllib.parse import unquote

from flask import Flask

from ..core import resources
from ..core.entities import Entity
from ..core.errors import ApiError
from ..core.resources import Resource

CODE_MAX = 256


def observed(resource: Resource, entity: Entity, condition: dict[str, Any], path: str) -> tuple[str, str]:
    rest = unquote(resource.rest)
    code = rest[1:] if rest.startswith("/") else rest
    if code and (len(code) > CODE_MAX or "/" in code):
        raise ApiError(400, "invalid-parameter", f"Invalid fault code: 1 to {CODE_MAX} characters, no '/'",
                       {"parameter": "resource", "value": resource.text[:300]})
    return resources.scope(entity, resource, condition, path, "fault event", "/severity", code=code or None)


def setup(app: Flask) -> None:
    resources.observable(app, resources.Observable("faults", observed, "faults"))
