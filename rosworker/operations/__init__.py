"""The operations family: the nodes' services and actions (SOVD operations), and lifecycle status.

- ``interfaces.py``: which services and actions a node offers, their types;
- ``services.py``, ``actions.py``: the pooled service and action clients, goals;
- ``goals.py``: the running goals' restart record (``operations.json``);
- ``commands.py``: ``op_list``, ``op_call``, ``op_goal``, ``op_goals``, ``op_exec``, ``op_cancel``;
- ``lifecycle.py``: ``lifecycle_state`` (a managed node's state, through its get_state service);
- ``feed.py``: the ``execution`` sampler (cyclic subscriptions on a goal).
"""

from __future__ import annotations

from ..core.family import Core, Family
from .commands import Operations
from .feed import ExecutionFeed
from .lifecycle import LifecycleStates

CHECK_EVERY = 1.0  # seconds between the clients' graph checks, idle sweeps and goal expiry


class OperationsFamily(Family):
    name = "operations"

    def start(self, core: Core) -> None:
        cfg = core.cfg
        self.operations = ops = Operations(
            core.node, core.executor, core.stats, max_clients=cfg.max_operation_clients, idle=cfg.idle_safety_net,
            call_timeout=cfg.service_call_timeout, max_goals=cfg.max_goals_per_action, retention=cfg.goal_retention,
            restore=bool(core.restart))
        core.every(CHECK_EVERY, ops.check)
        core.samplers.register("execution", ExecutionFeed(core, ops.actions))
        self.commands = {**ops.handlers, **LifecycleStates(core.node, ops.services).handlers}

    def shutdown(self) -> None:
        self.operations.shutdown()


FAMILY = OperationsFamily()
