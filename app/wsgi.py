"""The Flask application factory; gunicorn loads ``app.wsgi:create_app()``.

Nothing happens at import time.  ``create_app`` runs in each HTTP worker
after gunicorn forked it; the ROS-worker client it sets up opens its ZeroMQ
context only on first use (``app/core/rosclient.py``), and a family's stream hub
is made when its first stream opens (``app/sse/hub.py``).  Settings come from
``common.settings.load()``: the supervisor hands them to gunicorn's workers as
``SOVD_*`` environment variables.

The app is the core (``app/core/``: the request hooks, the errors, the ROS
worker's client, discovery, the root routes, the dashboard) and the resource
families (``app/<family>/``, found by ``core/family.py``'s ``discover``), each
plugged in by its ``FAMILY.init_app(app)``.

``test_config`` overrides settings by their name (``runtime_dir``,
``allow_publish``, ``sample_timeout`` ...); any other key goes into
``app.config`` (e.g. ``SOVD_HOSTNAME``, ``SOVD_GRAPH_REFRESH_S``).
"""

from __future__ import annotations

from typing import Any

from flask import Flask

from common import settings

from . import audit, auth, ratelimit
from .core import (
    clientaddr,
    common,
    cors,
    discovery,
    errors,
    family,
    metrics,
    requestid,
    root,
    rosclient,
    ui,
    unimplemented,
)


def create_app(test_config: dict[str, Any] | None = None) -> Flask:
    app = Flask(__name__)
    cfg = settings.load()
    for key, value in (test_config or {}).items():
        setting = settings.BY_NAME.get(key)
        if setting is not None:
            cfg[key] = setting.parse(value, "test_config")
        else:
            app.config[key] = value
    app.config["SOVD"] = cfg
    app.config["MAX_CONTENT_LENGTH"] = cfg.max_body_bytes

    # `data//a/b` must reach the data route as `/a/b`, not be redirected to `data/a/b`.
    app.url_map.merge_slashes = False
    app.url_map.converters["collection"] = common.CollectionConverter
    app.url_map.converters["data_id"] = common.DataIdConverter

    # Order of the request hooks: the request id first (every answer carries it), then the
    # timing, the real client behind the proxy, and the rate limit; CORS headers go on every answer.
    requestid.init_app(app)
    metrics.init_app(app)
    clientaddr.init_app(app)
    ratelimit.init_app(app)
    # Who is acting (issue 31): every request's token and role (app/auth/) before any route runs (and
    # before the lock check the locks family adds, app/locks/); every write's audit record after it.
    auth.init_app(app)
    audit.init_app(app)
    cors.init_app(app)
    errors.init_app(app)
    rosclient.init_app(app)
    families = family.discover()
    family.offer(app, families)   # what the families offer every mode (core/resources.py's Relayed)
    # the fleet over Zenoh (issue 34, app/fleet/): a mode of the gateway, not a family
    from . import fleet

    if fleet.init_app(app):  # the fleet gateway: its own routes, no ROS worker
        return app
    app.register_blueprint(root.bp)
    app.register_blueprint(discovery.bp)
    family.plug(app, families)   # the resource families, each by its FAMILY.init_app
    app.register_blueprint(unimplemented.bp)  # medkit's routes not served here: 501
    app.register_blueprint(ui.bp)  # the dashboard at /ui/ (app/ui/)
    if cfg.debug_commands:  # test and bench routes; never in production
        from .core import debug

        debug.init_app(app)
    return app
