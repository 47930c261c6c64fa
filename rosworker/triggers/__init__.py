"""The triggers family: SOVD condition triggers, evaluated on every change of what they observe.

- ``registry.py``: the triggers, their commands (``trig_*``) and their events;
- ``conditions.py``: medkit's conditions; ``sources.py``: the triggers of one target as one observer
  of a collection another family provides (``core/notifier.py``), and the one evaluation;
- ``store.py``: their rows in the state dir's store (and an older gateway's ``triggers.json``).

The triggers are restored once every family has started (the collections they observe provided):
all of them after a ROS worker restart, the persistent ones at a gateway's first boot.
"""

from __future__ import annotations

import os

from ..core.family import Core, Family
from .registry import TriggerRegistry
from .store import LEGACY_FILE, TriggerStore


class Triggers(Family):
    name = "triggers"

    def start(self, core: Core) -> None:
        cfg = core.cfg
        # where an older gateway kept them
        legacy = os.path.join((os.environ.get("STATE_DIRECTORY") or "").split(":")[0] or cfg.runtime_dir,
                              LEGACY_FILE)
        self.registry = registry = TriggerRegistry(
            core.executor, core.stats, core.notifier, core.events.send, TriggerStore(core.store, legacy),
            max_triggers=cfg.max_triggers, max_per_client=cfg.max_triggers_per_client,
            max_bytes=cfg.max_trigger_bytes)
        core.on_started(lambda: registry.restore(restart=bool(core.restart)))
        self.commands = registry.handlers

    def shutdown(self) -> None:
        # Their subscriptions destroyed (their rows are in the store).
        self.registry.close()


FAMILY = Triggers()
