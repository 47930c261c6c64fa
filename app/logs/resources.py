"""The logs as triggers observe them (``core/resources.py``): ``…/logs``.

A trigger on an entity's logs observes every line of the entity's nodes (the rule
of ``routes.py``); the ROS worker evaluates it on each line
(``rosworker/logs/observable.py``), whose payload is the entry as ``GET …/logs``
lists it.  ``…/logs`` has no items (``…/logs/x`` is refused).
"""

from __future__ import annotations

from typing import Any
from urllib.parse import unquote

from flask import Flask

from ..core import resources
from ..core.entities import Entity
from ..core.errors import ApiError
from ..core.resources import Resource


def observed(resource: Resource, entity: Entity, condition: dict[str, Any], path: str) -> tuple[str, str]:
    if unquote(resource.rest).strip("/"):
        raise ApiError(400, "invalid-parameter", "The logs collection has no items: observe "
                       "/api/v1/{entity}/{id}/logs", {"parameter": "resource", "value": resource.text[:300]})
    return resources.scope(entity, resource, condition, path, "log entry", "/context/line")


def setup(app: Flask) -> None:
    resources.observable(app, resources.Observable("logs", observed, "logs"))
