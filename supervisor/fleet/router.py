"""``sovd-zenoh-router``: a Zenoh router in one small process, for tests and small deployments.

Eclipse's ``zenohd`` is the router to run in production (it is not on PyPI or in Debian; Eclipse
publishes it as packages and a container image).  Where it is not at hand, this is a Zenoh session
in router mode (``eclipse-zenoh``, the same library the links use), configured from the same kind
of JSON5 file (``--config``: TLS certificates, access control) with ``--listen`` endpoints applied on
top, that runs until SIGTERM or SIGINT.  It prints ``ready <zid>`` once it listens.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="sovd-zenoh-router", description=__doc__.split("\n\n")[0])
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                        help="an endpoint to listen on, e.g. tcp/0.0.0.0:7447 or tls/0.0.0.0:7447 (repeatable)")
    parser.add_argument("--config", metavar="FILE", help="a Zenoh configuration file (JSON5)")
    args = parser.parse_args(argv)
    import zenoh

    try:
        config = zenoh.Config.from_file(args.config) if args.config else zenoh.Config()
        config.insert_json5("mode", '"router"')
        if not args.config:
            config.insert_json5("scouting/multicast/enabled", "false")
        if args.listen:
            config.insert_json5("listen/endpoints", json.dumps(args.listen))
        session = zenoh.open(config)
    except Exception as exc:  # zenoh.ZError: a bad file, an endpoint in use
        print(f"sovd-zenoh-router: {str(exc).split(' at /', 1)[0]}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    print(f"ready {session.zid()}", flush=True)
    while not stop.wait(1.0):
        pass
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
