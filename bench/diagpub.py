"""Moved (issue 30): common/harness/diagpub.py.  A re-export until the tests import from there."""

from common.harness.diagpub import DiagPub  # noqa: F401
