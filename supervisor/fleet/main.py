"""``sovd-fleetlink``: the fleet-link process, the only holder of a Zenoh session in the gateway.

Started by the supervisor when ``fleet_link`` (a robot) or ``fleet_aggregate`` (the fleet gateway)
is on, with the gateway's settings in its environment.  Start-up: arm the parent-death signal,
settings, runtime dir, the runtime dir's ``fleetlink.lock`` (one link per gateway), the control
socket (``ping``/``stats``, for the supervisor), the role (``robot.py`` or ``aggregator.py`` with
its events channel), the Zenoh session opened in the background until a router answers
(``session.py``), then the IPC loop on the main thread (``server.py``).  SIGTERM/SIGINT only record
the request; the loop ends, the role's declarations are undone (a robot's liveliness token goes,
so the fleet marks it away at once), and the session is closed within ``session.close``'s deadline.

Exit codes (the ROS worker's): 0 stopped on request, 1 the supervisor is gone, 2 bad settings,
3 cannot boot (another link holds the runtime dir).
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import time
from typing import Any

from common import pdeathsig
from common import settings as config
from common.process import PidfileHeld, lock_pidfile, package_version

EXIT_OK, EXIT_ORPHANED, EXIT_CONFIG, EXIT_CANNOT_BOOT = 0, 1, 2, 3
IDLE_WAIT = 2.0   # seconds a thread of the link waits when nothing happens: a robot's link costs little idle

log = logging.getLogger("sovd.fleet")


def main(argv: list[str] | None = None) -> int:
    if not pdeathsig.arm():
        print("sovd-fleetlink: the supervisor that started it is gone; not starting", file=sys.stderr)
        return EXIT_ORPHANED
    parser = argparse.ArgumentParser(prog="sovd-fleetlink",
                                     description="The gateway's fleet link (normally started by sovd-gateway).")
    config.add_arguments(parser)
    try:
        cfg = config.load(parser.parse_args(argv))
        if not (cfg.fleet_link or cfg.fleet_aggregate):
            raise config.ConfigError("neither fleet_link nor fleet_aggregate is on: the link has nothing to do")
        config.ensure_runtime_dir(cfg.runtime_dir)
    except config.ConfigError as exc:
        print(f"sovd-fleetlink: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    logging.basicConfig(level=cfg.log_level.upper(), stream=sys.stderr,
                        format="%(asctime)s fleetlink[%(process)d] %(levelname)s %(name)s: %(message)s")
    return Link(cfg).run()


class Link:
    def __init__(self, cfg: Any):
        self.cfg = cfg
        self._signal: int | None = None

    def _on_signal(self, signum, _frame) -> None:
        self._signal = signum   # only record: the IPC loop wakes (set_wakeup_fd) and stops

    def run(self) -> int:
        from ipc.fleet import LOCK_NAME

        try:
            lock = lock_pidfile(os.path.join(self.cfg.runtime_dir, LOCK_NAME))
        except PidfileHeld as exc:
            print(f"sovd-fleetlink: another fleet link (pid {exc.holder or '?'}) serves {self.cfg.runtime_dir}",
                  file=sys.stderr)
            return EXIT_CANNOT_BOOT
        wake_r, wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        signal.set_wakeup_fd(wake_w, warn_on_full_buffer=False)
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, self._on_signal)
        try:
            return self._serve(wake_r)
        finally:
            signal.set_wakeup_fd(-1)
            os.close(wake_r)
            os.close(wake_w)
            lock.close()

    def _serve(self, wake_fd: int) -> int:
        import zmq

        from ipc.fleet import CONTROL_SOCKET_NAME
        from ipc.server import ControlServer

        from . import session as zsession
        from .server import Server
        from .stats import LinkStats

        cfg = self.cfg
        zctx = zmq.Context()
        stats = LinkStats(cfg)
        role_name = "aggregator" if cfg.fleet_aggregate else "robot"
        control = ControlServer(zctx, cfg.runtime_dir, stats,
                                {"version": package_version(), "role": role_name, "fleet_id": cfg.fleet_id,
                                 "started_at": time.time()}, socket_name=CONTROL_SOCKET_NAME,
                                check_every=IDLE_WAIT)
        control.start()
        channel = None
        if cfg.fleet_aggregate:
            from .aggregator import Aggregator
            from .channel import EventChannel

            channel = EventChannel(zctx, cfg.runtime_dir)
            channel.start()
            role = Aggregator(cfg, stats, channel.send)
        else:
            from .robot import RobotLink

            role = RobotLink(cfg, stats)
        opener = zsession.Opener(lambda: zsession.config(cfg), role.attach)
        stats.session_open = lambda: opener.session is not None and not opener.session.is_closed()
        stats.session_attempts = lambda: opener.attempts
        opener.start()
        log.info("fleet link pid %d started as %s (%s), connecting to %s", os.getpid(), role_name,
                 cfg.fleet_id if not cfg.fleet_aggregate else "fleet gateway", cfg.fleet_connect or "its config")
        try:
            server = Server(zctx, cfg.runtime_dir, stats, handlers(cfg, role, opener, stats))
            server.serve(lambda: self._signal is not None, wake_fd, idle_wait=IDLE_WAIT)
        finally:
            opener.stop()
            role.close()
            zsession.close(opener.session)
            if channel is not None:
                channel.stop()
            control.finish()
            zctx.term()
        log.info("fleet link stopped")
        return EXIT_OK


def handlers(cfg: Any, role: Any, opener: Any, stats: Any) -> dict:
    """The IPC commands (``supervisor/fleet/PROTOCOL.md``) of this role."""
    from ipc.errors import IpcError

    from .server import arg

    def status(args: dict, deadline: float) -> dict:
        out = {"role": "aggregator" if cfg.fleet_aggregate else "robot", "fleet_id": cfg.fleet_id,
               "session_open": stats.session_open(), "session_error": opener.last_error}
        if cfg.fleet_aggregate:
            out.update(role.robot_status())
        return out

    if not cfg.fleet_aggregate:
        return {"fleet_status": status}

    from ipc.fleet import COLLECTIONS

    from .gather import NotAnswered

    def collection(args: dict) -> str:
        name = arg(args, "collection", str)
        if name not in COLLECTIONS:
            raise IpcError("bad-request", "collection: one of " + ", ".join(COLLECTIONS))
        return name

    def listing(args: dict, deadline: float) -> dict:
        return {"body": role.listing(collection(args))}

    def entity(args: dict, deadline: float) -> dict:
        return role.entity(collection(args), arg(args, "id", str))

    def forward(args: dict, deadline: float) -> dict:
        robot = arg(args, "robot", str)
        try:
            status_, headers, body = role.forward(
                robot, arg(args, "method", str), arg(args, "path", str), arg(args, "query", str, ""),
                arg(args, "headers", dict, {}), arg(args, "body", bytes, b""), deadline - time.monotonic())
        except NotAnswered as exc:
            what = "is not connected to the fleet" if exc.reason == "offline" else \
                f"did not answer within {exc.seconds:g} s"
            raise IpcError("not-responding", f"Robot '{robot}' {what}", {"peer": robot}) from None
        return {"status": status_, "headers": headers, "body": body}

    def fanout(args: dict, deadline: float) -> dict:
        targets = arg(args, "targets", list, None)
        if targets is not None and not all(isinstance(t, str) for t in targets):
            raise IpcError("bad-request", "targets: a list of robot names")
        return {"body": role.fanout(arg(args, "path", str), arg(args, "query", str, ""), arg(args, "headers", dict, {}),
                                    targets, deadline - time.monotonic(), arg(args, "entity_id", str, None))}

    def events(args: dict, deadline: float) -> dict:
        return {"events": role.events(arg(args, "after", int, 0))}

    return {"fleet_status": status, "fleet_list": listing, "fleet_entity": entity, "fleet_forward": forward,
            "fleet_fanout": fanout, "fleet_events": events}


if __name__ == "__main__":
    sys.exit(main())
