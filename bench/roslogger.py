"""Moved (issue 30): common/harness/roslogger.py.  A re-export until the tests import from there."""

from common.harness.roslogger import LoggerNode  # noqa: F401
