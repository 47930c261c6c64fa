"""The fleet on the HTTP side (issue 34; ``docs/fleet.md``): a mode of the gateway, not a family; ``init_app(app)``.

- Every gateway: a request its robot's fleet link makes (marked, ``ipc/fleet.py``) needs a valid
  identity, a read included (``robotside.py``).
- ``fleet_link`` or ``fleet_aggregate``: the link's client (``link.py``), its ``/metrics``
  (``metrics.py``) and, on a robot, its section of ``/health`` (``x-medkit-fleet``).
- ``fleet_aggregate``: the fleet gateway's routes (``routes.py``) and the dashboard, in place of the
  ROS worker's; :func:`init_app` then returns True and ``app/wsgi.py`` registers nothing else.
"""

from __future__ import annotations

from flask import Flask

from . import link, robotside


def init_app(app: Flask) -> bool:
    """Plug the fleet in; True when this gateway is the fleet gateway (its routes are the only ones)."""
    from ..core.metrics import COLLECTORS
    from ..core.root import HEALTH_SECTIONS

    cfg = app.config["SOVD"]
    robotside.init_app(app)
    if not (cfg.fleet_link or cfg.fleet_aggregate):
        return False
    link.init_app(app)
    from .metrics import FleetCollector

    app.extensions.setdefault(COLLECTORS, []).append(
        lambda: FleetCollector(link.get(), min(link.STATS_TIMEOUT_S, cfg.ipc_timeout)))
    if not cfg.fleet_aggregate:
        from .routes import fleet_section

        app.extensions.setdefault(HEALTH_SECTIONS, {})["x-medkit-fleet"] = lambda: fleet_section(link.get().stats()[1])
        return False
    from ..core import ui
    from . import routes, stream

    stream.setup(app)   # its merged fault stream (the faults family's hub on the link's channel)
    app.register_blueprint(routes.bp)
    app.register_blueprint(routes.robot_bp)   # /fleet/<fleet_id>/...: one robot, and the dashboard on it
    app.register_blueprint(ui.bp)
    return True
