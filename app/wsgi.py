"""The Flask application factory; gunicorn loads ``app.wsgi:create_app()``.

Nothing happens at import time.  ``create_app`` runs in each HTTP worker
after gunicorn forked it; the ROS-worker client it sets up opens its ZeroMQ
context only on first use (``app/core/rosclient.py``).  Settings come from
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

from . import ratelimit
from .core import clientaddr, cors, errors, metrics, requestid, rosclient
from .subscriptions import hub as streams


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

    from .core import common, discovery, root, ui, unimplemented
    from .data import routes as data
    from .subscriptions import routes as subscriptions

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
    cors.init_app(app)
    errors.init_app(app)
    rosclient.init_app(app)
    streams.init_app(app)
    app.register_blueprint(root.bp)
    app.register_blueprint(discovery.bp)
    app.register_blueprint(data.bp)
    app.register_blueprint(subscriptions.bp)
    from .faults import routes as faults  # faults: /diagnostics as SOVD faults

    app.register_blueprint(faults.bp)
    from .operations import status  # GET .../status: ready or notReady (lifecycle)

    app.register_blueprint(status.bp)
    app.register_blueprint(unimplemented.bp)  # medkit's routes not served here: 501
    app.register_blueprint(ui.bp)  # the dashboard at /ui/ (app/ui/)
    from .operations import routes as operations  # operations: services and actions
    app.register_blueprint(operations.bp)
    # configurations: the nodes' ROS 2 parameters (app/configurations/routes.py)
    from .configurations import routes as configurations
    app.register_blueprint(configurations.bp)
    from .logs import routes as logs  # logs (issue 22)
    app.register_blueprint(logs.bp)
    # Triggers (app/triggers/routes.py, their streams app/triggers/hub.py).
    from .triggers import hub as triggerstreams
    from .triggers import routes as triggers

    triggerstreams.init_app(app)
    app.register_blueprint(triggers.bp)
    if cfg.debug_commands:  # test and bench routes; never in production
        from .core import debug

        debug.init_app(app)
    return app
