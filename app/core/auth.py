"""The ``allow_*`` switches: what the robot permits at all, whoever asks.

Called by the routes of a write family that has one (publishing, operations, configurations,
fault clearing), on the request's greenlet, before anything reaches the ROS worker.  Who may use
what is permitted is another question, answered before any route runs: the token and its role
(``app/auth/``) and the locks (``app/locks/``).  Reads never ask, but those that come through the
fleet (:func:`authorize_change`).
"""

from __future__ import annotations

from .common import config
from .errors import ApiError


def authorize_feature(enabled: bool, what: str, flag: str, enables: str) -> None:
    """403 unless the gateway was started with ``flag`` (``enabled``)."""
    if not enabled:
        raise ApiError(403, "forbidden", f"{what} is disabled on this gateway",
                       {"details": f"start the gateway with {flag} to {enables}"})


def authorize_publish() -> None:
    """403 unless publishing is on (``allow_publish``)."""
    authorize_feature(config().allow_publish, "Publishing", "--allow-publish", "enable PUT")


def authorize_change() -> None:
    """401 unless the request carries a good token, while authentication is on: for what must come
    from a known client even when it reads (a request through the fleet: ``app/fleet/``).  A write
    needs no call: every write passed the token, role and lock checks before its route ran."""
    from .. import auth

    auth.require_identity()
