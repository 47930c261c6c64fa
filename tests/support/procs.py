"""Moved (issue 30): the process harness is common/harness/procs.py; the tests' ROS node is
tests/support/rospub.py.  A re-export until the tests import from there."""

from common.harness.procs import *  # noqa: F403
from common.harness.procs import DOMAIN_LOCK_DIR, REPO, Proc, _domain_locks  # noqa: F401
from tests.support.rospub import RosNode, publisher, unique_topic  # noqa: F401
