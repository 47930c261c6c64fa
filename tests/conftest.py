"""Session-wide isolation: each test session gets its own ROS domain, localhost only.

This runs before any test module imports rclpy, so every process the tests
start (they inherit the environment) lives in the same private domain.
"""

from __future__ import annotations

import os

import pytest

from tests.support.procs import private_ros_domain

private_ros_domain()


@pytest.fixture(scope="session")
def ros_domain() -> int:
    return int(os.environ["ROS_DOMAIN_ID"])


@pytest.fixture
def nodes():
    """ROS nodes (``RosNode``/``publisher``) appended here are stopped at the end of the test."""
    started: list = []
    yield started
    for node in reversed(started):
        node.stop()
