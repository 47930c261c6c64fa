"""SOVD locks on the HTTP side: their routes (``routes.py``) and the lock check of every write
(``check.py``).  The locks themselves are the ROS worker's (``rosworker/locks/``).

:func:`setup` registers the check (``FAMILY``: plugged after the role check of ``app/auth/``, which
``app/wsgi.py`` installs first): a write is first asked who sends it, then whether a lock of someone
else is in its way, then its route runs (and the route's ``allow_*`` switch says whether the robot
permits it at all).
"""

from __future__ import annotations

from typing import Any

from flask import Flask

from ipc import counters

from ..core import metrics
from ..core.family import Family, Health
from . import check, doc, routes


def setup(app: Flask) -> None:
    cfg = app.config["SOVD"]
    if cfg.locking_enabled:
        app.extensions[check.EXTENSION] = check.LockCopy(cfg.runtime_dir)
        app.before_request(check.check)


def health_section(stats: dict[str, Any] | None, settings: object) -> dict[str, Any]:
    """``/health``'s ``x-medkit-locks``: the ROS worker's lock counters and the HTTP workers' refusals."""
    section = counters.health_defaults("locks", settings)
    if stats and isinstance(stats.get("locks"), dict):
        section.update(stats["locks"])
    totals = metrics.stream_totals()
    section.update({key: totals[key] for key in section if key in totals})
    return section


FAMILY = Family(
    name="locks",
    blueprints=(routes.bp,),
    spec=doc.SPEC,
    health=(Health("x-medkit-locks", health_section, doc.HEALTH_SCHEMA),),
    capabilities=lambda cfg: {"locking": bool(cfg.locking_enabled)},
    setup=setup,
)
