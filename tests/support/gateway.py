"""Moved (issue 30): common/harness/gateway.py.  A re-export until the tests import from there."""

from common.harness.gateway import *  # noqa: F403
from common.harness.gateway import BIN, SECRET_FLAGS, FleetGateway, Gateway  # noqa: F401
