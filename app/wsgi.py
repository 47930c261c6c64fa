"""The Flask application factory; gunicorn loads ``app.wsgi:create_app()``.

Nothing happens at import time.  ``create_app`` runs in each HTTP worker
after gunicorn forked it; the ROS-worker client it sets up opens its ZeroMQ
context only on first use (``app/rosclient.py``).  Settings come from
``common.settings.load()``: the supervisor hands them to gunicorn's workers as
``SOVD_*`` environment variables.

``test_config`` overrides settings by their name (``runtime_dir``,
``allow_publish``, ``sample_timeout`` ...); any other key goes into
``app.config`` (e.g. ``SOVD_HOSTNAME``, ``SOVD_GRAPH_REFRESH_S``).
"""

from __future__ import annotations

from typing import Any

from flask import Flask

from common import settings

from . import clientaddr, cors, errors, metrics, ratelimit, requestid, rosclient, streams


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

    from .routes import common, data, discovery, root, subscriptions, ui, unimplemented

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
    # Who is acting (issue 31): every request's token and role (app/auth/), then every write's
    # lock check (app/locks/), both before any route runs; every write's audit record after it.
    from . import audit, auth, locks

    auth.init_app(app)
    locks.init_app(app)
    audit.init_app(app)
    cors.init_app(app)
    errors.init_app(app)
    rosclient.init_app(app)
    streams.init_app(app)
    from . import fleet  # the fleet over Zenoh (issue 34, app/fleet/)

    if fleet.init_app(app):  # the fleet gateway: its own routes, no ROS worker
        return app
    app.register_blueprint(root.bp)
    app.register_blueprint(discovery.bp)
    app.register_blueprint(data.bp)
    app.register_blueprint(subscriptions.bp)
    from .routes import faults  # faults: /diagnostics as SOVD faults

    app.register_blueprint(faults.bp)
    from .routes import status  # GET .../status: ready or notReady (lifecycle)

    app.register_blueprint(status.bp)
    app.register_blueprint(unimplemented.bp)  # medkit's routes not served here: 501
    app.register_blueprint(ui.bp)  # the dashboard at /ui/ (app/ui/)
    from .routes import operations  # operations: services and actions
    app.register_blueprint(operations.bp)
    # configurations: the nodes' ROS 2 parameters (app/routes/configurations.py)
    from .routes import configurations
    app.register_blueprint(configurations.bp)
    from .routes import logs  # logs (issue 22)
    app.register_blueprint(logs.bp)
    # Triggers (app/routes/triggers.py, their streams app/triggerstreams.py).
    from . import triggerstreams
    from .routes import triggers

    triggerstreams.init_app(app)
    app.register_blueprint(triggers.bp)
    from . import bulk_data  # bulk data (issue 32): medkit's /bulk-data routes (app/bulk_data/)

    bulk_data.init_app(app)
    if cfg.debug_commands:  # test and bench routes; never in production
        from .routes import debug

        debug.init_app(app)
    return app
