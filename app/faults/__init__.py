"""The faults family: the robot's ``/diagnostics`` as SOVD faults (medkit's fault handlers).

- ``routes.py``: ``/faults``, ``/faults/stream``, ``{entity}/faults`` and ``…/faults/{code}``;
- ``hub.py``: the fault stream's hub (``app/sse/``);
- ``resources.py``: the faults as triggers observe them;
- ``spec.py``: its part of the OpenAPI document.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from ..core.family import Family, Health
from ..core.metrics import number
from ..core.resources import Relayed, relayed
from . import hub, resources, routes, spec

HEALTH_KEYS = ("active", "confirmed", "store_size", "max_faults", "refused", "active_by_severity",
               "store_enabled", "store_writes", "store_write_errors", "store_pending", "last_write_error",
               "moved_aside", "diagnostics_arrays", "left_by_absent_nodes", "absent_nodes")


def health(stats: dict[str, Any] | None, cfg: Any) -> dict[str, Any]:
    """/health's x-medkit-faults: the fault manager's counters as the ROS worker last sent them (zeros
    before its first answer)."""
    part = stats.get("faults") if isinstance(stats, dict) else None
    section: dict[str, Any] = {"active": 0, "confirmed": 0, "store_size": 0, "max_faults": cfg.max_faults,
                               "last_write_error": "", "left_by_absent_nodes": 0, "absent_nodes": []}
    if isinstance(part, dict):
        section.update({k: part[k] for k in HEALTH_KEYS if k in part})
    return section


def metrics(stats: dict[str, Any]) -> Iterator[Any]:
    """``sovd_faults_active{severity}`` and the fault store's counters, from the ROS worker's ``stats``."""
    from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

    part = stats.get("faults")
    if not isinstance(part, dict):
        return
    by = part.get("active_by_severity")
    family = GaugeMetricFamily("sovd_faults_active", "Active faults (PREFAILED, CONFIRMED, PREPASSED), by severity",
                               labels=["severity"])
    for label, value in sorted(by.items() if isinstance(by, dict) else []):
        if number(value) is not None:
            family.add_metric([str(label)], number(value))
    yield family
    for key, name, kind, text in (
            ("confirmed", "sovd_faults_confirmed", GaugeMetricFamily, "Confirmed faults"),
            ("store_size", "sovd_faults_stored", GaugeMetricFamily, "Faults kept in the fault store"),
            ("store_write_errors", "sovd_fault_store_write_errors", CounterMetricFamily,
             "Failed writes of the fault store"),
            ("refused", "sovd_faults_refused", CounterMetricFamily, "New faults not recorded at max_faults")):
        if number(part.get(key)) is not None:
            yield kind(name, text, value=number(part[key]))


def setup(app: Any) -> None:
    hub.setup(app)
    resources.setup(app)


def offer(app: Any) -> None:
    """The fleet gateway serves the robots' faults with these rules (``app/core/resources.py``)."""
    relayed(app, Relayed("faults", routes.status_filter, hub.register, hub.response))


FAMILY = Family(
    name="faults",
    blueprints=(routes.bp,),
    spec=spec.SPEC,
    health=(Health("x-medkit-faults", health, spec.HEALTH_SCHEMA, required=True),),
    capabilities=lambda cfg: {"faults": True,
                              "fault_clear": bool(cfg.allow_fault_clear)},  # DELETE …/faults (the dashboard's Clear)
    metrics=metrics,
    setup=setup,
    offer=offer,
)
