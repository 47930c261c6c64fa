"""The subscriptions family: SOVD cyclic subscriptions, kept by the ROS worker for every HTTP worker.

- ``registry.py``: the subscriptions (caps, expiry, updates, control events); each is framed by the
  sampler of its kind (``core/samplers.py``: the data family's topics, the operations' goals, the
  configurations' parameters), so this family knows none of them;
- ``commands.py``: ``sub_create``, ``sub_list``, ``sub_get``, ``sub_update``, ``sub_delete``.

The subscriptions are in the restart state (``subscriptions``, their JSON records): restored once
every family has started (their samplers registered), the expired ones dropped.
"""

from __future__ import annotations

from ..core.family import Core, Family
from . import commands
from .registry import StreamRegistry


class Subscriptions(Family):
    name = "subscriptions"

    def start(self, core: Core) -> None:
        cfg = core.cfg
        self.registry = registry = StreamRegistry(
            core.executor, core.events, core.samplers, core.stats, max_subscriptions=cfg.max_subscriptions,
            max_per_client=cfg.max_subscriptions_per_client, max_duration=cfg.max_stream_duration,
            save=core.restart_state.save)
        core.restart_state.part("subscriptions", registry.records, records=True, version=lambda: registry.version)
        saved = core.restart_state.loaded("subscriptions", records=True)
        core.on_started(lambda: registry.restore(saved))
        self.commands = commands.handlers(registry)


FAMILY = Subscriptions()
