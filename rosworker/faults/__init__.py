"""The faults family: the robot's ``/diagnostics`` as SOVD faults, kept in the state dir's store.

- ``manager.py``: the faults' lifecycle from the statuses of ``/diagnostics``;
- ``events.py``: the faults' events (ids that never go backwards, kept for replay, published, observed);
- ``model.py``: statuses, codes, medkit's fault body; ``sources.py``: who reported a status;
- ``snapshots.py``: freeze frames (the data family's topics, through the core's samplers);
- ``store.py``: the faults and their events in the store; ``left.py``: faults left by absent nodes;
- ``observable.py``: the ``faults`` collection for observers (triggers);

Its extension points (``core.extend``): ``fault_confirmed`` fn(code, sources), ``fault_snapshots`` fn(code) -> list.
- ``commands.py``: ``fault_list``, ``fault_get``, ``fault_clear``, ``fault_events``.
"""

from __future__ import annotations

from ..core.family import Core, Family
from . import commands
from .left import LeftFaults, check_delay
from .manager import FaultManager
from .store import FaultTables


class Faults(Family):
    name = "faults"

    def start(self, core: Core) -> None:
        cfg = core.cfg
        self.manager = manager = FaultManager(
            core.node, core.executor, core.samplers, core.stats, FaultTables(core.store), graph=core.graph,
            endpoints=core.endpoints, send=core.events.send, confirm_count=cfg.fault_confirm_count,
            confirm_s=cfg.fault_confirm_s, heal_count=cfg.fault_heal_count, stale_s=cfg.fault_stale_s,
            max_faults=cfg.max_faults, codes=cfg.fault_codes, snapshot_topics=cfg.fault_snapshot_topics)
        manager.load()
        manager.start()
        # faults left in the store by nodes that are not on the graph: said in the log and /health
        LeftFaults(manager, core.graph, core.stats, core.executor, check_after=check_delay(cfg.fault_stale_s)).start()
        core.notifier.provide("faults", manager.observable)
        # extension points (core/family.py Core.extend): fn(code, sources) on each confirmation, and
        # fn(code) -> the fault's extra snapshots in fault_get (bulk data's recordings)
        manager.on_confirmed = core.extensions("fault_confirmed")
        manager.snapshot_sources = core.extensions("fault_snapshots")
        self.commands = commands.handlers(manager)

    def shutdown(self) -> None:
        # What is not written yet goes to the store (the core closes it after the last answers).
        self.manager.shutdown()


FAMILY = Faults()
