"""Who may change the gateway's or the robot's state: ``allow_publish`` and the bearer token.

Called by the routes that change something on a client's behalf (``data.py``'s PUT,
``subscriptions.py``'s create, update and delete), on the request's greenlet, before
anything reaches the ROS worker.  Reads never ask.
"""

from __future__ import annotations

import hmac

from flask import request

from .common import config
from .errors import ApiError


def authorize_feature(enabled: bool, what: str, flag: str, enables: str) -> None:
    """403 unless the gateway was started with ``flag`` (``enabled``); then :func:`authorize_change`."""
    if not enabled:
        raise ApiError(403, "forbidden", f"{what} is disabled on this gateway",
                       {"details": f"start the gateway with {flag} to {enables}"})
    authorize_change()


def authorize_publish() -> None:
    """403 unless publishing is on; with an API token, 401 without it and 403 with a wrong one."""
    authorize_feature(config().allow_publish, "Publishing", "--allow-publish", "enable PUT")


def authorize_change() -> None:
    """With an API token configured: 401 without it, 403 with a wrong one (else nothing to check).

    Every request that changes the gateway's or the robot's state on a client's behalf asks
    this (publishing, making, changing and deleting cyclic subscriptions); reads never do.
    """
    token = config().api_token
    if not token:
        return
    scheme, _, given = request.headers.get("Authorization", "").partition(" ")
    given = given.strip()
    if scheme.lower() != "bearer" or not given:
        raise ApiError(401, "unauthorized", "Authentication required",
                       {"details": "send the header 'Authorization: Bearer <token>'"},
                       headers={"WWW-Authenticate": 'Bearer realm="sovd-gateway"'})
    if not hmac.compare_digest(given.encode("utf-8", "surrogateescape"), token.encode("utf-8")):
        raise ApiError(403, "forbidden", "Invalid API token")
