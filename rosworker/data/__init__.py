"""The data family: topics read (``sample``), written (``publish``), streamed and observed.

- ``pool.py``: one subscription per topic, its newest sample on demand;
- ``publishers.py``: the pooled publishers of ``PUT .../data/{topic}``;
- ``ticks.py``: the ``data`` sampler (cyclic subscriptions on topics, one frame per topic per tick);
- ``observable.py``: the ``data`` collection for observers (triggers: every message of a topic);
- ``commands.py``: ``sample``, ``subscribe``, ``evict``, ``pool``, ``publish``, ``type_info``.

The pooled topics are in the restart state (``topics``): a restarted worker subscribes them again
as their publishers are discovered, for ``REWARM_FOR`` seconds.
"""

from __future__ import annotations

import logging
import time

from ipc.errors import IpcError

from ..core.family import Core, Family
from .commands import Commands
from .observable import DataObservable
from .pool import TopicPool
from .publishers import PublisherPool
from .ticks import TopicTicks

log = logging.getLogger("sovd.rosworker.data")

REWARM_FOR = 30.0    # seconds to keep trying to re-subscribe topics pooled before a restart
REWARM_RETRY = 0.25


class Data(Family):
    name = "data"

    def start(self, core: Core) -> None:
        cfg = core.cfg
        self.core = core
        self.pool = pool = TopicPool(core.node, core.executor, core.stats, max_pool_size=cfg.max_pool_size,
                                     cold_wait_cap=cfg.cold_wait_cap, idle_safety_net=cfg.idle_safety_net,
                                     max_pool_bytes=cfg.max_pool_bytes, endpoints=core.endpoints)
        self.publishers = PublisherPool(core.node, core.executor, core.stats, pool, core.endpoints,
                                        cfg.max_publishers, cfg.idle_safety_net, cfg.publish_match_wait)
        core.graph.on_change(pool.check_graph)
        # topics another family subscribes already (bulk data's recorded ones): read through theirs
        pool.shared_subscription = core.shared_topics.get
        core.shared_topics.attach(pool)
        # A look at each topic that callers wait on (its first message) on every round of the loop.
        core.executor.watch_cold(pool.cold_entries, pool.on_ready, pool.cold_waitables)
        if cfg.idle_safety_net:
            core.every(cfg.idle_sweep_tick, pool.sweep_idle)
            core.every(cfg.idle_sweep_tick, self.publishers.sweep_idle)
        core.samplers.register("data", TopicTicks(core, pool, cfg.sample_timeout))
        core.notifier.provide("data", DataObservable(core.node, core.executor, core.endpoints, core.stats))
        core.restart_state.part("topics", pool.restart_topics)
        topics = core.restart_state.loaded("topics")
        if topics:
            core.on_started(lambda: self._rewarm(topics, time.monotonic() + REWARM_FOR))
        self.commands = Commands(pool, self.publishers, sample_timeout=cfg.sample_timeout).handlers

    def shutdown(self) -> None:
        self.pool.closing = True
        self.core.executor.guarded("the pool's shutdown", self.pool.shutdown)
        self.publishers.shutdown()

    def _rewarm(self, topics: list[str], until: float) -> None:
        """Subscribe again to the topics pooled before a restart, as their publishers are discovered."""
        def pooled(topic: str) -> bool:
            try:
                return self.pool.subscribe(topic)["status"] == "pooled"
            except IpcError as exc:
                log.info("re-subscribing %s failed: %s", topic, exc.message)
                return False

        executor = self.core.executor
        pending = [t for t in topics if not pooled(t)]
        if len(pending) < len(topics):
            log.info("re-subscribed %d topics pooled before the restart", len(topics) - len(pending))
        if pending and time.monotonic() < until and not executor.stopping:
            executor.call_later(REWARM_RETRY, lambda: self._rewarm(pending, until))
        elif pending:
            log.info("gave up re-subscribing %d topics with no publishers", len(pending))


FAMILY = Data()
