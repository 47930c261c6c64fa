"""How a resource family plugs into the HTTP workers: :class:`Family`.

A family (the same name as in the ROS worker: ``app/faults/`` beside
``rosworker/faults/``) is one package of ``app/`` whose ``__init__.py`` holds
``FAMILY``::

    FAMILY = Family(
        name="logs",
        blueprints=(routes.bp,),                  # its routes, under /api/v1
        spec=spec.SPEC,                           # its part of the OpenAPI document (app/openapi/)
        health=Health("x-medkit-logs", counters_section("logs")),   # its /health section
        capabilities=lambda cfg: {"logs": True},  # its entries of GET /api/v1/'s capabilities
        setup=setup,                              # anything else: a hub, a registration (resources.py)
        offer=None,                               # what every mode of the app may use (resources.py)
    )

``create_app`` (``app/wsgi.py``) finds the families (:func:`discover`: every
package of ``app/`` that holds a ``FAMILY``, in name order) and calls
``FAMILY.init_app(app)`` for each: Home Assistant's ``async_setup_entry``.
Before that, whatever the mode, :func:`offer` runs each family's ``offer(app)``:
registrations a mode that plugs no family uses (the fleet gateway serves the
robots' faults with the faults family's rules, ``resources.Relayed``).  The
root routes (``core/root.py``: ``/health``, the capabilities), the OpenAPI
document (``app/openapi/``) and the metrics (``core/metrics.py``) loop over the
families and know none by name.  A family imports no other family: it reaches
their resources through ``core/resources.py``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from flask import Blueprint, Flask

from common import families
from ipc import counters

NOT_FAMILIES = ("core", "sse", "openapi", "ui", "auth", "audit", "fleet")  # auth, audit: every request's; fleet: a mode
EXTENSION = "sovd_families"   # app.extensions: the families create_app plugged in, in order


@dataclass(frozen=True)
class Health:
    """A family's section of ``/health``: ``build(stats, cfg)`` from the ROS worker's last ``stats``
    answer (None before its first), never waiting on anything; ``schema``: its part of the
    ``HealthStatus`` schema (``openapi.build.counters_schema(section, ...)`` for a section of
    ``ipc/counters.py``; None: not described there), ``required`` puts its key in that schema's
    ``required``."""

    key: str
    build: Callable[[dict[str, Any] | None, Any], dict[str, Any]]
    schema: dict[str, Any] | None = None
    required: bool = False


def counters_section(name: str) -> Callable[[dict[str, Any] | None, Any], dict[str, Any]]:
    """The ``build`` of a /health section that is one section of the stats answer (``ipc/counters.py``):
    zeros and the settings it shows until the ROS worker first answers, then its last answer."""
    def build(stats: dict[str, Any] | None, cfg: Any) -> dict[str, Any]:
        section = counters.health_defaults(name, cfg)
        if stats and isinstance(stats.get(name), dict):
            section.update(stats[name])
        return section
    return build


@dataclass(frozen=True)
class Family:
    """A resource family of the HTTP side (see the module's docstring)."""

    name: str
    blueprints: tuple[Blueprint, ...] = ()
    spec: Any = None
    health: tuple[Health, ...] = ()
    capabilities: Callable[[Any], dict[str, bool]] = field(default=lambda cfg: {})
    metrics: Callable[[dict[str, Any]], Iterator[Any]] | None = None
    setup: Callable[[Flask], None] | None = None
    offer: Callable[[Flask], None] | None = None

    def init_app(self, app: Flask) -> None:
        """Plug the family into ``app``: its routes, and what its ``setup`` does (hubs, registrations)."""
        for blueprint in self.blueprints:
            app.register_blueprint(blueprint)
        if self.setup is not None:
            self.setup(app)


def discover(package: str = "app") -> tuple[Family, ...]:
    """Every family of ``package``, in name order (``common/families.py``)."""
    return families.discover(package, Family, NOT_FAMILIES)


def offer(app: Flask, families: tuple[Family, ...]) -> None:
    """What ``families`` offer every mode of ``app`` (``create_app``, before it picks the mode)."""
    for family in families:
        if family.offer is not None:
            family.offer(app)


def plug(app: Flask, families: tuple[Family, ...]) -> None:
    """Plug ``families`` into ``app``, in order (``create_app``)."""
    app.extensions[EXTENSION] = families
    for family in families:
        family.init_app(app)


def plugged(app: Flask) -> tuple[Family, ...]:
    """The families plugged into ``app``."""
    return app.extensions.get(EXTENSION, ())
