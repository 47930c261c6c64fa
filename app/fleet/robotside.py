"""On a robot: a request that came through the fleet is answered only to a valid identity.

The robot's fleet link makes every fleet request to this gateway over the loopback and marks it
(``ipc/fleet.py``'s :data:`~ipc.fleet.MARK`).  Such a request, a read included, must carry a valid
identity: the caller's ``Authorization``, checked here as the gateway checks a write's
(``app/core/auth.py``; the roles of the access issue when they come).  A local client that sends
the header only makes its own request stricter, so the mark needs no secret.
"""

from __future__ import annotations

from flask import Flask, request

from ipc import fleet

from ..core.auth import authorize_change


def _fleet_identity() -> None:
    if fleet.MARK in request.headers:
        authorize_change()


def init_app(app: Flask) -> None:
    app.before_request(_fleet_identity)
