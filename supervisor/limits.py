"""Process limits the gateway raises for itself and its children where it starts.

Open descriptors: every SSE stream holds one connection in an HTTP worker, so
the soft ``RLIMIT_NOFILE`` (1,024 by default on most distributions) caps a
gateway at about 1,000 streams, less its sockets and files.  The supervisor
raises the soft limit to the hard one before it starts its children, which
inherit it (the systemd unit sets both with ``LimitNOFILE=``; see the README's
"Streaming: what a robot needs").
"""

from __future__ import annotations

import logging
import resource

log = logging.getLogger("sovd.supervisor")


def raise_nofile() -> tuple[int, int]:
    """Soft RLIMIT_NOFILE up to the hard limit; returns ``(soft, hard)`` as they are now."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard == resource.RLIM_INFINITY or soft == resource.RLIM_INFINITY or soft < hard:
        wanted = hard if hard != resource.RLIM_INFINITY else max(soft, 1 << 20)
        if wanted != soft:
            try:
                resource.setrlimit(resource.RLIMIT_NOFILE, (wanted, hard))
                soft = wanted
            except (OSError, ValueError) as exc:
                log.warning("could not raise the open-file limit from %d to %d: %s", soft, wanted, exc)
    log.info("open-file limit %d (hard %s): about %d SSE streams", soft,
             "unlimited" if hard == resource.RLIM_INFINITY else hard, max(0, soft - 200))
    return soft, hard
