"""The link's Zenoh session: its configuration from the settings, and opening it against a flaky link.

The configuration is ``fleet_zenoh_config`` (a Zenoh JSON5 file: TLS certificates, access control,
timeouts) when given, with the mode (``client`` for a robot and for the fleet gateway, which both
reach the fleet through a router) and ``fleet_connect`` applied on top; without a file, multicast
scouting is off, so a link talks to the routers it was given and to nothing it happens to find.

A client session cannot open while no router answers.  :class:`Opener` tries again with a backoff
(``OPEN_RETRY`` up to ``OPEN_RETRY_MAX`` seconds) until it opens or the link stops, so a robot boots
while the cloud is out of reach and joins once it is back; once open, Zenoh reconnects by itself
and declares the link's queryables, subscribers and liveliness token again.
"""

from __future__ import annotations

import json
import logging
import threading
from typing import Any

log = logging.getLogger("sovd.fleet.session")

OPEN_RETRY = 0.5
OPEN_RETRY_MAX = 10.0


def endpoints(text: str) -> list[str]:
    return [e.strip() for e in text.split(",") if e.strip()]


def config(cfg: Any, mode: str = "client"):
    """The ``zenoh.Config`` of this link (``cfg``: the gateway's settings)."""
    import zenoh

    zc = zenoh.Config.from_file(cfg.fleet_zenoh_config) if cfg.fleet_zenoh_config else zenoh.Config()
    zc.insert_json5("mode", json.dumps(mode))
    if not cfg.fleet_zenoh_config:
        zc.insert_json5("scouting/multicast/enabled", "false")
    if endpoints(cfg.fleet_connect):
        zc.insert_json5("connect/endpoints", json.dumps(endpoints(cfg.fleet_connect)))
    return zc


class Opener:
    """Opens the session, again and again until it opens or :meth:`stop` (the link's shutdown)."""

    def __init__(self, make_config, on_open):
        self._make_config = make_config
        self._on_open = on_open
        self._stop = threading.Event()
        self.session = None
        self.attempts = 0
        self.last_error = ""
        self._thread = threading.Thread(target=self._run, name="zenoh-open", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        import zenoh

        delay = OPEN_RETRY
        while not self._stop.is_set():
            self.attempts += 1
            try:
                session = zenoh.open(self._make_config())
            except Exception as exc:  # zenoh.ZError, or a bad configuration file
                self.last_error = str(exc).split(" at /", 1)[0][:300]
                if self.attempts == 1 or self.attempts % 10 == 0:
                    log.warning("fleet: cannot open the Zenoh session (attempt %d): %s; trying again",
                                self.attempts, self.last_error)
                self._stop.wait(delay)
                delay = min(OPEN_RETRY_MAX, delay * 2)
                continue
            if self._stop.is_set():
                close(session)
                return
            self.session = session
            self.last_error = ""
            log.info("fleet: Zenoh session %s open", session.zid())
            self._on_open(session)
            return


def close(session, timeout: float = 3.0) -> None:
    """Close a session within ``timeout`` (Zenoh may linger on a dead link; the process then exits anyway)."""
    if session is None:
        return
    done = threading.Event()

    def run():
        try:
            session.close()
        except Exception:
            pass
        done.set()

    threading.Thread(target=run, name="zenoh-close", daemon=True).start()
    if not done.wait(timeout):
        log.warning("fleet: the Zenoh session did not close within %g s", timeout)
