"""``sovd-rosworker``: the ROS worker process.

Start-up order: settings → runtime dir → lock → rclpy → IPC thread → ROS loop
(on the main thread).  SIGTERM/SIGINT only record the request; the loop then
stops taking work, wakes every waiter, drains what is queued, destroys every
subscription and publisher and exits 0.

Before anything else the worker arms its parent-death signal and exits (1)
if the supervisor that started it is already gone (``common/pdeathsig.py``).
So the module imports only light modules at its top: zmq, rclpy and the
modules that load them (numpy, orjson; about 0.3 s) are imported inside
:class:`Worker`, after the death signal is armed and the settings are read,
and an orphaned or misconfigured worker exits without loading them
(``tests/common/test_pdeathsig.py`` checks it).

Wiring: :meth:`Worker._serve` builds every piece and passes each its
collaborators and callbacks through its constructor; the executor, which the
pieces need first (its timers), gets the command handlers and the pool's cold
entries through :meth:`RosExecutor.serve` and :meth:`RosExecutor.watch_cold`,
called there only.

The runtime dir's lock: at the first boot a holder is another gateway's
worker, and the worker refuses at once.  A restarted worker (the supervisor
sets ``SOVD_WORKER_RESTART``) waits up to ``LOCK_WAIT`` for it: the holder is
most likely its predecessor, killed but not yet gone.

Exit codes: 0 stopped on request, 1 the supervisor is gone, 2 bad settings,
3 cannot boot (lock held by another worker, rclpy failed to start).  At the
first boot the supervisor gives up on 2 or 3; after a restart they count as
one more failure under its restart limit (the cause may be passing).
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import time

from common import pdeathsig
from common import settings as config
from common.process import package_version
from ipc.errors import IpcError

from .core.graph import Endpoints, GraphMonitor, node_names
from .core.requestlog import RequestIdFilter
from .core.state import RestartState
from .core.stats import Stats

EXIT_OK = 0
EXIT_ORPHANED = 1
EXIT_CONFIG = 2
EXIT_CANNOT_BOOT = 3
LOCK_WAIT = 10.0     # seconds a restarted worker waits for the runtime dir's lock
LOCK_POLL = 0.05
STATE_SAVE_EVERY = 0.25  # seconds; only written when it changed
OPERATIONS_CHECK_EVERY = 1.0  # seconds between the operations' graph checks and sweeps
STATE_FLUSH_WAIT = 2.0   # seconds the restart state's writer gets to finish at shutdown
REWARM_FOR = 30.0    # seconds to keep trying to re-subscribe topics pooled before a restart
REWARM_RETRY = 0.25
# Discovery settles before the socket is bound: at least SETTLE_MIN after a restart, until
# the graph has not changed for SETTLE_QUIET, at most SETTLE_MAX seconds.
SETTLE_MIN, SETTLE_QUIET, SETTLE_MAX = 1.0, 0.5, 5.0

log = logging.getLogger("sovd.rosworker")


def parse_args(argv: list[str] | None):
    parser = argparse.ArgumentParser(prog="sovd-rosworker",
                                     description="The gateway's ROS worker (normally started by sovd-gateway).")
    config.add_arguments(parser)
    args = parser.parse_args(argv)
    return config.load(args)


def restart_attempt(environ=os.environ) -> int:
    """Which restart this worker is (0: the first boot), as the supervisor said."""
    try:
        return max(0, int(environ.get(config.RESTART_ENV, "0")))
    except ValueError:
        return 0


def main(argv: list[str] | None = None) -> int:
    if not pdeathsig.arm():
        print("sovd-rosworker: the supervisor that started it is gone; not starting", file=sys.stderr)
        return EXIT_ORPHANED
    try:
        cfg = parse_args(argv)
        config.ensure_runtime_dir(cfg.runtime_dir)
    except config.ConfigError as exc:
        print(f"sovd-rosworker: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    logging.basicConfig(level=cfg.log_level.upper(), stream=sys.stderr,
                        format="%(asctime)s rosworker[%(process)d] %(levelname)s %(name)s: "
                               "%(message)s%(request_tag)s")
    for handler in logging.getLogger().handlers:
        handler.addFilter(RequestIdFilter())  # " [request <id>]" on lines of an HTTP request's command
    return Worker(cfg, restart=restart_attempt()).run()


class Worker:
    def __init__(self, cfg, restart: int = 0):
        self.cfg = cfg
        self.restart = restart
        self._signal = None

    def _on_signal(self, signum, _frame) -> None:
        # Only record: the ROS loop wakes up (signal.set_wakeup_fd, see _serve) and stops.
        self._signal = signum

    def _signalled(self) -> bool:
        return self._signal is not None

    def run(self) -> int:
        from ipc.server import RuntimeLock  # loads zmq: imported after arming (module docstring)

        lock = RuntimeLock(self.cfg.runtime_dir)
        if not self._take_lock(lock):
            return EXIT_CANNOT_BOOT
        signal.signal(signal.SIGTERM, self._on_signal)
        signal.signal(signal.SIGINT, self._on_signal)
        try:
            return self._serve()
        finally:
            lock.release()

    def _take_lock(self, lock) -> bool:
        """The runtime dir's lock: at once at the first boot, within LOCK_WAIT after a restart."""
        from ipc.server import LockHeld  # loads zmq: imported after arming (module docstring)

        wait = LOCK_WAIT if self.restart else 0.0
        started = time.monotonic()
        waiting = False
        while True:
            try:
                lock.acquire()
            except LockHeld as exc:
                waited = time.monotonic() - started
                if waited >= wait:
                    text = f"{exc} (waited {waited:.1f} s)" if wait else str(exc)
                    log.error("%s", text)
                    print(f"sovd-rosworker: {text}", file=sys.stderr)
                    return False
                if not waiting:
                    waiting = True
                    log.warning("%s; restart %d: waiting up to %g s for it to exit", exc, self.restart, wait)
                time.sleep(min(LOCK_POLL, wait - waited))
                continue
            if waiting:
                log.info("took the runtime dir's lock after %.1f s", time.monotonic() - started)
            return True

    def _serve(self) -> int:
        # zmq, rclpy, numpy and orjson: imported after arming (see the module's docstring).
        import rclpy
        import zmq
        from rclpy.node import Node

        from ipc.server import ControlServer

        from .core.executor import RosExecutor
        from .data.commands import Commands
        from .data.pool import TopicPool
        from .data.publishers import PublisherPool
        from .subscriptions.registry import StreamRegistry

        cfg = self.cfg
        try:
            context = rclpy.Context()
            rclpy.init(context=context, signal_handler_options=rclpy.SignalHandlerOptions.NO)
            node = Node(f"{cfg.gateway_name}_sub", context=context, start_parameter_services=False,
                        enable_rosout=False)
        except Exception as exc:
            log.error("rclpy could not start: %s", exc)
            return EXIT_CANNOT_BOOT

        # The pieces, each given what it uses.  The executor comes first: everything else
        # sets its timers on it.
        stats = Stats(pool_cap=cfg.max_pool_size, cold_wait_cap=cfg.cold_wait_cap,
                      watchdog_threshold_ms=cfg.watchdog_threshold)
        zctx = zmq.Context()
        control = ControlServer(zctx, cfg.runtime_dir, stats, {
            "version": package_version(), "node": node.get_fully_qualified_name(),
            "started_at": time.time_ns(), "domain_id": context.get_domain_id(),
        })
        executor = RosExecutor(zctx, cfg.runtime_dir, stats, cfg.max_queue_depth,
                               stop_when=self._signalled)
        # A signal writes to the executor's wake-up pipe, so the loop wakes up and sees it at once.
        signal.set_wakeup_fd(executor.wakeup_fd, warn_on_full_buffer=False)
        endpoints = Endpoints(node)
        pool = TopicPool(node, executor, stats, max_pool_size=cfg.max_pool_size,
                         cold_wait_cap=cfg.cold_wait_cap, idle_safety_net=cfg.idle_safety_net,
                         max_pool_bytes=cfg.max_pool_bytes, endpoints=endpoints)
        state = RestartState(cfg.runtime_dir, post=executor.post)
        if not self.restart:
            # The restart state is for a worker that died, not for a new gateway: a clean
            # (re)start begins with no subscriptions (and nothing to re-warm).
            state.discard()
        graph = GraphMonitor(node, pool, stats)
        publishers = PublisherPool(node, executor, stats, pool, endpoints, cfg.max_publishers,
                                   cfg.idle_safety_net, cfg.publish_match_wait)

        def save_state(then=None) -> None:
            # Hands the state to the writer thread; no serialisation of the registry here.
            # ``streams`` is the registry made below: it calls this only after a change.
            state.submit(pool.restart_topics(), graph.nodes, streams.version, streams.records, then)

        streams = StreamRegistry(zctx, cfg.runtime_dir, executor, pool, stats,
                                 max_subscriptions=cfg.max_subscriptions,
                                 max_per_client=cfg.max_subscriptions_per_client, graph=graph,
                                 max_duration=cfg.max_stream_duration, sample_timeout=cfg.sample_timeout,
                                 save=save_state)
        commands = Commands(pool, graph, publishers, streams, sample_timeout=cfg.sample_timeout,
                            debug=cfg.debug_commands)
        # Operations (services and actions): their commands, upkeep timers and restart record.
        from .operations.commands import Operations
        operations = Operations(node, executor, stats, max_clients=cfg.max_operation_clients,
                                idle=cfg.idle_safety_net, call_timeout=cfg.service_call_timeout,
                                max_goals=cfg.max_goals_per_action, retention=cfg.goal_retention,
                                restore=self.restart)
        commands.handlers.update(operations.handlers)
        operations.repeat(OPERATIONS_CHECK_EVERY)
        # lifecycle status: managed nodes' get_state, through the operations' service clients
        from .operations.lifecycle import LifecycleStates
        commands.handlers.update(LifecycleStates(node, operations.services).handlers)
        # faults: /diagnostics as SOVD faults, kept in the state dir's fault store (rosworker/faults/manager.py)
        from .core.store import FaultStore
        from .faults.manager import FaultManager
        from .faults.manager import handlers as fault_handlers
        # the state dir's SQLite store: the faults and the triggers (rosworker/core/store.py)
        store = FaultStore(cfg.state_dir or config.default_state_dir(os.environ))
        faults = FaultManager(node, executor, pool, stats, store, graph=graph,
                              endpoints=endpoints, send=streams.send,
                              confirm_count=cfg.fault_confirm_count, confirm_s=cfg.fault_confirm_s,
                              heal_count=cfg.fault_heal_count, stale_s=cfg.fault_stale_s,
                              max_faults=cfg.max_faults, codes=cfg.fault_codes,
                              snapshot_topics=cfg.fault_snapshot_topics)
        faults.load()
        faults.start()
        # faults left in the store by nodes that are not on the graph: said in the log and /health
        from .faults.left import LeftFaults, check_delay
        LeftFaults(faults, graph, stats, executor, check_after=check_delay(cfg.fault_stale_s)).start()
        commands.handlers.update(fault_handlers(faults))
        # What the executor's loop runs: the queued commands, and a look at each topic that
        # callers wait on (its first message) on every round.
        # logs (issue 22): /rosout's ring buffers and their commands (rosworker/logs/book.py)
        from .logs.book import LogBook
        logbook = LogBook(node, executor, stats, buffer_size=cfg.log_buffer_size, max_bytes=cfg.log_max_bytes,
                          max_nodes=cfg.log_max_nodes)
        executor.guarded("subscribing to /rosout", logbook.start)
        commands.handlers.update(logbook.handlers)
        # Triggers (rosworker/triggers/registry.py): their commands, their rows in the store, restored before discovery.
        from .triggers.registry import LEGACY_FILE, TriggerRegistry, events_sender
        legacy = os.path.join((os.environ.get("STATE_DIRECTORY") or "").split(":")[0] or cfg.runtime_dir,
                              LEGACY_FILE)  # where an older gateway kept them
        triggers = TriggerRegistry(node, executor, stats, endpoints, events_sender(streams), store,
                                   max_triggers=cfg.max_triggers, max_per_client=cfg.max_triggers_per_client,
                                   max_bytes=cfg.max_trigger_bytes, legacy_path=legacy)
        triggers.sources["faults"].bind(faults)  # faults and logs triggers (rosworker/triggers/sources.py)
        triggers.sources["logs"].bind(logbook)
        triggers.restore(restart=bool(self.restart))
        commands.handlers.update(triggers.handlers)
        executor.serve(commands.handlers)
        executor.watch_cold(pool.cold_entries, pool.on_ready)

        def every(seconds: float, fn):
            def tick():
                executor.call_later(seconds, tick)
                fn()
            executor.call_later(seconds, tick)

        rewarm, known_nodes, subscriptions = state.load()
        self._settle_discovery(node, set(known_nodes))
        executor.guarded("the first graph check", graph.tick)
        every(cfg.graph_poll_tick / 1000, graph.tick)
        if cfg.idle_safety_net:
            every(cfg.idle_sweep_tick, pool.sweep_idle)
            every(cfg.idle_sweep_tick, publishers.sweep_idle)
        every(STATE_SAVE_EVERY, save_state)
        # configurations: the nodes' ROS 2 parameters through pooled parameter clients (rosworker/configurations/clients.py)
        from .configurations.clients import ParameterClients
        parameters = ParameterClients(node, stats, timeout=cfg.parameter_service_timeout,
                                      negative_cache_s=cfg.parameter_negative_cache_s,
                                      max_clients=cfg.max_parameter_clients, idle_s=cfg.parameter_client_idle_s)
        executor.serve({**commands.handlers, **parameters.handlers()})
        executor.add_poller("parameter clients", parameters.active, parameters.poll)
        every(min(cfg.idle_sweep_tick, 1.0), parameters.sweep_idle)
        # feeds: cyclic subscriptions on executions and parameters (rosworker/configurations/feed.py)
        from .configurations.feed import Feeds
        streams.feeds = Feeds(streams, executor, operations.actions, parameters)
        if rewarm:
            self._rewarm(executor, pool, rewarm, time.monotonic() + REWARM_FOR)
        streams.restore(subscriptions)
        state.start()

        try:
            executor.bind()
            streams.bind()
            control.start()
        except Exception as exc:
            log.error("cannot serve IPC on %s: %s", cfg.runtime_dir, exc)
            signal.set_wakeup_fd(-1)  # before the executor closes the pipe
            executor.close()
            node.destroy_node()
            rclpy.try_shutdown(context=context)
            zctx.destroy(linger=0)
            return EXIT_CANNOT_BOOT
        log.info("ROS worker ready: node %s, domain %s, socket %s", node.get_fully_qualified_name(),
                 context.get_domain_id(), cfg.runtime_dir)
        try:
            executor.run()
            # Stop taking work, wake every waiter, answer what is queued, release everything.
            executor.closing = True
            pool.closing = True
            # Write what is pending and answer the commands that waited for it; from here on
            # a change (a queued command drained below) is written on this thread.
            state.close(STATE_FLUSH_WAIT)
            triggers.close()  # triggers: their subscriptions destroyed (their rows are in the store)
            executor.run_posted()
            executor.guarded("the pool's shutdown", pool.shutdown)
            executor.guarded("the operations' shutdown", operations.shutdown)  # operations
            executor.guarded("the publishers' shutdown", publishers.shutdown)
            # configurations: the parameter operations in flight are answered "shutdown"
            executor.guarded("the parameters' shutdown", parameters.shutdown)
            executor.guarded("the faults' shutdown", faults.shutdown)  # faults
            executor.guarded("the logs' shutdown", logbook.shutdown)  # logs (issue 22)
            executor.linger()
            # the store last: what the drained commands changed is written too
            executor.guarded("the store's shutdown", store.close, STATE_FLUSH_WAIT)
            executor.run_posted()
        finally:
            streams.close()
            signal.set_wakeup_fd(-1)  # before the executor closes the pipe
            executor.close()
            control.finish()
            node.destroy_node()
            rclpy.try_shutdown(context=context)
            zctx.destroy(linger=0)
        log.info("ROS worker stopped (signal %s)", self._signal)
        return EXIT_OK

    def _settle_discovery(self, node, expected: set[str]) -> None:
        """Wait until DDS discovery has found the running graph before answering anyone.

        A graph answered too early would tell the HTTP side that nodes which
        never left are gone (404).  Until the socket is bound, clients get 503
        ``unavailable`` with Retry-After instead, which is the truth.  Settled
        means: the nodes the previous worker knew (``expected``) are back, or
        SETTLE_MAX passed (some of them really left); and the graph has not
        changed for SETTLE_QUIET.  At the first boot nobody was told anything
        before, so only the quiet period counts (gunicorn, started next, takes
        longer than SETTLE_MIN to answer anyway).
        """
        own = (node.get_name(), node.get_namespace())
        least = SETTLE_MIN if self.restart else 0.0
        started = time.monotonic()
        last, quiet_since = None, started
        while self._signal is None:
            now = time.monotonic()
            nodes = node.get_node_names_and_namespaces()
            seen = (sorted(nodes), sorted((n, tuple(t)) for n, t in node.get_topic_names_and_types()))
            if seen != last:
                last, quiet_since = seen, now
            elapsed = now - started
            found = expected.issubset(node_names(nodes, own))
            if elapsed >= SETTLE_MAX or (found and elapsed >= least and now - quiet_since >= SETTLE_QUIET):
                break
            time.sleep(0.05)
        log.info("discovery settled after %.2f s (%d nodes)", time.monotonic() - started,
                 len(last[0]) if last else 0)

    def _rewarm(self, executor, pool, topics: list[str], until: float) -> None:
        """Subscribe again to the topics pooled before a restart, as their publishers are discovered."""
        def pooled(topic: str) -> bool:
            try:
                return pool.subscribe(topic)["status"] == "pooled"
            except IpcError as exc:
                log.info("re-subscribing %s failed: %s", topic, exc.message)
                return False

        pending = [t for t in topics if not pooled(t)]
        if len(pending) < len(topics):
            log.info("re-subscribed %d topics pooled before the restart", len(topics) - len(pending))
        if pending and time.monotonic() < until and not executor.stopping:
            executor.call_later(REWARM_RETRY, lambda: self._rewarm(executor, pool, pending, until))
        elif pending:
            log.info("gave up re-subscribing %d topics with no publishers", len(pending))


if __name__ == "__main__":
    sys.exit(main())
