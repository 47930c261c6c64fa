"""Bulk data on the HTTP side (issue 32): medkit's ``/{entity}/bulk-data`` routes.

- ``routes.py``: the routes, the ``rosbags`` category's scope;
- ``files.py``: the uploaded files' store (``bulk_data_categories``);
- ``download.py``: a file as a streamed, resumable response;
- zero-copy, cooperative ``sendfile`` for the HTTP workers: ``app/core/sendfile.py``;
- ``spec.py``: the routes' part of the OpenAPI document.

The fault recordings themselves are made by the ROS worker (``rosworker/bulk_data/``).
"""

from __future__ import annotations

from typing import Any

from flask import Flask

from ipc import counters

from ..core.family import Family, Health
from . import routes, spec


def setup(app: Flask) -> None:
    app.url_map.converters["bulk_rest"] = routes.RestConverter   # before the routes that use it
    app.register_blueprint(routes.bp)


def health(stats: dict[str, Any] | None, cfg) -> dict[str, Any]:
    """``/health``'s ``x-medkit-bulk-data``: the recordings' counters (zeros before the ROS worker answers)."""
    section = counters.health_defaults("bulk_data", cfg)
    if stats and isinstance(stats.get("bulk_data"), dict):
        section.update(stats["bulk_data"])
    return section


FAMILY = Family(
    name="bulk_data",
    spec=spec.SPEC,
    health=(Health("x-medkit-bulk-data", health, spec.health_schema(), required=True),),
    capabilities=lambda cfg: {"bulk_data": True, "bulk_data_writes": bool(cfg.allow_bulk_data)},
    setup=setup,
)
