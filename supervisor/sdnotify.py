"""systemd's notify protocol (sd_notify(3)), stdlib only (and ``common/process.py``).

The service manager passes ``NOTIFY_SOCKET`` (a unix datagram socket: a path,
or an abstract name written with a leading ``@``) and, when ``WatchdogSec=``
is set, ``WATCHDOG_USEC`` (and maybe ``WATCHDOG_PID``).  Without
``NOTIFY_SOCKET`` every method does nothing, so the supervisor runs the same
way in a terminal, a container or under systemd.

Only the supervisor notifies (the unit says ``NotifyAccess=main``): its
children get an environment without these variables (:func:`child_env`), so
gunicorn's own ``READY=1`` never reaches systemd.

Before fork / after fork: the constructor only reads the environment; the
socket is opened on first use by the process that sends.  A send has a
timeout: a receiver whose queue is full must not block the supervisor's loop.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

from common.process import PerProcess

log = logging.getLogger("sovd.sdnotify")

SEND_TIMEOUT = 1.0  # seconds
NOTIFY_VARS = ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID")


def child_env(environ: Mapping[str, str]) -> dict[str, str]:
    """A copy of ``environ`` without the notify/watchdog variables (for children)."""
    return {k: v for k, v in environ.items() if k not in NOTIFY_VARS}


def _address(raw: str) -> str | None:
    if len(raw) < 2 or raw[0] not in "@/":
        return None
    return "\0" + raw[1:] if raw[0] == "@" else raw


def _notify_socket() -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
    sock.settimeout(SEND_TIMEOUT)
    return sock


class Notifier:
    def __init__(self, environ: Mapping[str, str] | None = None):
        env = os.environ if environ is None else environ
        raw = env.get("NOTIFY_SOCKET", "")
        self.address = _address(raw) if raw else None
        if raw and self.address is None:
            log.warning("NOTIFY_SOCKET=%r is neither a path nor an abstract (@) name; not notifying", raw)
        self._watchdog_usec = 0
        try:
            usec = int(env.get("WATCHDOG_USEC", "0"))
        except ValueError:
            usec = 0
        pid = env.get("WATCHDOG_PID")
        if usec > 0 and (not pid or pid == str(os.getpid())):
            self._watchdog_usec = usec
        self._sock: PerProcess[socket.socket] = PerProcess(_notify_socket, socket.socket.close)

    @property
    def enabled(self) -> bool:
        return self.address is not None

    @property
    def watchdog_interval(self) -> float | None:
        """Seconds between ``WATCHDOG=1`` pings (half of ``WATCHDOG_USEC``), or None."""
        if not self.enabled or not self._watchdog_usec:
            return None
        return self._watchdog_usec / 2e6

    def notify(self, *fields: str) -> bool:
        """Send one datagram of ``KEY=value`` lines; True when it was sent."""
        if self.address is None:
            return False
        data = "\n".join(f.replace("\n", " ") for f in fields).encode("utf-8", "replace")
        try:
            self._sock.get().sendto(data, self.address)
            return True
        except OSError as exc:  # includes socket.timeout
            log.debug("sd_notify(%r) failed: %s", data, exc)
            self.close()
            return False

    def ready(self, status: str | None = None) -> bool:
        return self.notify("READY=1", *([f"STATUS={status}"] if status else []))

    def status(self, text: str) -> bool:
        return self.notify(f"STATUS={text}")

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def stopping(self, status: str | None = None) -> bool:
        return self.notify("STOPPING=1", *([f"STATUS={status}"] if status else []))

    def close(self) -> None:
        self._sock.reset()
