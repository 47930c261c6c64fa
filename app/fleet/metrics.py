"""``/metrics``: the fleet link's counters (``ipc/counters.py``'s section ``fleet``) and, on the fleet
gateway, its per-robot series (``fleet_robots``: label ``robot``, as many as ``fleet_max_robots`` at
most, a robot's series gone when it is forgotten), asked once per scrape on the link's control
socket.  ``sovd_fleet_link_up`` is 0, and nothing else of it is exported, while it does not answer.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from ipc import counters

from ..core.metrics import number
from .link import FleetLink

FIELDS = tuple(c for c in counters.FLEET_COUNTERS if c.section == "fleet" and c.metric)
PER_ROBOT = tuple(c for c in counters.FLEET_COUNTERS if c.section == "fleet_robots")


class FleetCollector:
    def __init__(self, link: FleetLink, timeout: float):
        self.link = link
        self.timeout = timeout

    def collect(self) -> Iterator[Any]:
        from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

        alive, stats = self.link.stats(self.timeout)
        yield GaugeMetricFamily("sovd_fleet_link_up", "1 when the fleet link answered this scrape's stats "
                                "request in time, else 0 (its other metrics are then left out)",
                                value=1.0 if alive else 0.0)
        if not alive or not isinstance(stats, dict):
            return
        fleet = stats.get("fleet") if isinstance(stats.get("fleet"), dict) else {}
        for c in FIELDS:
            value = number(fleet.get(c.name))
            if value is not None:
                family = CounterMetricFamily if c.kind == counters.COUNTER else GaugeMetricFamily
                yield family(c.metric, c.help, value=value * c.scale)
        robots = stats.get("fleet_robots") if isinstance(stats.get("fleet_robots"), dict) else {}
        for c in PER_ROBOT:
            values = robots.get(c.name) if isinstance(robots.get(c.name), dict) else {}
            family = (GaugeMetricFamily if c.kind == counters.GAUGES_BY else CounterMetricFamily)(
                c.metric, c.help, labels=[c.label])
            for robot, value in sorted(values.items()):
                if number(value) is not None:
                    family.add_metric([str(robot)], number(value) * c.scale)
            yield family
