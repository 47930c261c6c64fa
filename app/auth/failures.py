"""Failed authorizations, limited per client address, so a secret cannot be guessed at line rate.

A failed client-credentials grant, a refresh token refused and a bearer token refused each spend
one token of the address's bucket (``auth_failure_limit``: RATE/BURST, default 1/30: thirty
failures at once, then one a second).  While the bucket is empty, every authorization
attempt of that address (``/auth/authorize``, ``/auth/token``, a bearer token not checked before)
is answered 429 before any secret is compared.  A success spends nothing, and a token that
checked out before passes without being asked (``tokens.py``'s cache).

The buckets are the rate limiter's (``app/ratelimit.py``): one memory-mapped file of the runtime
dir (``authfail.buckets``) that every HTTP worker shares, so two workers do not allow twice the
failures.
"""

from __future__ import annotations

import os

from common import settings

from .tokens import OAuthError

FILE_NAME = "authfail.buckets"


class TooManyFailures(OAuthError):
    def __init__(self, retry_after: int):
        super().__init__(429, "access_denied", "Too many failed authorizations from this address; retry "
                         f"after {retry_after} seconds")
        self.retry_after = retry_after


class FailureLimit:
    def __init__(self, runtime_dir: str, limit: str):
        # here, not at load: ratelimit keys its buckets with this package's rate_key (no import cycle)
        from .. import ratelimit

        rate = settings.parse_rate(limit, "auth_failure_limit")
        self.buckets = ratelimit.SharedBuckets(os.path.join(runtime_dir, FILE_NAME), rate, None) if rate else None

    def check(self, address: str) -> None:
        """Raise :class:`TooManyFailures` while ``address`` has no failure left."""
        if self.buckets is None:
            return
        decision = self.buckets.take(address, spend=False)
        if decision is not None and not decision.allowed:
            raise TooManyFailures(decision.retry_after)

    def failed(self, address: str) -> None:
        if self.buckets is not None:
            self.buckets.take(address)
