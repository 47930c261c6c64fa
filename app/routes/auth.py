"""The ``allow_*`` switches: what the robot permits at all, whoever asks.

Called by the routes of a write family that has one (publishing, operations, configurations,
fault clearing), on the request's greenlet, before anything reaches the ROS worker.  Who may use
what is permitted is another question, answered before any route runs: the token and its role
(``app/auth/``) and the locks (``app/locks/``).  Reads never ask.
"""

from __future__ import annotations

from ..errors import ApiError
from .common import config


def authorize_feature(enabled: bool, what: str, flag: str, enables: str) -> None:
    """403 unless the gateway was started with ``flag`` (``enabled``)."""
    if not enabled:
        raise ApiError(403, "forbidden", f"{what} is disabled on this gateway",
                       {"details": f"start the gateway with {flag} to {enables}"})


def authorize_publish() -> None:
    """403 unless publishing is on (``allow_publish``)."""
    authorize_feature(config().allow_publish, "Publishing", "--allow-publish", "enable PUT")
