"""``sovd-gateway``: the whole service (supervisor → ROS worker + gunicorn).

    sovd-gateway [--bind HOST:PORT] [--runtime-dir DIR] [--workers N] [--allow-publish]
                 [--sample-timeout S] [--config FILE] [--log-level L] [--<any setting> VALUE]

Every setting of ``common.settings`` is a flag (and a ``SOVD_*`` variable, and a key
of the TOML config file); flags win.  Exit codes: 0 stopped on request,
1 failed at run time (e.g. the ROS worker kept dying), 2 bad settings or
usage, 3 cannot boot (another gateway on the runtime dir, the ROS worker or
the HTTP app cannot start).
"""

from __future__ import annotations

import argparse
import logging
import sys

from common import settings as config
from common.process import package_version

EXIT_USAGE = 2


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sovd-gateway",
        description="SOVD REST gateway for ROS 2: starts the ROS worker and the HTTP server, "
                    "restarts the ROS worker when it dies, speaks systemd's notify protocol.",
        epilog="Every option can also be set as SOVD_<NAME> in the environment or as a key "
               "of the TOML file given with --config; options win over both.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    config.add_arguments(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        cfg = config.load(args)
        config.ensure_runtime_dir(cfg.runtime_dir)
    except config.ConfigError as exc:
        print(f"sovd-gateway: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as exc:
        print(f"sovd-gateway: error: runtime_dir {exc.filename or ''}: {exc.strerror}", file=sys.stderr)
        return EXIT_USAGE
    logging.basicConfig(
        level=cfg.log_level.upper(), stream=sys.stderr,
        format="%(asctime)s sovd-gateway[%(process)d] %(levelname)s: %(message)s",
    )
    for note in cfg.ignored:
        logging.getLogger("sovd.config").warning("%s", note)
    from .supervisor import Supervisor  # imports zmq: only once the settings are good

    return Supervisor(cfg).run()


if __name__ == "__main__":
    sys.exit(main())
