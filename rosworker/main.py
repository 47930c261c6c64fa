"""``sovd-rosworker``: the ROS worker process, and nothing else.

Start-up: parent-death signal → settings → runtime dir → lock → rclpy → the
families → discovery settles → sockets → ROS loop (on the main thread).  The
resource families (``core/family.py``: a package each, found by ``discover``)
start in order on the ROS thread before the loop and shut down in the reverse
order after it; what they share is the ``Core``.  SIGTERM/SIGINT only record
the request; the loop then stops taking work, the families answer what waits
and release what they hold, and the worker exits 0.

The worker arms its parent-death signal first and exits (1) if the supervisor
that started it is already gone (``common/pdeathsig.py``): zmq, rclpy and what
loads them (numpy, orjson; about 0.3 s) are imported after that, so an orphaned
or misconfigured worker exits without loading them.  The runtime dir's lock:
at the first boot a holder is another gateway's worker, refused at once; a
restarted worker (``SOVD_WORKER_RESTART``) waits up to ``LOCK_WAIT`` for it
(most likely its predecessor, killed but not yet gone).

Exit codes: 0 stopped on request, 1 the supervisor is gone, 2 bad settings,
3 cannot boot (lock held, rclpy or a family failed to start).  At the first
boot the supervisor gives up on 2 or 3; after a restart they count as one more
failure under its restart limit (the cause may be passing).
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

from .core.requestlog import RequestIdFilter

EXIT_OK = 0
EXIT_ORPHANED = 1
EXIT_CONFIG = 2
EXIT_CANNOT_BOOT = 3
LOCK_WAIT = 10.0     # seconds a restarted worker waits for the runtime dir's lock
LOCK_POLL = 0.05     # ... looking every so often; one that waited this long says so
SETTLE_MIN, SETTLE_QUIET, SETTLE_MAX = 1.0, 0.5, 5.0

log = logging.getLogger("sovd.rosworker")


def parse_args(argv: list[str] | None):
    parser = argparse.ArgumentParser(prog="sovd-rosworker",
                                     description="The gateway's ROS worker (normally started by sovd-gateway).")
    config.add_arguments(parser)
    args = parser.parse_args(argv)
    return config.load(args)


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
    return Worker(cfg, restart=config.restart_attempt(os.environ)).run()


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
        # loads zmq: imported after arming (see the module's docstring)
        from ipc.server import LockHeld, RuntimeLock

        # The runtime dir's lock: at once at the first boot, within LOCK_WAIT after a restart.
        lock = RuntimeLock(self.cfg.runtime_dir)
        wait = LOCK_WAIT if self.restart else 0.0
        try:
            waited = lock.acquire(wait, waiting=lambda exc: log.warning(
                "%s; restart %d: waiting up to %g s for it to exit", exc, self.restart, wait))
        except LockHeld as exc:
            log.error("%s", exc)
            print(f"sovd-rosworker: {exc}", file=sys.stderr)
            return EXIT_CANNOT_BOOT
        if waited >= LOCK_POLL:
            log.info("took the runtime dir's lock after %.1f s", waited)
        signal.signal(signal.SIGTERM, self._on_signal)
        signal.signal(signal.SIGINT, self._on_signal)
        try:
            return self._serve()
        finally:
            lock.release()

    def _serve(self) -> int:
        # zmq, rclpy, numpy and orjson: imported after arming (see the module's docstring).
        import rclpy
        import zmq

        from common.process import package_version
        from ipc.server import ControlServer

        from .core.executor import RosExecutor
        from .core.family import Core, discover
        from .core.graph import settle
        from .core.node import GatewayNode
        from .core.stats import Stats

        cfg = self.cfg
        try:
            context = rclpy.Context()
            rclpy.init(context=context, signal_handler_options=rclpy.SignalHandlerOptions.NO)
            node = GatewayNode(f"{cfg.gateway_name}_sub", context=context, start_parameter_services=False,
                        enable_rosout=False)
        except Exception as exc:
            log.error("rclpy could not start: %s", exc)
            return EXIT_CANNOT_BOOT
        stats = Stats(pool_cap=cfg.max_pool_size, cold_wait_cap=cfg.cold_wait_cap,
                      watchdog_threshold_ms=cfg.watchdog_threshold)
        zctx = zmq.Context()
        control = ControlServer(zctx, cfg.runtime_dir, stats, {
            "version": package_version(), "node": node.get_fully_qualified_name(),
            "started_at": time.time_ns(), "domain_id": context.get_domain_id(),
        })
        executor = RosExecutor(zctx, cfg.runtime_dir, stats, cfg.max_queue_depth, stop_when=self._signalled)
        node.releasing = executor.release
        # A signal writes to the executor's wake-up pipe, so the loop wakes up and sees it at once.
        signal.set_wakeup_fd(executor.wakeup_fd, warn_on_full_buffer=False)
        core = Core(cfg, node, zctx, executor, stats, restart=self.restart)
        families = discover()
        started = []
        try:
            core.open()
            handlers = dict(core.commands)
            for family in families:   # in order; shut down in the reverse order
                family.start(core)
                started.append(family)
                handlers.update(family.commands)
            executor.serve(handlers)
            executor.use_waiter(context)
            # Discovery settles before the sockets are bound (core/graph.py: what it waits for).
            settle(node, set(core.restart_state.loaded("nodes")), SETTLE_MIN if self.restart else 0.0,
                   SETTLE_QUIET, SETTLE_MAX, stop=self._signalled)
            core.started()
            core.bind()
            control.start()
        except Exception:
            log.exception("the ROS worker cannot serve (runtime dir %s)", cfg.runtime_dir)
            core.shutdown(started)
            self._close(core, control, node, context, zctx)
            return EXIT_CANNOT_BOOT
        log.info("ROS worker ready: node %s, domain %s, socket %s, families %s", node.get_fully_qualified_name(),
                 context.get_domain_id(), cfg.runtime_dir, ", ".join(f.name for f in families))
        try:
            executor.run()
            # Stop taking work, answer what waits, release everything, in the reverse order of the start.
            core.closing()
            core.shutdown(started)
            executor.linger()
            core.close()   # the store last: what the drained commands changed is written too
        finally:
            self._close(core, control, node, context, zctx)
        log.info("ROS worker stopped (signal %s)", self._signal)
        return EXIT_OK

    @staticmethod
    def _close(core, control, node, context, zctx) -> None:
        core.events.close()
        signal.set_wakeup_fd(-1)  # before the executor closes the pipe
        core.executor.close()
        control.finish()
        node.destroy_node()
        context.try_shutdown()
        zctx.destroy(linger=0)


if __name__ == "__main__":
    sys.exit(main())
