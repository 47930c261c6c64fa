"""Bulk data on the HTTP side (issue 32): medkit's ``/{entity}/bulk-data`` routes.

- ``routes.py``: the routes, the ``rosbags`` category's scope;
- ``files.py``: the uploaded files' store (``bulk_data_categories``);
- ``download.py``: a file as a streamed, resumable response;
- ``sendfile.py``: zero-copy, cooperative ``sendfile`` for the HTTP workers;
- ``spec.py``: the routes' part of the OpenAPI document.

The fault recordings themselves are made by the ROS worker (``rosworker/bulk_data/``).
"""

from __future__ import annotations

from typing import Any

from flask import Flask

from ipc import counters


def init_app(app: Flask) -> None:
    from . import routes

    app.url_map.converters["bulk_rest"] = routes.RestConverter
    app.register_blueprint(routes.bp)


def health(stats: dict[str, Any] | None, cfg) -> dict[str, Any]:
    """``/health``'s ``x-medkit-bulk-data``: the recordings' counters (zeros before the ROS worker answers)."""
    section = counters.health_defaults("bulk_data", cfg)
    if stats and isinstance(stats.get("bulk_data"), dict):
        section.update(stats["bulk_data"])
    return section
