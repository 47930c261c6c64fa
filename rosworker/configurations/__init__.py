"""The configurations family: the nodes' ROS 2 parameters (SOVD configurations).

- ``clients.py``: the driving of the operations on the nodes (deadlines, the line for a client set,
  the negative cache);
- ``pool.py``: the pooled parameter clients (one set of four per node);
- ``defaults.py``: the record of each node's defaults per start, kept by ``/parameter_events``;
- ``commands.py``: ``param_list``, ``param_get``, ``param_set``, ``param_reset``, ``param_reset_all``;
- ``values.py``: parameter values <-> JSON;
- ``feed.py``: the ``parameter`` sampler (cyclic subscriptions on a parameter).
"""

from __future__ import annotations

from ..core.family import Core, Family
from .clients import ParameterClients
from .commands import ParameterCommands
from .defaults import Defaults
from .feed import ParameterFeed


class Configurations(Family):
    name = "configurations"

    def start(self, core: Core) -> None:
        cfg = core.cfg
        defaults = Defaults(core.node, core.stats)
        self.clients = clients = ParameterClients(
            core.node, core.stats, defaults, timeout=cfg.parameter_service_timeout,
            negative_cache_s=cfg.parameter_negative_cache_s, max_clients=cfg.max_parameter_clients,
            idle_s=cfg.parameter_client_idle_s)
        core.executor.add_poller("parameter clients", clients.waitables, clients.poll, clients.due)
        core.every(min(cfg.idle_sweep_tick, 1.0), clients.sweep_idle)
        commands = ParameterCommands(clients, defaults)
        core.samplers.register("parameter", ParameterFeed(core, clients, defaults, commands))
        self.commands = commands.handlers()

    def shutdown(self) -> None:
        # The operations in flight are answered "shutdown", not left to their callers' deadline.
        self.clients.shutdown()


FAMILY = Configurations()
